"""Per token cell quantities of the census selector study (census_selector.py).

`pair_cells` runs the native head (one encoder pass) and the census SGM on one resized pair:
the census disparity, its left-right check, uniqueness test, winner's margin and runner-up
(`CensusCells`); the head's disparity, left-right check, softmax peak and entropy; the cell's
ground truth, gradient and ground-truth spread (`PairCells`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
import torch
from numpy.typing import NDArray

from .census_companion import (
    box_sums,
    cell_costs,
    pixel_hamming,
    refine_search,
    right_view,
    wta_parabola,
)
from .head import StereoHead
from .head_eval import consistent, diagonal_right, fill_rejected
from .model import BinoEncoder
from .probe import encoder_phase_maps
from .readout_variants import sgm_aggregate
from .refine import CELL, RefineParams

Grid = NDArray[np.float64]
Mask = NDArray[np.bool_]
Pixels = NDArray[np.float32]

CENSUS_PENALTIES = (32.0, 128.0)
"""`census::DEFAULT_PENALTIES` (P1, P2) in cell-summed Hamming units."""
UNIQUENESS = 10
"""`census::DEFAULT_UNIQUENESS`, percent."""


@dataclass(frozen=True)
class CensusCells:
    """The census SGM of one view pair per token cell."""

    disparity: Grid
    """Left disparity, patch columns (winner with a parabola step, / CELL)."""
    lr: Mask
    """Left-right agreement (`head_eval.consistent`)."""
    unique: Mask
    """The uniqueness test (`bino_core::census::unique`)."""
    margin: Grid
    """(second - best) / second of the aggregate, the second over candidates more than one
    away from the winner, in [0, 1] (1 where there is no such candidate or it costs 0)."""
    runner_up: Grid
    """That second candidate's disparity (patch columns, parabola step): a diagnostic of
    whether the census's own costs hold the answer its winner missed."""

    @property
    def kept(self) -> Mask:
        return self.lr & self.unique


def uniqueness(total: Grid, ratio: int) -> tuple[Mask, Grid]:
    """(unique, margin) of (T, P, N) aggregated costs: unique where every candidate more than one
    away from the lowest costs more than 100 / (100 - ratio) times it (strictly; 0 keeps all);
    the margin is (second - lowest) / second, second the lowest of those candidates."""
    n = total.shape[-1]
    best = total.argmin(axis=-1)
    low = total.min(axis=-1)
    far = np.abs(np.arange(n)[None, None, :] - best[..., None]) > 1
    second = np.where(far, total, np.inf).min(axis=-1)
    has = np.isfinite(second)
    unique = ~has | (second * (100 - ratio) > low * 100) if ratio > 0 else np.ones_like(has)
    safe = np.where(has & (second > 0), second, 1.0)
    margin = np.where(has & (second > 0), (second - low) / safe, 1.0)
    return np.asarray(unique, dtype=bool), np.clip(margin, 0.0, 1.0)


def census_cells(
    hamming: Grid,
    rows: int,
    cols: int,
    penalties: tuple[float, float] = CENSUS_PENALTIES,
    ratio: int = UNIQUENESS,
) -> CensusCells:
    """The census SGM of (H, W, N) pixel distances (`census_companion.pixel_hamming`, no
    clamp): left and right aggregates, the left-right check, uniqueness and margin."""
    p1, p2 = penalties
    left = sgm_aggregate(cell_costs(hamming, rows, cols), p1, p2)
    right = sgm_aggregate(cell_costs(right_view(hamming), rows, cols), p1, p2)
    d_left = wta_parabola(left) / CELL
    d_right = wta_parabola(right) / CELL
    unique, margin = uniqueness(left, ratio)
    n = left.shape[-1]
    far = np.abs(np.arange(n)[None, None, :] - left.argmin(axis=-1)[..., None]) > 1
    ceiling = left.max(axis=-1, keepdims=True) + 1.0
    runner_up = wta_parabola(np.where(far, left, ceiling)) / CELL
    return CensusCells(d_left, consistent(d_left, d_right), unique, margin, runner_up)


def head_stats(logits: Grid) -> tuple[Grid, Grid]:
    """(softmax peak, entropy / log D) per cell of (D, T, P) logits."""
    z = logits - logits.max(axis=0, keepdims=True)
    p = np.exp(z)
    p /= p.sum(axis=0, keepdims=True)
    entropy = -(p * np.log(np.maximum(p, 1e-300))).sum(axis=0)
    return p.max(axis=0), entropy / math.log(logits.shape[0])


