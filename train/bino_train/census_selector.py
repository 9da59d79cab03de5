"""Can a learned readout that starts from the census and corrects it earn its cost (issue 54)?

    python -m bino_train.census_selector --width 160 --out J [--encoder E --head H --data DIR]

The crate's encoder-free readout `census+lr+ref` (census SGM of the pixels, its own left-right
check and uniqueness test, rejected cells filled from the left, integer pixel refinement) beats
every learned readout on the real labeled pairs. This study asks whether a per-cell choice
between the census cell and the native head's cell can beat it by a real margin (target: epe at
most 0.85 x the census's, bad1tok below it), in float, on the clean labeled pairs: the
`labeled.LABELED_HOLDOUT` pairs, four MiddEval3-Q pairs and `mb2006_Monopoly`, no head trained
on them, each resized to `--width` by the EVAL.md profile rule (in memory, as
`labeled_folder` writes them), the head searching `head.head_candidates(width)` columns.

Per token cell (`PairCells`): the census disparity (`census_companion`'s float twin with the
core's penalties `census::DEFAULT_PENALTIES` and uniqueness `census::DEFAULT_UNIQUENESS`), its
left-right agreement, its uniqueness and its winner's margin (the best candidate more than one
away from the winner minus the winner, over the former: the quantity the uniqueness test
thresholds); the native head's disparity, its softmax peak, its normalised entropy and its own
left-right check (`head_eval.diagonal_right`); the ground truth (median of the cell's valid
pixels, in patch columns); the left view's horizontal gradient and the ground truth's spread.

Readouts, each refined to pixels as `census_companion` does and scored by EVAL.md's metrics:
- `census+lr+ref` (the baseline), `head+lr+ref`, `fuse-census+lr+ref` (share 1/2 moved by the
  head's confidence, `census::FUSE_HEAD_WEIGHT`); `census-nouniq+lr+ref` ties the numbers to
  `census_companion`'s (it has no uniqueness test);
- `oracle(census|head)+ref`: each cell the census+lr or the head+lr cell, the one closer to the
  cell's ground truth, then refined; `oracle(census|head|fuse)+ref` the same over three;
  `oracle-px(...)`: each cell's pixels from whichever refined map is better on them (the bound
  of a choice made after refining both); `gt-cells+ref`: the ground truth's own cells refined
  (what the refinement leaves of a perfect cell readout);
- `select(census|head)+ref`: a logistic per-cell selector on `FEATURES`, trained leave-one-pair-
  out (each pair scored by the selector fitted on the other four), started at (and pulled by its
  L2 prior towards) the census path: zero weights, bias `INIT_BIAS`; each cell labelled by the
  side whose refined pixels are better and weighted by what that changes its pair's epe. Each
  fold chooses its L2 and logit threshold (`SETTINGS`) by leave-one-pair-out over its own four
  pairs and keeps the census path where no setting gains (`fit_fold`). `select-q8` is the same
  selector with its weights and features in Q8 (`choose_q8`: integer arithmetic, as a no_std
  core would run it); `select-plain` the fit at `--l2` with threshold 0, no choice;
  `select-insample` one fit on all five pairs scored on them (an optimistic bound of the feature
  set, not a held-out number). `select...(census|fuse)` the same against the fused cell;
- diagnostics of what else could move the census: `oracle(census|runner-up)+ref` (the census's
  own best candidate more than one column from its winner, chosen by the ground truth),
  `oracle(census|runner-up|head)+ref`, `census+lr(bg-fill)+ref` (rejected cells filled with the
  lower of their kept neighbours left and right, `fill_background`) and
  `census-nouniq+lr(bg-fill)+ref`.

Conditions (cells, pooled pixels of the five pairs): textureless (mean horizontal gradient of
the left view below `TEXTURELESS_GRADIENT` grey levels per px), near a discontinuity (valid ground
truth over the cell and its 8 neighbours spanning more than `DISCONTINUITY_PX`), large disparity
(cell ground truth above its pair's median) and census-rejected, each with the epe / bad1tok of
every readout above.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray

from .census_companion import (
    box_sums,
    cell_costs,
    fuse,
    pixel_hamming,
    refine_search,
    refined,
    right_view,
    wta_parabola,
)
from .head import StereoHead, head_candidates, load_head, with_candidates
from .head_eval import consistent, diagonal_right, fill_rejected
from .labeled import LABELED_HOLDOUT, labeled_pairs, load_checked_gt
from .model import BinoEncoder
from .pairs import Pair, load_gray
from .probe import encoder_phase_maps, mean_metrics, score
from .profile import resize_gt, resize_image, to_u8
from .readout_variants import sgm_aggregate
from .refine import CELL, RefineParams

Grid = NDArray[np.float64]
Mask = NDArray[np.bool_]
Pixels = NDArray[np.float32]

CLEAN_PAIRS = LABELED_HOLDOUT
"""Labeled train pairs no head was trained on (never the eval split)."""
CENSUS_PENALTIES = (32.0, 128.0)
"""`census::DEFAULT_PENALTIES` (P1, P2) in cell-summed Hamming units."""
UNIQUENESS = 10
"""`census::DEFAULT_UNIQUENESS`, percent."""
FUSE_SHARE = 0.5
"""`census::FUSE_HEAD_WEIGHT` / 256: the head's share in `fuse-census`."""
DISAGREEMENT_CLIP = 4.0
"""|head - census| (patch columns) at which the disagreement feature saturates at 1."""
FEATURES = (
    "census_kept",
    "census_lr",
    "census_margin",
    "head_kept",
    "head_peak",
    "head_entropy",
    "disagreement",
    "head_only_kept",
)
"""The selector's features, each in [0, 1] (Q8-friendly): the census check (left-right and
uniqueness) and its left-right part alone, the census winner's margin, the head's check, its
softmax peak and normalised entropy, |head+lr - census+lr| / DISAGREEMENT_CLIP clipped to 1, and
head kept where the census is not."""
INIT_BIAS = -4.0
"""The selector's starting bias: every cell the census's (the head is taken only where the
features argue for it)."""
L2 = 1e-3
"""The fit's L2 pull towards the starting selector (per unit of mean cell weight)."""
INSAMPLE_L2 = 1e-4
"""L2 of the in-sample selector (fitted and scored on the same pairs: an optimistic bound of
what this feature set can do, not a held-out result)."""
SETTINGS = tuple((l2, threshold) for l2 in (1e-3, 1e-2, 1e-1) for threshold in (0.0, 1.0, 2.0))
"""(L2, logit threshold) pairs a fold chooses from by leave-one-pair-out on its own training
pairs (`fit_fold`); the threshold is folded into the bias. A fold none of them helps keeps the
census selector."""
Q8 = 256
TEXTURELESS_GRADIENT = 2.0
"""Mean |horizontal gradient| of a cell (grey levels per px, central differences) below which a
cell counts as textureless."""
DISCONTINUITY_PX = 2.0
"""Spread (px) of the valid ground truth over a cell and its 8 neighbours above which a cell
counts as near a discontinuity."""


