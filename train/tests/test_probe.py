"""No-linkage probe: band plan, matching, sub-token step, upsampling, metrics."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from bino_train.probe import (
    ProbeItem,
    band_plan,
    encoder_descriptors,
    fill_invalid,
    load_probe_set,
    run_probe,
    score,
    similarity_volume,
    upsample_disparity,
    window_descriptors,
    wta_subtoken,
)


def test_band_plan_matches_bino_core() -> None:
    plan = [(b.start, b.keep_from, b.keep_to) for b in band_plan(24)]
    assert plan == [(0, 0, 9), (6, 9, 15), (12, 15, 24)]  # the bino_core::band doc example
    assert [(b.start, b.rows, b.keep_to) for b in band_plan(7)] == [(0, 7, 7)]
    for rows in range(1, 80):
        bands, covered = band_plan(rows), 0
        for band in bands:
            assert band.keep_from == covered and band.keep_to > band.keep_from
            assert band.start <= band.keep_from and band.keep_to <= band.start + band.rows
            assert band.start + band.rows <= rows and band.rows <= 12
            covered = band.keep_to
        assert covered == rows
        if len(bands) > 1:
            assert all(b.start - a.start <= 8 for a, b in zip(bands, bands[1:], strict=False))


class _PoolingModel(nn.Module):
    """Descriptor = the 4x4 cell's pixels plus the cell's row inside the band it was run on."""

    def __init__(self) -> None:
        super().__init__()
        self.dummy = nn.Parameter(torch.zeros(1))

    def descriptors(self, image: Tensor) -> Tensor:
        cells = F.pixel_unshuffle(image[:, :1], 4).permute(0, 2, 3, 1)  # (B, T, P, 16)
        rows = torch.arange(cells.shape[1], dtype=cells.dtype).view(1, -1, 1, 1)
        return torch.cat([cells, rows.expand(*cells.shape[:3], 1)], dim=-1)


def test_banded_descriptors_stitch_the_right_rows() -> None:
    image = np.random.default_rng(0).random((132, 40), dtype=np.float32)  # 33 token rows
    (desc,) = encoder_descriptors(_PoolingModel(), [image])  # type: ignore[arg-type]
    expected = F.pixel_unshuffle(torch.from_numpy(image)[None, None], 4)[0].permute(1, 2, 0)
    assert desc.shape == (33, 10, 17)
    assert torch.equal(desc[..., :16], expected)
    # Each kept row comes from the band where it sits furthest from a cut.
    in_band_row = desc[:, 0, 16].tolist()
    want = [r - b.start for b in band_plan(33) for r in range(b.keep_from, b.keep_to)]
    assert in_band_row == want


def _oracle_pair(height: int, width: int, shift_cols: int) -> tuple[np.ndarray, np.ndarray]:
    """Each pixel stores its scene column, so the cell's scene position can be read back."""
    scene = (np.arange(width + 4 * shift_cols, dtype=np.float32) + 1.0) / 1024.0
    left = np.tile(scene[:width], (height, 1))
    right = np.tile(scene[4 * shift_cols : 4 * shift_cols + width], (height, 1))
    return left, right  # left(x) = right(x - 4 * shift_cols)


def _oracle_describe(images: Sequence[np.ndarray]) -> list[Tensor]:
    """A perfect descriptor: one-hot of the scene column of each cell."""
    out = []
    for image in images:
        scene_col = np.rint(image[::4, ::4] * 1024.0 - 1.0).astype(np.int64)
        out.append(F.one_hot(torch.from_numpy(scene_col), 2048).float())
    return out


def test_probe_with_a_perfect_descriptor_recovers_the_shift() -> None:
    shift_cols = 3
    left, right = _oracle_pair(96, 160, shift_cols)
    gt = np.full(left.shape, 4.0 * shift_cols, dtype=np.float32)
    valid = np.zeros(left.shape, dtype=bool)
    valid[:, 4 * shift_cols + 4 :] = True  # left pixels whose match is inside the right view
    item = ProbeItem("oracle", left, right, gt, valid)
    metrics = run_probe(_oracle_describe, [item], max_cols=10)
    assert metrics["epe"] == pytest.approx(0.0, abs=1e-6)
    assert metrics["bad1tok"] == 0.0 and metrics["bad2"] == 0.0
    # The wrong sign of disparity is caught: the same pair swapped and mirrored scores badly.
    swapped = ProbeItem("swapped", right, left, gt, valid)
    assert run_probe(_oracle_describe, [swapped], max_cols=10)["epe"] > 4.0


def test_similarity_excludes_out_of_image_candidates() -> None:
    d = torch.randn(2, 6, 8)
    sims = similarity_volume(d, d, 10)
    assert sims.shape == (2, 6, 10)
    assert torch.isinf(sims[:, 0, 1:]).all() and torch.isfinite(sims[:, 5, :6]).all()
    assert torch.allclose(sims[:, :, 0], torch.ones(2, 6))


def test_parabola_step_finds_the_vertex() -> None:
    ks = torch.arange(10, dtype=torch.float32)
    for true in (2.3, 4.0, 6.75):
        sims = -((ks - true) ** 2)
        assert float(wta_subtoken(sims[None, None])[0, 0]) == pytest.approx(true, abs=1e-5)
    edge = -((ks - 0.2) ** 2)  # best at k = 0: no left neighbour, no sub-token step
    assert float(wta_subtoken(edge[None, None])[0, 0]) == 0.0


def test_upsampling_is_bilinear_between_cell_centres() -> None:
    tokens = torch.tensor([[1.0, 2.0]])
    pixels = upsample_disparity(tokens)
    assert pixels.shape == (4, 8)
    # Cell centres at x = 1.5 and 5.5 hold 4 and 8 px; outside them the value is held.
    assert np.allclose(pixels[0], [4, 4, 4.5, 5.5, 6.5, 7.5, 8, 8])


def test_score_and_fill() -> None:
    gt = np.zeros((2, 4), dtype=np.float32)
    pred = np.array([[0, 1, 3, 5], [0, 0, 0, 0]], dtype=np.float32)
    valid = np.ones_like(gt, dtype=bool)
    valid[1] = False
    m = score(pred, gt, valid)
    assert m == {"epe": 2.25, "bad1tok": 25.0, "bad2": 50.0}
    raw = np.array([[9, 1, 9, 2, 9]], dtype=np.float32)
    ok = np.array([[False, True, False, True, False]])
    assert fill_invalid(raw, ok).tolist() == [[1, 1, 1, 2, 2]]


def test_window_descriptor_is_zero_mean_unit_norm_and_centred() -> None:
    image = np.random.default_rng(0).random((48, 64), dtype=np.float32)
    (desc,) = window_descriptors([image], 12)
    assert desc.shape == (12, 16, 144)
    assert torch.allclose(desc.sum(-1), torch.zeros(12, 16), atol=1e-5)
    assert torch.allclose(desc.norm(dim=-1), torch.ones(12, 16), atol=1e-5)
    window = torch.from_numpy(image[4:16, 8:20]).reshape(-1)  # cell (2, 3): rows 8..11, cols 12..15
    window = window - window.mean()
    assert torch.allclose(desc[2, 3], window / window.norm(), atol=1e-5)


def test_probe_set_reads_eval_pairs_at_w160(data_dir: Path) -> None:
    items = load_probe_set(data_dir, "w160")
    assert [i.pair_id for i in items] == ["e0", "e1"]
    assert (
        items[0].left.shape == items[0].gt.shape == (104, 160)
    )  # 300x200 -> 160x106.7 -> 107 -> 104
    assert items[1].left.shape == (120, 160)
