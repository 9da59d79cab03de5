"""Sharpness equalisation: untouched when the views match, the sharper view blurred otherwise."""

from __future__ import annotations

import numpy as np
import pytest

from bino_train.sharpness import BAND_ROWS, box, decide, equalise, sharpness_rows
from bino_train.synthetic import smooth_texture


def _texture(seed: int, height: int = 2 * BAND_ROWS + 16, width: int = 96) -> np.ndarray:
    values = smooth_texture(np.random.default_rng(seed), height, width)
    return np.clip(np.round(values * 255.0), 0, 255).astype(np.uint8)


def test_box_is_the_rounded_window_mean_with_edges_replicated() -> None:
    view = np.array([[0, 9, 0], [9, 0, 9], [0, 9, 0]], dtype=np.uint8)
    assert box(view, 0).tolist() == view.tolist()
    # Centre: 36 / 9 = 4. Corner (0, 0) sees rows/cols clamped: 0 0 9 / 0 0 9 / 9 9 0 -> 36 / 9.
    assert box(view, 1)[1, 1] == 4 and box(view, 1)[0, 0] == 4
    # Rounded half up: a 1 among eight 0s is 1/9 -> 0; five 1s of nine -> 5/9 -> 1.
    assert box(np.eye(3, dtype=np.uint8), 1)[1, 1] == 0
    assert box(np.ones((3, 3), dtype=np.uint8), 1)[1, 1] == 1


def test_identical_views_are_left_alone() -> None:
    view = _texture(1)
    left, right, decisions = equalise(view, view)
    assert all(d.radius == 0 for d in decisions)
    assert np.array_equal(left, view) and np.array_equal(right, view)
    assert [d.row for d in decisions] == [0, BAND_ROWS, 2 * BAND_ROWS]


@pytest.mark.parametrize("blurred_view", [0, 1])
def test_the_sharper_view_is_blurred_towards_the_other(blurred_view: int) -> None:
    sharp = _texture(2)
    views = [sharp, sharp]
    views[blurred_view] = box(sharp, 2)
    decisions = decide(views[0], views[1])
    assert all(d.view == 1 - blurred_view and d.radius >= 1 for d in decisions)
    left, right, _ = equalise(views[0], views[1])
    out = (left, right)
    # The blurred view is untouched; the sharper one now matches it far better than before.
    assert np.array_equal(out[blurred_view], views[blurred_view])
    before = np.abs(views[0].astype(int) - views[1].astype(int)).mean()
    after = np.abs(left.astype(int) - right.astype(int)).mean()
    assert after < 0.5 * before
    target = sharpness_rows(views[blurred_view]).sum()
    assert abs(sharpness_rows(out[1 - blurred_view]).sum() - target) < abs(
        sharpness_rows(sharp).sum() - target
    )


def test_views_of_different_shapes_are_refused() -> None:
    with pytest.raises(ValueError, match="equal 2-D arrays"):
        decide(_texture(3), _texture(3, width=64))