# --- per-cell quantities -------------------------------------------------------------------


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
        gt=gt,
        valid=valid,
        boxed=boxed,
        search=refine_search(left_u8.shape[1]),
    )


# --- readouts ------------------------------------------------------------------------------

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
    kept): a classical alternative to `fill_rejected`'s left fill."""
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


# --- the selector --------------------------------------------------------------------------


def features(c: PairCells, other: Readout | None = None) -> Grid:
    """(T, P, F) `FEATURES` of one pair, each in [0, 1]; `other` is the cell the selector may
    take instead of the census (default head+lr)."""
    cc = c.census
    census = fill_rejected(cc.disparity, cc.kept)
    alt = other if other is not None else (fill_rejected(c.head, c.head_kept), c.head_kept)
    disagreement = np.clip(np.abs(alt[0] - census) / DISAGREEMENT_CLIP, 0.0, 1.0)
    kc = cc.kept.astype(np.float64)
    kh = c.head_kept.astype(np.float64)
    columns = (
        kc,
        cc.lr.astype(np.float64),
        cc.margin,
        kh,
        c.head_peak,
        np.clip(c.head_entropy, 0.0, 1.0),
        disagreement,
        kh * (1.0 - kc),
    )
    return np.stack(columns, axis=-1)


@dataclass(frozen=True)
class Selector:
    """A logistic per-cell choice: the other cell where `features @ weights + bias > 0`."""

    weights: NDArray[np.float64]
    bias: float

    def logits(self, x: Grid) -> Grid:
        return np.asarray(x @ self.weights + self.bias)

    def choose(self, x: Grid) -> Mask:
        return np.asarray(self.logits(x) > 0)

    def to_json(self) -> dict[str, Any]:
        return {
            "weights": dict(zip(FEATURES, map(float, self.weights), strict=True)),
            "bias": float(self.bias),
            "weights_q8": [int(v) for v in np.rint(self.weights * Q8)],
            "bias_q8": int(np.rint(self.bias * Q8)),
        }


