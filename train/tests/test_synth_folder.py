"""Synthetic scenes with exact disparity and textureless surfaces, as a `bino eval` folder."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from bino_train.pairs import load_gt, load_pairs
from bino_train.synth_folder import (
    FLAT_GRAIN_LEVELS,
    Layer,
    render,
    scene,
    textured,
    textureless,
    write_folder,
)
from bino_train.synthetic import high_pass

H, W, MARGIN = 40, 96, 20


def _layers() -> list[Layer]:
    rng = np.random.default_rng(1)
    tw = W + MARGIN + 2
    background = Layer(
        np.full((H, W), 5.0, np.float32), np.ones((H, W), bool), textured(rng, H, tw)
    )
    box = np.zeros((H, W), bool)
    box[10:30, 40:70] = True
    flat = Layer(np.full((H, W), 14.0, np.float32), box, textureless(rng, H, tw))
    return [background, flat]


def test_render_matches_every_visible_pixel_at_its_disparity() -> None:
    layers = _layers()
    left, right, disparity = render(layers, H, W, MARGIN)
    assert set(np.unique(disparity)) == {5.0, 14.0}
    ys, xs = np.mgrid[0:H, 0:W]
    target = xs - disparity.astype(int)
    # Visible in the right view: on the image, and no nearer surface covers the target there.
    near_in_right = np.zeros((H, W), bool)
    near_in_right[10:30, 40 - 14 : 70 - 14] = True
    visible = (target >= 0) & ~((disparity == 5.0) & near_in_right[ys, np.clip(target, 0, W - 1)])
    matched = right[ys, np.clip(target, 0, W - 1)]
    assert visible.sum() > 0.8 * H * W
    np.testing.assert_allclose(left[visible], matched[visible], atol=1e-5)
    # The occluded background strip beside the box does not match: the test can fail.
    occluded = (disparity == 5.0) & near_in_right[ys, np.clip(target, 0, W - 1)] & (target >= 0)
    assert occluded.sum() > 0
    assert np.abs(left[occluded] - matched[occluded]).max() > 0.05


def test_textureless_surface_is_flat_with_a_real_surfaces_grain() -> None:
    rng = np.random.default_rng(2)
    flat, busy = textureless(rng, 64, 64), textured(rng, 64, 64)
    smooth = cv2.GaussianBlur(flat, (0, 0), 3.0)
    # No structure at the scale of a window or a head's cell: under a grey level per pixel ...
    assert np.abs(np.diff(smooth, axis=1)).max() < 0.5 / 255.0
    # ... and the fine grain real flat regions carry, for a census of signs to match.
    grain = float(np.sqrt(np.mean(high_pass(flat * 255.0)[8:-8, 8:-8] ** 2)))
    assert grain == pytest.approx(FLAT_GRAIN_LEVELS, rel=0.2)
    assert np.abs(np.diff(busy, axis=1)).max() > 5.0 / 255.0


def test_folder_is_reproducible_with_exact_dense_ground_truth(tmp_path: Path) -> None:
    a, b = tmp_path / "a", tmp_path / "b"
    assert write_folder(a, 160, 96, 3) == 3
    write_folder(b, 160, 96, 3)
    for path in sorted(a.iterdir()):
        assert path.read_bytes() == (b / path.name).read_bytes(), path.name
    pairs = load_pairs(a)
    assert [p.split for p in pairs] == ["val"] * 3
    for pair in pairs:
        gt, valid = load_gt(pair)
        assert valid.all() and gt.shape == (96, 160)
        assert 0.0 < gt.min() and gt.max() <= 30.0  # 60 px per 320 px of width
        left = cv2.imread(str(pair.left), cv2.IMREAD_GRAYSCALE)
        assert left is not None and left.shape == (96, 160)
    _, _, disparity = scene(0, 96, 160, 30.0)
    assert len(np.unique(disparity)) > 3  # a slanted background and nearer objects


def test_real_textures_come_from_train_split_views(tmp_path: Path) -> None:
    from bino_train.synth_folder import RealTextures
    from tests.conftest import HEADER

    rng = np.random.default_rng(4)
    image = rng.integers(0, 256, (60, 90), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "l.png"), image)
    cv2.imwrite(str(tmp_path / "e.png"), np.zeros_like(image))
    rows = ["\t".join(HEADER)]
    rows.append("\t".join(["t0", "train", "x", "l.png", "l.png", "", "", "", "", "90", "60"]))
    rows.append("\t".join(["e0", "eval", "x", "e.png", "e.png", "", "", "", "", "90", "60"]))
    (tmp_path / "PAIRS.tsv").write_text("\n".join(rows) + "\n")
    real = RealTextures(tmp_path)
    assert [p.name for p in real.paths] == ["l.png"]  # never the eval split's
    crop = real(np.random.default_rng(0), 40, 120)
    assert crop.shape == (40, 120) and crop.std() > 0.1  # the random image, not the black one
    left, right, disparity = scene(1, 40, 120, 20.0, real)
    assert left.shape == right.shape == disparity.shape == (40, 120)
