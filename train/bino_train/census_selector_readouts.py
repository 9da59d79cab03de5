"""Cell readouts of the census selector study (census_selector.py) and choices among them.

The base readouts census+lr, head+lr and fuse-census+lr of a pair (`base_readouts`), the
background fill (`fill_background`), a per-cell choice among readouts (`select`), the
ground-truth oracles on cells (`oracle_choice`) and on refined pixels (`pixel_oracle`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from .census_companion import fuse
from .census_selector_cells import Grid, Mask, PairCells, Pixels, cell_sums
from .head_eval import fill_rejected
from .refine import CELL

FUSE_SHARE = 0.5
"""`census::FUSE_HEAD_WEIGHT` / 256: the head's share in `fuse-census`."""

Readout = tuple[Grid, Mask]
"""(filled disparity in patch columns, kept mask): what `census_companion.refined` refines."""


def base_readouts(c: PairCells) -> dict[str, Readout]:
    """census+lr, head+lr and fuse-census+lr of one pair (filled from the left)."""
    cc = c.census
    head = (c.head, c.head_kept)
    return {
        "census": (fill_rejected(cc.disparity, cc.kept), cc.kept),
        "head": (fill_rejected(c.head, c.head_kept), c.head_kept),
        "fuse": fuse(head, c.head_peak, (cc.disparity, cc.kept), FUSE_SHARE),
    }


def fill_background(disparity: Grid, kept: Mask) -> Grid:
    """Each rejected cell takes the lower of the nearest kept values to its left and right (the
    background side of an occlusion; the one that exists at a row's ends; 0 in a row with nothing
    kept): a classical alternative to `fill_rejected`'s left fill, since adopted by the core for
    the census readouts (`bino_core::lr::Fill::Background`)."""
    from_left = fill_rejected(disparity, kept)
    from_right = fill_rejected(disparity[:, ::-1], kept[:, ::-1])[:, ::-1]
    cols = np.arange(kept.shape[1])
    seen_left = np.maximum.accumulate(np.where(kept, cols, -1), axis=1) >= 0
    seen_right = np.maximum.accumulate(np.where(kept, cols, -1)[:, ::-1] >= 0, axis=1)[:, ::-1]
    both = np.minimum(from_left, from_right)
    out = np.where(seen_left & seen_right, both, np.where(seen_left, from_left, from_right))
    return np.where(kept, disparity, out)


def select(readouts: Sequence[Readout], choice: NDArray[np.int64]) -> Readout:
    """Each cell's (disparity, kept) from `readouts[choice]`."""
    grids = np.stack([r[0] for r in readouts])
    kept = np.stack([r[1] for r in readouts])
    pick = choice[None]
    return (
        np.take_along_axis(grids, pick, 0)[0],
        np.take_along_axis(kept, pick, 0)[0],
    )


def oracle_choice(readouts: Sequence[Readout], gt_cell: Grid) -> NDArray[np.int64]:
    """Per cell the readout closest to the cell's ground truth (the first where unknown or
    tied)."""
    err = np.stack([np.abs(r[0] - gt_cell) for r in readouts])
    err = np.where(np.isfinite(err), err, np.inf)
    err[0] = np.where(np.isfinite(gt_cell), err[0], -1.0)
    return np.asarray(err.argmin(axis=0), dtype=np.int64)


def cell_errors(pred: Pixels, c: PairCells) -> tuple[Grid, Grid]:
    """(sum, count) of |pred - gt| over each cell's valid pixels."""
    return cell_sums(np.abs(pred.astype(np.float64) - c.gt), c.valid)


def pixel_oracle(preds: Sequence[Pixels], c: PairCells) -> Pixels:
    """Each cell's pixels from the refined map with the lowest error on them (the first where
    the cell has no valid pixel)."""
    sums = np.stack([cell_errors(p, c)[0] for p in preds])
    choice = sums.argmin(axis=0)
    pix = np.repeat(np.repeat(choice, CELL, axis=0), CELL, axis=1)
    return np.take_along_axis(np.stack(preds), pix[None], 0)[0]
