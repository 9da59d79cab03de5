"""A classical second opinion for the native pathway, tried in float before any goes into the
integer core: census costs of the views' pixels, aggregated per 4x4 cell, 4-path SGM, fused with
the native head as `fuse+lr` fuses the export head with its descriptor SGM (issue 41: the native
pathway has one encoder pass and no descriptors, so no `sgm` of its own).

    python -m bino_train.census_companion --encoder E --head H --folders DIR ... [--out J]

Per pair (folders from `labeled_folder` / `synth_folder` / `val_folder`, split `val`):
- the native head on the encoder's one pass on (L, R), its right view from its own logits
  (`head_eval.diagonal_right`) and its left-right check;
- `census`: 5x5 census codes of both grey views (`refine.census`), the Hamming distance of every
  pixel at every pixel disparity 0 .. 4 D - 1 (D the head's candidates; a right pixel outside
  the view costs the maximum), summed over each 4x4 cell: a (T, P, 4 D) cost volume. The right
  view's volume comes from the same distances (right pixel x at d is left pixel x + d at d).
  Both are aggregated by the core's four streaming SGM paths (`readout_variants.sgm_aggregate`)
  with penalties P1 / P2 in cell-summed Hamming units, winner-take-all with a parabola step,
  divided by 4 into patch columns; each checked against the other (`head_eval.consistent`);
- `fuse`: `bino_core::lr::fuse_row`'s rule: the mean weighted by the head's share where both
  checks pass, the one that passes where only one does, rejected (filled from the left) where
  neither does. The share follows the head's confidence as the core's (`fuse_head_weight`);
- every map refined to pixels by `refine.refine_float`'s search (on the distances above, box
  sums by OpenCV; the search radius of `RefineParams::for_width`), rejected cells keeping
  their bilinear step.

Scored with EVAL.md's metrics against each folder's ground truth (mean over pairs).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from numpy.typing import NDArray

from .folder_scoring import per_variant, run_cli
from .head import StereoHead
from .head_eval import consistent, diagonal_right, fill_rejected
from .model import BinoEncoder
from .pairs import load_gray, load_gray_u8, load_gt, load_pairs
from .probe import encoder_phase_maps, score
from .readout_variants import sgm_aggregate
from .refine import CELL, RefineParams, _popcount, census, upsample_float

Grid = NDArray[np.float64]
Mask = NDArray[np.bool_]

CENSUS_RADIUS = 2
"""5x5 census: 24 bits, the refinement's."""
OUTSIDE_COST = 24
"""Hamming distance charged to a pixel whose match lies outside the right view."""
PENALTIES = ((16.0, 64.0), (32.0, 128.0), (64.0, 256.0), (128.0, 512.0))
"""(P1, P2) in cell-summed Hamming units (a cell sums 16 pixels of 0..24)."""
HEAD_SHARES = (0.5, 0.625, 0.75)
"""The head's base share where both checks pass."""
CONFIDENCE_SLOPE = 0.25
"""The share moves by this times (head confidence - 1/2), as `lr::FUSE_CONFIDENCE_SLOPE_INV`."""


def pixel_hamming(
    left: NDArray[np.uint8], right: NDArray[np.uint8], disparities: int, clamp: bool
) -> Grid:
    """(H, W, N) census Hamming distance of left pixel (y, x) and right pixel (y, x - d); a
    right pixel left of the view is the view's first (`clamp`, the refinement's rule) or costs
    the maximum."""
    cl = census(left, CENSUS_RADIUS)
    cr = census(right, CENSUS_RADIUS)
    h, w = left.shape
    out = np.full((h, w, disparities), float(OUTSIDE_COST))
    for d in range(min(disparities, w)):
        out[:, d:, d] = _popcount(cl[:, d:] ^ cr[:, : w - d])
        if clamp:
            out[:, :d, d] = _popcount(cl[:, :d] ^ cr[:, :1])
    return out