def census_selector(features_count: int = len(FEATURES), bias: float = INIT_BIAS) -> Selector:
    """The selector that keeps every census cell: zero weights, a negative bias."""
    if bias >= 0:
        raise ValueError(f"a census-first selector needs a negative bias, not {bias}")
    return Selector(np.zeros(features_count), bias)


def choose_q8(selector: Selector, x: Grid) -> Mask:
    """`Selector.choose` in integers: features and weights rounded to Q8, the bias to Q16
    (i64 sums, as a fixed-point core computes them)."""
    fq = np.rint(np.clip(x, 0.0, 1.0) * Q8).astype(np.int64)
    wq = np.rint(selector.weights * Q8).astype(np.int64)
    bq = int(np.rint(selector.bias * Q8)) * Q8
    return np.asarray(fq @ wq + bq > 0)


def fit_selector(
    x: NDArray[np.float64],
    label: Mask,
    weight: NDArray[np.float64],
    prior: Selector | None = None,
    l2: float = L2,
    iterations: int = 50,
) -> Selector:
    """Weighted logistic regression by Newton steps: minimises the weighted mean log-loss of
    `label` (True: take the other cell) plus `l2 / 2 |theta - prior|^2` (theta the weights and
    bias). Weights are normalised to mean 1 over cells with positive weight."""
    prior = prior or census_selector(x.shape[1])
    keep = weight > 0
    if not keep.any():
        return prior
    xs = np.concatenate([x[keep], np.ones((int(keep.sum()), 1))], axis=1)
    y = label[keep].astype(np.float64)
    w = weight[keep] / weight[keep].mean()
    n = float(len(y))
    theta0 = np.append(prior.weights, prior.bias)

    def objective(t: NDArray[np.float64]) -> float:
        z = xs @ t
        loss = np.logaddexp(0.0, z) - y * z
        return float((w * loss).sum() / n + 0.5 * l2 * ((t - theta0) ** 2).sum())

    theta = theta0.copy()
    value = objective(theta)
    for _ in range(iterations):
        p = 1.0 / (1.0 + np.exp(-np.clip(xs @ theta, -40, 40)))
        grad = xs.T @ (w * (p - y)) / n + l2 * (theta - theta0)
        hess = (xs * (w * p * (1 - p))[:, None]).T @ xs / n + l2 * np.eye(len(theta))
        step = np.linalg.solve(hess, grad)
        # Damped Newton: halve the step until the objective does not rise.
        scale = 1.0
        while scale > 1e-6 and objective(theta - scale * step) > value:
            scale /= 2
        theta = theta - scale * step
        new = objective(theta)
        if value - new < 1e-12:
            break
        value = new
    return Selector(theta[:-1], float(theta[-1]))


def training_cells(
    c: PairCells, census_pred: Pixels, other_pred: Pixels, other: Readout | None = None
) -> tuple[NDArray[np.float64], Mask, NDArray[np.float64]]:
    """(features, label, weight) of one pair's cells: label where the other refined map's
    cell error is below the census's, weighted by what taking it changes the pair's epe (the
    difference of the cells' summed pixel errors over the pair's valid pixels: every pair
    weighs as in the mean over pairs); cells with no valid pixel weigh 0."""
    sc, n = cell_errors(census_pred, c)
    so, _ = cell_errors(other_pred, c)
    diff = (sc - so) / max(float(n.sum()), 1.0)
    f = features(c, other)
    return f.reshape(-1, f.shape[-1]), (diff > 0).reshape(-1), np.abs(diff).reshape(-1)


Cells = tuple[NDArray[np.float64], Mask, NDArray[np.float64]]
"""`training_cells`' (features, label, weight) of one pair."""


def epe_gain(take: Mask, cells: Cells) -> float:
    """How much taking the other cell where `take` lowers the pair's epe (px, to first order:
    each cell's refined pixels as refined in its own map)."""
    _, label, weight = cells
    return float((np.where(label, weight, -weight) * take).sum())


def fit_pairs(cells: Sequence[Cells], l2: float = L2) -> Selector:
    """`fit_selector` on the cells of several pairs together."""
    x = np.concatenate([c[0] for c in cells])
    label = np.concatenate([c[1] for c in cells])
    weight = np.concatenate([c[2] for c in cells])
    return fit_selector(x, label, weight, l2=l2)


