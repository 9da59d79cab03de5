"""The learned per-cell selector of the census selector study (census_selector.py).

Its `FEATURES` of a pair's cells, the logistic `Selector` (in float and in Q8 integers,
`choose_q8`), started at the census path (`census_selector`), its weighted fit by Newton steps
(`fit_selector`) on cells labelled by the better refined map (`training_cells`), and a fold's
leave-one-pair-out choice of L2 and logit threshold (`fit_fold`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .census_selector_cells import Grid, Mask, PairCells, Pixels
from .census_selector_readouts import Readout, cell_errors
from .head_eval import fill_rejected

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