def right_view(hamming: Grid) -> Grid:
    """The right view's (H, W, N) distances: right pixel x at d is left pixel x + d at d."""
    _, w, n = hamming.shape
    out = np.full_like(hamming, float(OUTSIDE_COST))
    for d in range(min(n, w)):
        out[:, : w - d, d] = hamming[:, d:, d]
    return out


def cell_costs(hamming: Grid, rows: int, cols: int) -> Grid:
    """(T, P, N) sums of the distances over each 4x4 cell."""
    h = hamming[: rows * CELL, : cols * CELL]
    return h.reshape(rows, CELL, cols, CELL, -1).sum(axis=(1, 3))


def wta_parabola(total: Grid) -> Grid:
    """(T, P) lowest-cost candidate of (T, P, N) with a parabola step of at most half."""
    n = total.shape[-1]
    best = total.argmin(axis=-1)
    lo = np.take_along_axis(total, np.clip(best - 1, 0, n - 1)[..., None], -1)[..., 0]
    at = np.take_along_axis(total, best[..., None], -1)[..., 0]
    hi = np.take_along_axis(total, np.clip(best + 1, 0, n - 1)[..., None], -1)[..., 0]
    denom = lo - 2 * at + hi
    inner = (best >= 1) & (best <= n - 2) & (denom > 0)
    step = np.where(inner, (lo - hi) / (2 * np.where(inner, denom, 1.0)), 0.0)
    return best + np.clip(step, -0.5, 0.5)


def census_sgm(hamming: Grid, rows: int, cols: int) -> dict[tuple[float, float], tuple[Grid, Mask]]:
    """{(P1, P2): (left disparity in patch columns, its left-right kept mask)} from the
    (H, W, N) distances of `pixel_hamming`, N = 4 x the candidates."""
    costs_left = cell_costs(hamming, rows, cols)
    costs_right = cell_costs(right_view(hamming), rows, cols)
    out = {}
    for p1, p2 in PENALTIES:
        d_left = wta_parabola(sgm_aggregate(costs_left, p1, p2)) / CELL
        d_right = wta_parabola(sgm_aggregate(costs_right, p1, p2)) / CELL
        out[(p1, p2)] = (d_left, consistent(d_left, d_right))
    return out


def fuse(
    head: tuple[Grid, Mask], confidence: Grid, other: tuple[Grid, Mask], share: float
) -> tuple[Grid, Mask]:
    """`fuse_row`'s rule on whole grids, then the fill from the left of cells neither keeps."""
    (dh, kh), (ds, ks) = head, other
    w = np.clip(share + CONFIDENCE_SLOPE * (confidence - 0.5), 0.0, 1.0)
    both = w * dh + (1 - w) * ds
    fused = np.where(kh & ks, both, np.where(kh, dh, ds))
    kept = kh | ks
    return fill_rejected(fused, kept), kept


def box_sums(hamming: Grid, radius: int) -> Grid:
    """(H, W, N) sums of each disparity's distances over the (2r + 1)^2 box around each pixel,
    edges replicated (the refinement's clamped box)."""
    size = 2 * radius + 1
    out = np.empty(hamming.shape, dtype=np.float64)
    for d in range(hamming.shape[-1]):
        out[..., d] = cv2.boxFilter(
            np.ascontiguousarray(hamming[..., d]),
            cv2.CV_64F,
            (size, size),
            normalize=False,
            borderType=cv2.BORDER_REPLICATE,
        )
    return out