def fit_fold(
    train: Sequence[Cells], settings: Sequence[tuple[float, float]] = SETTINGS
) -> tuple[Selector, dict[str, Any]]:
    """A selector from `train`'s pairs: each (L2, threshold) of `settings` scored by leave-one-
    pair-out over them (mean `epe_gain` on the left-out pair), the best refitted on all and its
    threshold folded into the bias; the census selector where none gains (the census path when
    unsure)."""
    gains = []
    for l2, threshold in settings:
        total = 0.0
        for i, held in enumerate(train):
            rest = [d for j, d in enumerate(train) if j != i]
            sel = fit_pairs(rest, l2)
            total += epe_gain(sel.logits(held[0]) > threshold, held)
        gains.append(total / len(train))
    best = int(np.argmax(gains))
    info: dict[str, Any] = {
        "inner_gain_px": {f"{l2:g}@{t:g}": g for (l2, t), g in zip(settings, gains, strict=True)}
    }
    if gains[best] <= 0:
        info["setting"] = "census"
        return census_selector(train[0][0].shape[1]), info
    l2, threshold = settings[best]
    sel = fit_pairs(train, l2)
    info["setting"] = f"{l2:g}@{threshold:g}"
    return Selector(sel.weights, sel.bias - threshold), info


# --- conditions ----------------------------------------------------------------------------


def conditions(c: PairCells) -> dict[str, Mask]:
    """Cell masks of the study's conditions."""
    known = np.isfinite(c.gt_cell)
    median = np.nanmedian(c.gt_cell) if known.any() else 0.0
    return {
        "all": np.ones(c.gt_cell.shape, dtype=bool),
        "textureless": c.gradient < TEXTURELESS_GRADIENT,
        "discontinuity": c.spread > DISCONTINUITY_PX,
        "large_disparity": known & (c.gt_cell > median),
        "census_rejected": ~c.census.kept,
    }


def pixels_of(cells: Mask) -> Mask:
    return np.repeat(np.repeat(cells, CELL, axis=0), CELL, axis=1)


def condition_table(
    pairs: Sequence[PairCells], preds: dict[str, list[Pixels]]
) -> dict[str, dict[str, Any]]:
    """{condition: {"cells_pct", "pixels", readout: {epe, bad1tok}}}, pooled over the pairs'
    valid pixels."""
    out: dict[str, dict[str, Any]] = {}
    masks = [conditions(c) for c in pairs]
    for name in masks[0]:
        cells = sum(int(m[name].sum()) for m in masks)
        total = sum(m[name].size for m in masks)
        where = [pixels_of(m[name]) & c.valid for m, c in zip(masks, pairs, strict=True)]
        row: dict[str, Any] = {
            "cells_pct": 100.0 * cells / total,
            "pixels": int(sum(int(w.sum()) for w in where)),
        }
        for readout, maps in preds.items():
            err = np.concatenate(
                [np.abs(p[w] - c.gt[w]) for p, w, c in zip(maps, where, pairs, strict=True)]
            )
            row[readout] = (
                {"epe": float(err.mean()), "bad1tok": float(100 * (err > 4.0).mean())}
                if err.size
                else None
            )
        out[name] = row
    return out


# --- the study -----------------------------------------------------------------------------


def clean_pairs(data_dir: Path | None, names: Sequence[str] = CLEAN_PAIRS) -> list[Pair]:
    """The labeled train pairs named (never the eval split: `labeled.labeled_pairs` reads the
    train split only), in `names`' order."""
    found = {p.pair_id: p for p in labeled_pairs(data_dir)}
    missing = [n for n in names if n not in found]
    if missing:
        raise ValueError(f"not labeled train pairs here: {', '.join(missing)}")
    return [found[n] for n in names]


def load_resized(
    pair: Pair, width: int
) -> tuple[NDArray[np.uint8], NDArray[np.uint8], Pixels, Mask]:
    """Both views and the ground truth at `width` by the EVAL.md profile rule (as
    `labeled_folder` writes them)."""
    grays = [load_gray(p) for p in (pair.left, pair.right)]
    disparity, valid = load_checked_gt(pair, grays[0].shape)
    left, right = (to_u8(resize_image(g, width)) for g in grays)
    gt, ok = resize_gt(disparity, valid, width)
    if gt.shape != left.shape:
        raise AssertionError(f"{pair.pair_id}: labels {gt.shape} vs view {left.shape}")
    return left, right, gt, ok


