"""Per cell quantities of the census re-ranking study (census_rerank.py).

What the study reads of one pair beyond `census_selector_cells.PairCells` (`RerankCells`): the
census's aggregated left costs, its right-view disparity, the runner-up's left-right check and
the native head's softmax; each cell's candidates (winner, runner-up, head argmax) with their
left-right checks (`candidate`), and the features a re-ranker reads of them
(`census_features`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from numpy.typing import NDArray

from .census_companion import cell_costs, right_view, wta_parabola
from .census_selector_cells import CENSUS_PENALTIES, Grid, Mask, PairCells
from .census_selector_fit import DISAGREEMENT_CLIP
from .head import StereoHead
from .head_eval import LR_MAX_DIFF, consistent
from .model import BinoEncoder
from .probe import encoder_phase_maps
from .readout_variants import sgm_aggregate
from .refine import CELL

GRADIENT_CLIP = 16.0
"""Mean |horizontal gradient| (grey levels per px) at which the gradient feature saturates."""
AGREE = LR_MAX_DIFF
"""A candidate agrees with a neighbour within this many patch columns (the left-right test's)."""
HEAD_WINDOW = 1
"""The head's evidence for a candidate: its softmax mass within this many columns of it."""


@dataclass(frozen=True)
class RerankCells:
    """What the re-ranking study reads of one pair beyond `census_selector.PairCells`."""

    base: PairCells
    cost: Grid
    """(T, P, N) the census's aggregated left costs (N pixel candidates)."""
    right: Grid
    """The census's right-view disparity (patch columns)."""
    runner_lr: Mask
    """The runner-up's left-right agreement with `right`."""
    prob: Grid
    """(T, P, D) the native head's softmax (D patch-column candidates)."""
    head_argmax: Grid
    """The head's argmax with a parabola step on its logits (patch columns)."""
    head_lr: Mask
    """The head argmax's left-right agreement with the census's right view."""


def census_volumes(
    hamming: Grid, rows: int, cols: int, penalties: tuple[float, float] = CENSUS_PENALTIES
) -> tuple[Grid, Grid]:
    """(left aggregate (T, P, N), right disparity in patch columns) of the census SGM, as
    `census_selector.census_cells` computes them."""
    p1, p2 = penalties
    left = sgm_aggregate(cell_costs(hamming, rows, cols), p1, p2)
    right = sgm_aggregate(cell_costs(right_view(hamming), rows, cols), p1, p2)
    return left, wta_parabola(right) / CELL


def head_logits(
    encoder: BinoEncoder, head: StereoHead, left_u8: NDArray[np.uint8], right_u8: NDArray[np.uint8]
) -> Grid:
    """(D, T, P) logits of the native head on one pair (one encoder pass)."""
    left_px = left_u8.astype(np.float32) / np.float32(255.0)
    right_px = right_u8.astype(np.float32) / np.float32(255.0)
    with torch.no_grad():
        out = head(*(t[None] for t in encoder_phase_maps(encoder, left_px, right_px)))
    return np.asarray(out.logits[0].double().numpy())


def rerank_cells(base: PairCells, hamming: Grid, logits: Grid) -> RerankCells:
    """The study's extras of one pair from the census distances (`pixel_hamming`, unclamped)
    and the head's (D, T, P) logits."""
    rows, cols = base.census.disparity.shape
    cost, right = census_volumes(hamming, rows, cols)
    if not np.allclose(wta_parabola(cost) / CELL, base.census.disparity):
        raise AssertionError(f"{base.pair_id}: census winner differs from census_selector's")
    d = logits.shape[0]
    z = logits - logits.max(axis=0, keepdims=True)
    p = np.exp(z)
    p /= p.sum(axis=0, keepdims=True)
    argmax = np.clip(wta_parabola(-np.moveaxis(logits, 0, -1)), 0.0, d - 1.0)
    return RerankCells(
        base=base,
        cost=cost,
        right=right,
        runner_lr=consistent(base.census.runner_up, right),
        prob=np.moveaxis(p, 0, -1),
        head_argmax=argmax,
        head_lr=consistent(argmax, right),
    )


def cost_at(cost: Grid, disparity: Grid) -> Grid:
    """The (T, P, N) aggregate at each cell's candidate nearest `disparity` (patch columns)."""
    n = cost.shape[-1]
    index = np.clip(np.rint(disparity * CELL).astype(np.int64), 0, n - 1)
    return np.take_along_axis(cost, index[..., None], -1)[..., 0]


def head_mass(prob: Grid, disparity: Grid, window: int = HEAD_WINDOW) -> Grid:
    """The (T, P, D) softmax's mass within `window` columns of each cell's rounded candidate."""
    d = prob.shape[-1]
    centre = np.rint(disparity).astype(np.int64)
    out = np.zeros(disparity.shape)
    for o in range(-window, window + 1):
        k = centre + o
        inside = (k >= 0) & (k < d)
        at = np.take_along_axis(prob, np.clip(k, 0, d - 1)[..., None], -1)[..., 0]
        out += np.where(inside, at, 0.0)
    return np.clip(out, 0.0, 1.0)


def neighbour_agreement(disparity: Grid, reference: Grid, kept: Mask) -> list[Mask]:
    """[left, right, up]: whether the neighbour cell is kept and its `reference` disparity lies
    within `AGREE` of `disparity` (False outside the grid)."""
    out = []
    for axis, shift in ((1, 1), (1, -1), (0, 1)):
        ref = np.roll(reference, shift, axis=axis)
        ok = np.roll(kept, shift, axis=axis)
        edge = np.zeros_like(kept)
        if axis == 1:
            edge[:, 0 if shift == 1 else -1] = True
        else:
            edge[0, :] = True
        out.append(ok & ~edge & (np.abs(disparity - ref) <= AGREE))
    return out


def candidate_columns(
    r: RerankCells, disparity: Grid, lr: Mask, use_head: bool
) -> tuple[list[str], list[Grid]]:
    """(names, grids) of one candidate's own features, each in [0, 1]."""
    cc = r.base.census
    top = np.maximum(r.cost.max(axis=-1), 1.0)
    names = ["cost", "lr", "agree_left", "agree_right", "agree_up"]
    grids = [np.clip(cost_at(r.cost, disparity) / top, 0.0, 1.0), lr.astype(np.float64)]
    grids += [a.astype(np.float64) for a in neighbour_agreement(disparity, cc.disparity, cc.kept)]
    if use_head:
        names.append("head_mass")
        grids.append(head_mass(r.prob, disparity))
    return names, grids


def candidate(r: RerankCells, k: int) -> tuple[Grid, Mask]:
    """(disparity, census left-right check) of candidate `k`: 0 winner, 1 runner-up, 2 head."""
    cc = r.base.census
    return [
        (cc.disparity, cc.lr),
        (cc.runner_up, r.runner_lr),
        (r.head_argmax, r.head_lr),
    ][k]


def census_features(r: RerankCells, k: int, use_head: bool) -> tuple[list[str], Grid]:
    """(names, (T, P, F) features in [0, 1]) of a re-ranker of the winner against candidate `k`:
    the census's flags and the view's gradient, the winner's and the candidate's own columns
    (`candidate_columns`), the costs' ratio, their distance and whether the candidate is
    nearer; with `use_head` also the head's peak."""
    cc = r.base.census
    dw, lw = candidate(r, 0)
    dk, lk = candidate(r, k)
    wn, wg = candidate_columns(r, dw, lw, use_head)
    kn, kg = candidate_columns(r, dk, lk, use_head)
    cw, ck = cost_at(r.cost, dw), cost_at(r.cost, dk)
    ratio = np.where(ck > 0, cw / np.maximum(ck, 1e-9), 1.0)
    names = ["kept", "unique", "gradient"]
    grids = [
        cc.kept.astype(np.float64),
        cc.unique.astype(np.float64),
        np.clip(r.base.gradient / GRADIENT_CLIP, 0.0, 1.0),
    ]
    names += [f"winner_{n}" for n in wn] + [f"cand_{n}" for n in kn]
    grids += wg + kg
    names += ["ratio", "distance", "cand_nearer"]
    grids += [
        np.clip(ratio, 0.0, 1.0),
        np.clip(np.abs(dk - dw) / DISAGREEMENT_CLIP, 0.0, 1.0),
        (dk > dw).astype(np.float64),
    ]
    if use_head:
        names.append("head_peak")
        grids.append(np.clip(r.base.head_peak, 0.0, 1.0))
    return names, np.stack(grids, axis=-1)