def cell_sums(values: Grid, mask: Mask) -> tuple[Grid, Grid]:
    """(sum over `mask`, count of `mask`) of (H, W) pixel values per 4x4 cell (H, W multiples of
    4)."""
    h, w = values.shape
    shape = (h // CELL, CELL, w // CELL, CELL)
    v = np.where(mask, values, 0.0).reshape(shape).sum(axis=(1, 3))
    return v, mask.reshape(shape).sum(axis=(1, 3)).astype(np.float64)


def cell_ground_truth(gt: Pixels, valid: Mask) -> Grid:
    """Median of each cell's valid ground-truth pixels in patch columns (NaN: none valid)."""
    h, w = gt.shape
    blocks = np.where(valid, gt, np.nan).reshape(h // CELL, CELL, w // CELL, CELL)
    flat = blocks.transpose(0, 2, 1, 3).reshape(h // CELL, w // CELL, -1)
    out = np.full(flat.shape[:2], np.nan)
    has = valid.reshape(h // CELL, CELL, w // CELL, CELL).any(axis=(1, 3))
    out[has] = np.nanmedian(flat[has], axis=-1)
    return out / CELL


def cell_gradient(view: NDArray[np.uint8]) -> Grid:
    """Mean |horizontal central difference| / 2 of each cell (grey levels per px)."""
    v = view.astype(np.float64)
    g = np.zeros_like(v)
    g[:, 1:-1] = np.abs(v[:, 2:] - v[:, :-2]) / 2
    s, n = cell_sums(g, np.ones(v.shape, dtype=bool))
    return s / n


PERIOD_SHIFTS = range(1, 17)
"""Horizontal shifts (px) over which `cell_periodicity` looks for the texture repeating."""


def cell_periodicity(view: NDArray[np.uint8]) -> Grid:
    """How strongly the texture around each cell repeats along its row: the largest rise of the
    normalised correlation of a 4 x 20 px window with itself shifted s px (s = 2..16) over its
    lowest value at a smaller shift (0..2). A period of p px gives a dip near p / 2 (close to
    -1) and a peak near p (close to 1): a rise near 2; a smooth ramp's correlation only falls,
    noise wanders by a few tenths."""
    v = view.astype(np.float64)
    h, w = v.shape
    size = (20, CELL)  # (width, height) for OpenCV
    mean_a = cv2.blur(v, size)
    var_a = cv2.blur(v * v, size) - mean_a * mean_a
    corr = []
    for s in PERIOD_SHIFTS:
        b = np.pad(v[:, s:], ((0, 0), (0, s)), mode="edge")
        mean_b = cv2.blur(b, size)
        cov = cv2.blur(v * b, size) - mean_a * mean_b
        var_b = cv2.blur(b * b, size) - mean_b * mean_b
        corr.append(cov / np.sqrt(np.maximum(var_a * var_b, 1e-6)))
    stack = np.stack(corr)  # (shifts, H, W)
    lowest = np.minimum.accumulate(stack, axis=0)
    rise = np.max(stack[1:] - lowest[:-1], axis=0)
    centres = rise[CELL // 2 :: CELL, CELL // 2 :: CELL]
    return np.asarray(centres[: h // CELL, : w // CELL], dtype=np.float64)


def cell_spread(gt: Pixels, valid: Mask) -> Grid:
    """Range (px) of the valid ground truth over each cell and its 8 neighbours (0: none)."""
    h, w = gt.shape
    shape = (h // CELL, CELL, w // CELL, CELL)
    hi = np.where(valid, gt, -np.inf).reshape(shape).max(axis=(1, 3))
    lo = np.where(valid, gt, np.inf).reshape(shape).min(axis=(1, 3))
    rows, cols = hi.shape
    hp = np.pad(hi, 1, constant_values=-np.inf)
    lp = np.pad(lo, 1, constant_values=np.inf)
    hi3 = np.max([hp[i : i + rows, j : j + cols] for i in range(3) for j in range(3)], axis=0)
    lo3 = np.min([lp[i : i + rows, j : j + cols] for i in range(3) for j in range(3)], axis=0)
    return np.where(np.isfinite(hi3) & np.isfinite(lo3), hi3 - lo3, 0.0)


@dataclass(frozen=True)
class PairCells:
    """Everything the study reads of one pair: per-cell quantities and the pixels to score."""

    pair_id: str
    census: CensusCells
    census_nouniq: Grid
    """The census filled from the left by its left-right check alone (`census_companion`)."""
    head: Grid
    head_kept: Mask
    head_peak: Grid
    head_entropy: Grid
    gt_cell: Grid
    gradient: Grid
    spread: Grid
    periodicity: Grid
    """`cell_periodicity` of the left view."""
    gt: Pixels
    valid: Mask
    boxed: Grid
    """`census_companion.box_sums` of the refinement's distances."""
    search: int


def pair_cells(
    encoder: BinoEncoder,
    head: StereoHead,
    pair_id: str,
    left_u8: NDArray[np.uint8],
    right_u8: NDArray[np.uint8],
    gt: Pixels,
    valid: Mask,
) -> PairCells:
    """Runs the native head (one encoder pass) and the census SGM on one resized pair."""
    left_px = left_u8.astype(np.float32) / np.float32(255.0)
    right_px = right_u8.astype(np.float32) / np.float32(255.0)
    with torch.no_grad():
        out = head(*(t[None] for t in encoder_phase_maps(encoder, left_px, right_px)))
    dh = out.disparity[0].double().numpy()
    logits = out.logits[0].double().numpy()
    kh = consistent(dh, diagonal_right(logits))
    peak, entropy = head_stats(logits)
    rows, cols = dh.shape
    n = CELL * head.cfg.max_disp
    cc = census_cells(pixel_hamming(left_u8, right_u8, n, False), rows, cols)
    boxed = box_sums(pixel_hamming(left_u8, right_u8, n + 8, True), RefineParams().box_radius)
    return PairCells(
        pair_id=pair_id,
        census=cc,
        census_nouniq=fill_rejected(cc.disparity, cc.lr),
        head=dh,
        head_kept=kh,
        head_peak=peak,
        head_entropy=entropy,
        gt_cell=cell_ground_truth(gt, valid),
        gradient=cell_gradient(left_u8),
        spread=cell_spread(gt, valid),
        periodicity=cell_periodicity(left_u8),
        gt=gt,
        valid=valid,
        boxed=boxed,
        search=refine_search(left_u8.shape[1]),
    )