def study(pairs: Sequence[PairCells], l2: float = L2) -> dict[str, Any]:
    """Every readout's scores (mean and per pair), the selectors' folds and the conditions."""
    names = [c.pair_id for c in pairs]
    bases = [base_readouts(c) for c in pairs]
    grids: dict[str, list[Readout]] = {
        "census+lr+ref": [b["census"] for b in bases],
        "head+lr+ref": [b["head"] for b in bases],
        "fuse-census+lr+ref": [b["fuse"] for b in bases],
        "census-nouniq+lr+ref": [(c.census_nouniq, c.census.lr) for c in pairs],
    }
    two = [[b["census"], b["head"]] for b in bases]
    three = [[b["census"], b["head"], b["fuse"]] for b in bases]
    grids["oracle(census|head)+ref"] = [
        select(r, oracle_choice(r, c.gt_cell)) for r, c in zip(two, pairs, strict=True)
    ]
    grids["oracle(census|head|fuse)+ref"] = [
        select(r, oracle_choice(r, c.gt_cell)) for r, c in zip(three, pairs, strict=True)
    ]
    runner = [
        [b["census"], (fill_rejected(c.census.runner_up, c.census.kept), c.census.kept)]
        for c, b in zip(pairs, bases, strict=True)
    ]
    grids["oracle(census|runner-up)+ref"] = [
        select(r, oracle_choice(r, c.gt_cell)) for r, c in zip(runner, pairs, strict=True)
    ]
    grids["oracle(census|runner-up|head)+ref"] = [
        select(r + [b["head"]], oracle_choice(r + [b["head"]], c.gt_cell))
        for r, b, c in zip(runner, bases, pairs, strict=True)
    ]
    grids["census+lr(bg-fill)+ref"] = [
        (fill_background(c.census.disparity, c.census.kept), c.census.kept) for c in pairs
    ]
    grids["census-nouniq+lr(bg-fill)+ref"] = [
        (fill_background(c.census.disparity, c.census.lr), c.census.lr) for c in pairs
    ]
    grids["gt-cells+ref"] = [
        (np.where(np.isfinite(c.gt_cell), c.gt_cell, b["census"][0]), np.ones_like(c.census.kept))
        for c, b in zip(pairs, bases, strict=True)
    ]
    preds: dict[str, list[Pixels]] = {
        name: [refined(c.boxed, g, k, c.search) for c, (g, k) in zip(pairs, rows, strict=True)]
        for name, rows in grids.items()
    }
    base_preds = {
        k: preds[f"{k}+lr+ref" if k != "fuse" else "fuse-census+lr+ref"] for k in bases[0]
    }
    preds["oracle-px(census|head)"] = [
        pixel_oracle([base_preds["census"][i], base_preds["head"][i]], c)
        for i, c in enumerate(pairs)
    ]
    preds["oracle-px(census|head|fuse)"] = [
        pixel_oracle([base_preds[k][i] for k in ("census", "head", "fuse")], c)
        for i, c in enumerate(pairs)
    ]
    shares: dict[str, list[float]] = {
        "oracle(census|head)+ref": [
            float(100 * oracle_choice(r, c.gt_cell).mean()) for r, c in zip(two, pairs, strict=True)
        ]
    }
    selectors: dict[str, Any] = {}
    for other in ("head", "fuse"):
        data = [
            training_cells(c, base_preds["census"][i], base_preds[other][i], bases[i][other])
            for i, c in enumerate(pairs)
        ]
        feats = [features(c, bases[i][other]) for i, c in enumerate(pairs)]
        folds: dict[str, Any] = {}
        variants = ("", "-q8", "-plain", "-insample")
        for v in variants:
            preds[f"select{v}(census|{other})+ref"] = []
            shares[f"select{v}(census|{other})+ref"] = []
        everything = fit_pairs(data, l2)
        insample = fit_pairs(data, INSAMPLE_L2)
        for i, c in enumerate(pairs):
            rest = [d for j, d in enumerate(data) if j != i]
            chosen, info = fit_fold(rest)
            plain = fit_pairs(rest, l2)
            folds[c.pair_id] = {
                **info,
                "selector": chosen.to_json(),
                "plain": plain.to_json(),
            }
            takes = {
                "": chosen.choose(feats[i]),
                "-q8": choose_q8(chosen, feats[i]),
                "-plain": plain.choose(feats[i]),
                "-insample": insample.choose(feats[i]),
            }
            for v, take in takes.items():
                name = f"select{v}(census|{other})+ref"
                g, k = select([bases[i]["census"], bases[i][other]], take.astype(np.int64))
                preds[name].append(refined(c.boxed, g, k, c.search))
                shares[name].append(float(100 * take.mean()))
        selectors[other] = {
            "folds": folds,
            "plain_all_pairs": everything.to_json(),
            "insample": insample.to_json(),
        }
    per = {
        name: [score(p, c.gt, c.valid) for p, c in zip(maps, pairs, strict=True)]
        for name, maps in preds.items()
    }
    baseline = mean_metrics(per["census+lr+ref"])
    readouts = {
        name: {
            "mean": mean_metrics(rows),
            "epe_over_census": mean_metrics(rows)["epe"] / baseline["epe"],
            "pairs": dict(zip(names, rows, strict=True)),
            **(
                {"other_cell_pct": dict(zip(names, shares[name], strict=True))}
                if name in shares
                else {}
            ),
        }
        for name, rows in per.items()
    }
    lr_keep = {
        "census": [float(100 * c.census.kept.mean()) for c in pairs],
        "census_lr_only": [float(100 * c.census.lr.mean()) for c in pairs],
        "head": [float(100 * c.head_kept.mean()) for c in pairs],
    }
    cond_preds = {k: preds[k] for k in CONDITION_READOUTS}
    return {
        "pairs": names,
        "target": {"epe": 0.85 * baseline["epe"], "bad1tok_below": baseline["bad1tok"]},
        "readouts": readouts,
        "kept_pct": {k: dict(zip(names, v, strict=True)) for k, v in lr_keep.items()},
        "selectors": {"features": list(FEATURES), "init_bias": INIT_BIAS, "l2": l2, **selectors},
        "conditions": condition_table(pairs, cond_preds),
    }


