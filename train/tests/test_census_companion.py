"""The census second opinion's float prototype: its distances, the right view's reindexing, the
SGM's disparity on a shifted texture, the fusion rule and the fast refinement's agreement with
`refine_float`."""

from __future__ import annotations

import numpy as np

from bino_train.census_companion import (
    OUTSIDE_COST,
    box_sums,
    census_sgm,
    fuse,
    pixel_hamming,
    refined,
    right_view,
)
from bino_train.refine import RefineParams, refine_float


def _shifted_pair(shift: int, h: int = 32, w: int = 64) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(41)
    base = rng.integers(0, 256, size=(h, w + shift), dtype=np.int64)
    # Left pixel x is right pixel x - shift.
    return base[:, :w].astype(np.uint8), base[:, shift:].astype(np.uint8)


def test_the_true_shift_costs_nothing_and_outside_costs_the_maximum() -> None:
    left, right = _shifted_pair(6)
    hamming = pixel_hamming(left, right, 12, clamp=False)
    # Away from the views' clamped borders.
    assert np.all(hamming[2:-2, 8:-2, 6] == 0)
    assert np.all(hamming[:, :3, 3] == OUTSIDE_COST)
    assert hamming[2:-2, 8:-2, 5].mean() > 5


def test_the_right_view_reads_the_left_distance_shifted_by_d() -> None:
    left, right = _shifted_pair(4)
    hamming = pixel_hamming(left, right, 8, clamp=False)
    mirrored = right_view(hamming)
    assert np.array_equal(mirrored[:, :-4, 4], hamming[:, 4:, 4])
    assert np.all(mirrored[:, -4:, 4] == OUTSIDE_COST)


def test_the_sgm_finds_a_constant_shift_and_its_check_keeps_it() -> None:
    left, right = _shifted_pair(8)
    rows, cols = left.shape[0] // 4, left.shape[1] // 4
    for disparity, kept in census_sgm(
        pixel_hamming(left, right, 16, clamp=False), rows, cols
    ).values():
        # Cells whose match lies inside the right view: 8 px = 2 patch columns, give or take
        # the parabola step's wobble.
        assert np.allclose(disparity[:, 2:], 2.0, atol=0.05)
        assert kept[:, 2:].all()


def test_fusion_takes_the_mean_where_both_pass_and_the_one_that_passes_elsewhere() -> None:
    head = np.array([[1.0, 2.0, 3.0, 4.0]])
    other = np.array([[3.0, 0.0, 1.0, 9.0]])
    kh = np.array([[True, True, False, False]])
    ko = np.array([[True, False, True, False]])
    confidence = np.full((1, 4), 0.5)
    grid, kept = fuse((head, kh), confidence, (other, ko), 0.5)
    # The fourth cell is kept by neither and takes its left neighbour's value.
    assert np.allclose(grid, [[2.0, 2.0, 1.0, 1.0]])
    assert np.array_equal(kept, [[True, True, True, False]])


def test_the_fast_refinement_equals_refine_float_where_every_cell_is_kept() -> None:
    left, right = _shifted_pair(5, h=24, w=48)
    rng = np.random.default_rng(3)
    tokens = 1.25 + rng.uniform(-0.4, 0.4, size=(6, 12))
    boxed = box_sums(pixel_hamming(left, right, 16, clamp=True), RefineParams().box_radius)
    fast = refined(boxed, tokens, np.ones((6, 12), dtype=bool), 2)
    assert np.allclose(fast, refine_float(left, right, tokens, RefineParams(search=2)), atol=1e-5)
