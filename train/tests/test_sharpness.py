"""Sharpness equalisation: untouched when the views match, the sharper view blurred otherwise."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bino_train.refine import CELL, refine_int
from bino_train.sharpness import (
    Decision,
    box,
    decide_rows,
    refine_equalised,
    sharpness_rows,
    write_fixture,
)
from bino_train.synthetic import smooth_texture


def _texture(seed: int, height: int = 40, width: int = 96) -> np.ndarray:
    values = smooth_texture(np.random.default_rng(seed), height, width)
    return np.clip(np.round(values * 255.0), 0, 255).astype(np.uint8)


def test_box_is_the_rounded_window_mean_with_edges_replicated() -> None:
    view = np.array([[0, 9, 0], [9, 0, 9], [0, 9, 0]], dtype=np.uint8)
    assert box(view, 0).tolist() == view.tolist()
    # Centre: 36 / 9 = 4. Corner (0, 0) sees rows/cols clamped: 0 0 9 / 0 0 9 / 9 9 0 -> 36 / 9.
    assert box(view, 1)[1, 1] == 4 and box(view, 1)[0, 0] == 4
    # Rounded half up: one 1 among nine is 1/9 -> 0; nine 1s -> 1.
    assert box(np.eye(3, dtype=np.uint8), 1)[1, 1] == 0
    assert box(np.ones((3, 3), dtype=np.uint8), 1)[1, 1] == 1


def test_sharpness_sums_the_gradient_of_the_3x3_mean() -> None:
    ramp = np.tile(np.arange(0, 90, 9, dtype=np.uint8), (5, 1))
    # The 3x3 mean of a ramp is the ramp inside, flattened at the two clamped ends.
    smooth = box(ramp, 1).astype(int)
    assert sharpness_rows(ramp).tolist() == [int(np.abs(np.diff(smooth[0])).sum())] * 5
    assert sharpness_rows(np.full((4, 6), 7, dtype=np.uint8)).tolist() == [0] * 4


def test_identical_views_are_left_alone() -> None:
    view = _texture(1)
    assert all(d.radius == 0 for d in decide_rows(view, view))
    tokens = np.full((view.shape[0] // CELL, view.shape[1] // CELL), 3 * 256, dtype=np.uint16)
    assert np.array_equal(refine_equalised(view, view, tokens), refine_int(view, view, tokens))


@pytest.mark.parametrize("blurred_view", [0, 1])
def test_the_sharper_view_is_blurred_towards_the_other(blurred_view: int) -> None:
    sharp = _texture(2)
    views = [sharp, sharp]
    views[blurred_view] = box(sharp, 2)
    decisions = decide_rows(views[0], views[1])
    assert all(d.view == 1 - blurred_view and d.radius >= 1 for d in decisions)
    # Each refined row is the refinement of the views its decision smooths.
    tokens = np.full((sharp.shape[0] // CELL, sharp.shape[1] // CELL), 2 * 256, dtype=np.uint16)
    out = refine_equalised(views[0], views[1], tokens)
    for y, d in enumerate(decisions):
        smoothed = list(views)
        smoothed[d.view] = box(smoothed[d.view], d.radius)
        assert np.array_equal(out[y], refine_int(smoothed[0], smoothed[1], tokens)[y])


def test_a_view_within_the_margin_is_not_blurred() -> None:
    # Every row alike, so each row's window has the whole view's sharpness ratio.
    sharp = np.tile(_texture(3)[0], (12, 1))
    slightly = box(sharp, 1)
    own, target = sharpness_rows(sharp).sum(), sharpness_rows(slightly).sum()
    margin = int(100 * own / target) - 100  # the views' sharpness ratio, in %

    def decide(margin_pct: int) -> list[Decision]:
        return decide_rows(sharp, slightly, margin_pct=margin_pct, contrast_margin_pct=None)

    assert all(d.radius == 0 for d in decide(margin + 1))
    assert any(d.radius > 0 for d in decide(max(margin - 5, 0)))
    assert decide(0)[0] == Decision(0, 1)


def test_a_view_with_less_contrast_is_not_read_as_defocused() -> None:
    # Exposure gain 0.7 (bino eval's `gain`): every gradient 30 % smaller, at every scale.
    sharp = _texture(4)
    dim = np.clip(np.floor(0.7 * sharp.astype(np.float64) + 20.5), 0, 255).astype(np.uint8)
    assert any(d.radius > 0 for d in decide_rows(sharp, dim, contrast_margin_pct=None))
    assert all(d.radius == 0 for d in decide_rows(sharp, dim))
    # A defocused view still is.
    assert all(d.radius > 0 for d in decide_rows(sharp, box(dim, 2)))


def test_views_of_different_shapes_are_refused() -> None:
    with pytest.raises(ValueError, match="equal 2-D arrays"):
        decide_rows(_texture(3), _texture(3, width=64))


def test_the_committed_fixture_is_current(tmp_path: Path) -> None:
    """The Rust tests pin bino_core::refine::sharpness to this file; rewrite it with
    `python -m bino_train.sharpness --fixture ../tests/fixtures/refine/equalised.bin`."""
    fresh = tmp_path / "equalised.bin"
    assert write_fixture(fresh) < 20_000
    committed = Path(__file__).resolve().parents[2] / "tests/fixtures/refine/equalised.bin"
    assert fresh.read_bytes() == committed.read_bytes()