CONDITION_READOUTS = (
    "census+lr+ref",
    "head+lr+ref",
    "fuse-census+lr+ref",
    "oracle(census|head)+ref",
    "oracle-px(census|head)",
    "oracle(census|head|fuse)+ref",
    "select-q8(census|head)+ref",
    "select-q8(census|fuse)+ref",
    "select-insample(census|head)+ref",
)


def main(argv: Sequence[str] | None = None) -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    root = Path(__file__).resolve().parents[1]
    p.add_argument("--width", type=int, required=True, help="view width (160 or 320)")
    p.add_argument("--out", type=Path, required=True, help="JSON to write")
    p.add_argument(
        "--encoder",
        type=Path,
        default=root / "checkpoints/p7_short_blur/student_0030000.pt",
        help="encoder checkpoint",
    )
    p.add_argument(
        "--head",
        type=Path,
        default=root / "checkpoints/hgt40nat_p7_mid/last.pt",
        help="native head checkpoint (the shipped one by default)",
    )
    p.add_argument("--data", type=Path, help="folder with PAIRS.tsv (default ../shared/data)")
    p.add_argument("--pairs", nargs="+", default=list(CLEAN_PAIRS), help="labeled train pairs")
    p.add_argument("--l2", type=float, default=L2, help="the selector's pull to the census")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    args = p.parse_args(argv)
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    from .export import load_encoder

    start = time.perf_counter()
    encoder = load_encoder(args.encoder).eval()
    head = with_candidates(load_head(args.head), head_candidates(args.width)).eval()
    cells = []
    for pair in clean_pairs(args.data, args.pairs):
        left, right, gt, valid = load_resized(pair, args.width)
        cells.append(pair_cells(encoder, head, pair.pair_id, left, right, gt, valid))
        print(f"{pair.pair_id}: {left.shape[1]}x{left.shape[0]}", flush=True)
    result: dict[str, Any] = {
        "width": args.width,
        "candidates": head.cfg.max_disp,
        "encoder": str(args.encoder),
        "head": str(args.head),
        **study(cells, args.l2),
    }
    result["seconds"] = round(time.perf_counter() - start, 1)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    for name, r in result["readouts"].items():
        m = r["mean"]
        print(f"  {name:32s} {m['epe']:.3f} / {m['bad1tok']:.2f}  ({r['epe_over_census']:.3f}x)")


if __name__ == "__main__":
    main()