def refined(boxed: Grid, grid: Grid, kept: Mask, search: int) -> NDArray[np.float32]:
    """`refine_float`'s search on precomputed box sums (every box pixel at the centre's d,
    a match outside the right view charged the maximum), then the pixels of rejected cells
    keep the bilinear step of the filled grid."""
    h, w, n = boxed.shape
    lam = float(RefineParams().lam)
    d0 = upsample_float(grid, h, w)
    base = np.floor(d0 + 0.5).astype(np.int64)
    xs = np.arange(w)[None, :]
    best_k = np.full((h, w), -(search + 1), dtype=np.int64)
    best_cost = np.full((h, w), np.inf)
    costs = {}
    for k in [0] + [s * k for k in range(1, search + 1) for s in (-1, 1)]:
        d = base + k
        ok = (d >= 0) & (d <= xs) & (d < n)
        c = np.take_along_axis(boxed, np.clip(d, 0, n - 1)[..., None], -1)[..., 0]
        c = np.where(ok, c + lam * np.abs(d - d0), np.inf)
        costs[k] = c
        take = c < best_cost
        best_k = np.where(take, k, best_k)
        best_cost = np.where(take, c, best_cost)
    found = np.isfinite(best_cost)
    inf = np.full((h, w), np.inf)

    def at(offset: int) -> Grid:
        out = inf.copy()
        for k, c in costs.items():
            out = np.where(best_k + offset == k, c, out)
        return out

    lo, hi = at(-1), at(1)
    both = found & np.isfinite(lo) & np.isfinite(hi)
    lo, hi, at0 = (np.where(both, v, 0.0) for v in (lo, hi, best_cost))
    denom = lo - 2 * at0 + hi
    step = both & (denom > 0)
    offset = np.where(step, (lo - hi) / (2 * np.where(step, denom, 1.0)), 0.0)
    out = np.where(found, np.maximum(base + best_k + np.clip(offset, -0.5, 0.5), 0.0), d0)
    rows = np.minimum(np.arange(h) // CELL, kept.shape[0] - 1)
    cols = np.minimum(np.arange(w) // CELL, kept.shape[1] - 1)
    return np.where(kept[rows][:, cols], out, d0).astype(np.float32)


def refine_search(width: int) -> int:
    """`RefineParams::for_width`: 2 px below 200 px of width, round(width / 80) from there."""
    return 2 if width < 200 else min(max(round(width / 80), 2), 8)


@torch.no_grad()
def score_folder(encoder: BinoEncoder, head: StereoHead, folder: Path) -> dict[str, Any]:
    """{readout: {"mean": metrics, "pairs": {pair: metrics}}} over `folder`'s val pairs."""
    per: dict[str, list[dict[str, float]]] = {}
    names = []
    for pair in load_pairs(folder, "val"):
        left_px, right_px = load_gray(pair.left), load_gray(pair.right)
        left_u8, right_u8 = load_gray_u8(pair.left), load_gray_u8(pair.right)
        gt, valid = load_gt(pair)
        search = refine_search(left_px.shape[1])
        out = head(*(t[None] for t in encoder_phase_maps(encoder, left_px, right_px)))
        dh = out.disparity[0].double().numpy()
        logits = out.logits[0].double().numpy()
        confidence = out.confidence[0].double().numpy()
        kh = consistent(dh, diagonal_right(logits))
        rows, cols = dh.shape
        maps: dict[str, tuple[Grid, Mask]] = {"head+lr+ref": (fill_rejected(dh, kh), kh)}
        n = CELL * head.cfg.max_disp
        boxed = box_sums(pixel_hamming(left_u8, right_u8, n + 8, True), RefineParams().box_radius)
        sgm_hamming = pixel_hamming(left_u8, right_u8, n, False)
        for (p1, p2), (ds, ks) in census_sgm(sgm_hamming, rows, cols).items():
            tag = f"{p1:g}/{p2:g}"
            maps[f"census{tag}+lr+ref"] = (fill_rejected(ds, ks), ks)
            for share in HEAD_SHARES:
                maps[f"fuse{tag}@{share:g}+lr+ref"] = fuse((dh, kh), confidence, (ds, ks), share)
        names.append(pair.pair_id)
        for name, (grid, kept) in maps.items():
            pred = refined(boxed, grid, kept, search)
            per.setdefault(name, []).append(score(pred, gt, valid))
    return per_variant(names, per)


def main(argv: Sequence[str] | None = None) -> None:
    run_cli(__doc__ or "", "native head checkpoint", score_folder, argv)


if __name__ == "__main__":
    main()
