"""Readouts that regularise where matching is blind, tried on the float shared head before any
goes into the integer core: scored on labeled folders off the eval split (token grid upsampled
bilinearly, EVAL.md metrics, mean over pairs).

    python -m bino_train.readout_variants --encoder E --head H --folders /tmp/heldout160 ...

Variants (each after the head's own left-right check, `head_eval.head_lr`):
- `fill-left`: each rejected cell takes the nearest kept cell to its left (today's `+lr`);
- `fill-background`: the nearer kept cell on either side with the smaller disparity (rejected
  cells are mostly occlusions, which belong to the background);
- `fill-gray`: the nearer kept cell on either side whose 4x4 cell mean grey level is closer to
  the rejected cell's (edge-aware, guided by the left image);
- `sgm-P1-P2`: 4-path SGM (left to right, right to left, top to bottom, top-left diagonal: the
  paths one streaming pass allows) over the cost `-logits`, soft-argmin of the aggregated cost,
  then `fill-left` with the head's mask.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from .folder_scoring import per_variant, run_cli
from .head import StereoHead
from .head_eval import consistent, fill_rejected, pair_inputs
from .model import BinoEncoder
from .pairs import load_gray, load_gt, load_pairs
from .probe import score, upsample_disparity

Grid = NDArray[np.float64]
Mask = NDArray[np.bool_]

SGM_PENALTIES = ((0.5, 2.0), (1.0, 4.0), (2.0, 8.0), (4.0, 16.0))
"""(P1, P2) in logit units tried by the SGM variant."""


def cell_means(gray: NDArray[np.float32], rows: int, cols: int) -> Grid:
    """Mean grey level of each 4x4 cell of the token grid (rows x cols)."""
    g = gray[: rows * 4, : cols * 4].astype(np.float64)
    return g.reshape(rows, 4, cols, 4).mean(axis=(1, 3))


def fill_two_sided(disparity: Grid, kept: Mask, choose: str, guide: Grid | None = None) -> Grid:
    """Rejected cells take the nearest kept cell on the left or the right: the one with the
    smaller disparity (`background`) or the closer guide value (`gray`); one side if only one
    exists; a row with nothing kept is 0."""
    out = disparity.copy()
    rows, cols = disparity.shape
    for r in range(rows):
        idx = np.flatnonzero(kept[r])
        if idx.size == 0:
            out[r] = 0.0
            continue
        for c in np.flatnonzero(~kept[r]):
            pos = np.searchsorted(idx, c)
            left = idx[pos - 1] if pos > 0 else None
            right = idx[pos] if pos < idx.size else None
            if left is None or right is None:
                src = right if left is None else left
            elif choose == "background":
                src = left if disparity[r, left] <= disparity[r, right] else right
            else:
                assert guide is not None
                dl = abs(guide[r, c] - guide[r, left])
                dr = abs(guide[r, c] - guide[r, right])
                src = left if dl <= dr else right
            out[r, c] = disparity[r, src]
    return out


def sgm_aggregate(cost: Grid, p1: float, p2: float) -> Grid:
    """Sum of the 4 streaming SGM paths (left to right, right to left, top to bottom, top-left
    diagonal) over a (T, P, D) cost volume; +inf costs mark impossible candidates."""
    t, p, _ = cost.shape
    total = np.zeros_like(cost)

    def step(prev: Grid, here: Grid) -> Grid:
        best = prev.min(axis=-1, keepdims=True)
        shifted_lo = np.concatenate([np.full_like(prev[..., :1], np.inf), prev[..., :-1]], axis=-1)
        shifted_hi = np.concatenate([prev[..., 1:], np.full_like(prev[..., :1], np.inf)], axis=-1)
        candidates = np.stack(
            [prev, shifted_lo + p1, shifted_hi + p1, np.broadcast_to(best + p2, prev.shape)]
        )
        return here + candidates.min(axis=0) - best

    for direction in ("lr", "rl"):
        agg = np.zeros_like(cost)
        order = range(p) if direction == "lr" else range(p - 1, -1, -1)
        prev = None
        for x in order:
            agg[:, x] = cost[:, x] if prev is None else step(prev, cost[:, x])
            prev = agg[:, x]
        total += agg
    agg = np.zeros_like(cost)
    for y in range(t):
        agg[y] = cost[y] if y == 0 else step(agg[y - 1], cost[y])
    total += agg
    agg = np.zeros_like(cost)
    for y in range(t):
        if y == 0:
            agg[y] = cost[y]
            continue
        prev = np.concatenate([agg[y - 1, :1], agg[y - 1, :-1]], axis=0)  # from (y-1, x-1)
        agg[y] = step(prev, cost[y])
        agg[y, 0] = cost[y, 0]  # no predecessor on the diagonal
    total += agg
    return total


def sgm_soft_argmin(logits: Grid, p1: float, p2: float) -> Grid:
    """Disparity of 4-path SGM over the cost `-logits` (D, T, P), soft-argmin of the negated
    aggregate (costs normalised per cell so the winning candidate costs 0)."""
    cost = -(logits - logits.max(axis=0, keepdims=True))  # (D, T, P), >= 0
    d = cost.shape[0]
    total = sgm_aggregate(np.transpose(cost, (1, 2, 0)), p1, p2)  # (T, P, D)
    z = -(total - total.min(axis=-1, keepdims=True))
    w = np.exp(z)
    k = np.arange(d, dtype=np.float64)
    return (w * k).sum(axis=-1) / w.sum(axis=-1)


@torch.no_grad()
def score_folder(encoder: BinoEncoder, head: StereoHead, folder: Path) -> dict[str, Any]:
    """{variant: {"mean": metrics, "pairs": {pair: metrics}}} over `folder`'s val pairs."""
    per: dict[str, list[dict[str, float]]] = {}
    names = []
    for pair in load_pairs(folder, "val"):
        left_px, right_px = load_gray(pair.left), load_gray(pair.right)
        gt, valid = load_gt(pair)
        inputs, mirrored = pair_inputs(encoder, head.cfg.pathway, left_px, right_px)
        out = head(*(t[None] for t in inputs))
        left = out.disparity[0].double().numpy()
        logits = out.logits[0].double().numpy()
        right = head(*(t[None] for t in mirrored)).disparity[0].double().numpy()[:, ::-1]
        kept = consistent(left, np.ascontiguousarray(right))
        guide = cell_means(left_px, *left.shape)
        maps: dict[str, Grid] = {
            "none": left,
            "fill-left": fill_rejected(left, kept),
            "fill-background": fill_two_sided(left, kept, "background"),
            "fill-gray": fill_two_sided(left, kept, "gray", guide),
        }
        for p1, p2 in SGM_PENALTIES:
            sgm = sgm_soft_argmin(logits, p1, p2)
            maps[f"sgm-{p1:g}-{p2:g}"] = sgm
            maps[f"sgm-{p1:g}-{p2:g}+fill-left"] = fill_rejected(sgm, kept)
        names.append(pair.pair_id)
        for name, grid in maps.items():
            per.setdefault(name, []).append(
                score(upsample_disparity(grid.astype(np.float32)), gt, valid)
            )
    return per_variant(names, per)


def main(argv: Sequence[str] | None = None) -> None:
    run_cli(__doc__ or "", "export head checkpoint", score_folder, argv)


if __name__ == "__main__":
    main()
