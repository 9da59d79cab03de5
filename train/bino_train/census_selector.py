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

import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .census_companion import refined
from .census_selector_cells import CENSUS_PENALTIES as CENSUS_PENALTIES
from .census_selector_cells import CensusCells as CensusCells
from .census_selector_cells import Grid as Grid
from .census_selector_cells import Mask as Mask
from .census_selector_cells import PairCells as PairCells
from .census_selector_cells import Pixels as Pixels
from .census_selector_cells import cell_ground_truth as cell_ground_truth
from .census_selector_cells import cell_spread as cell_spread
from .census_selector_cells import census_cells as census_cells
from .census_selector_cells import head_stats as head_stats
from .census_selector_cells import pair_cells as pair_cells
from .census_selector_cells import uniqueness as uniqueness
from .census_selector_fit import DISAGREEMENT_CLIP as DISAGREEMENT_CLIP
from .census_selector_fit import FEATURES as FEATURES
from .census_selector_fit import INIT_BIAS as INIT_BIAS
from .census_selector_fit import INSAMPLE_L2 as INSAMPLE_L2
from .census_selector_fit import L2, training_cells
from .census_selector_fit import Q8 as Q8
from .census_selector_fit import SETTINGS as SETTINGS
from .census_selector_fit import Cells as Cells
from .census_selector_fit import Selector as Selector
from .census_selector_fit import census_selector as census_selector
from .census_selector_fit import choose_q8 as choose_q8
from .census_selector_fit import epe_gain as epe_gain
from .census_selector_fit import features as features
from .census_selector_fit import fit_fold as fit_fold
from .census_selector_fit import fit_pairs as fit_pairs
from .census_selector_fit import fit_selector as fit_selector
from .census_selector_readouts import Readout, pixel_oracle
from .census_selector_readouts import base_readouts as base_readouts
from .census_selector_readouts import cell_errors as cell_errors
from .census_selector_readouts import fill_background as fill_background
from .census_selector_readouts import oracle_choice as oracle_choice
from .census_selector_readouts import select as select
from .census_study import load_models, study_parser, write_result
from .head_eval import fill_rejected
from .labeled import LABELED_HOLDOUT, labeled_pairs, load_checked_gt
from .pairs import Pair, load_gray
from .probe import mean_metrics, score
from .profile import resize_gt, resize_image, to_u8
from .refine import CELL

CLEAN_PAIRS = LABELED_HOLDOUT
"""Labeled train pairs no head was trained on (never the eval split)."""
TEXTURELESS_GRADIENT = 2.0
"""Mean |horizontal gradient| of a cell (grey levels per px, central differences) below which a
cell counts as textureless."""
REPETITIVE_RISE = 1.2
"""`cell_periodicity` above which a textured cell counts as repetitive texture: the window's
correlation climbs back by more than this after its dip (a period within 16 px gives close to
2; white noise and value noise stay below it in 99 % of cells)."""
DISCONTINUITY_PX = 2.0
"""Spread (px) of the valid ground truth over a cell and its 8 neighbours above which a cell
counts as near a discontinuity."""


# --- conditions ----------------------------------------------------------------------------


def conditions(c: PairCells) -> dict[str, Mask]:
    """Cell masks of the study's conditions."""
    known = np.isfinite(c.gt_cell)
    median = np.nanmedian(c.gt_cell) if known.any() else 0.0
    return {
        "all": np.ones(c.gt_cell.shape, dtype=bool),
        "textureless": c.gradient < TEXTURELESS_GRADIENT,
        "repetitive": (c.gradient >= TEXTURELESS_GRADIENT) & (c.periodicity > REPETITIVE_RISE),
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
    p = study_parser(__doc__)
    p.add_argument("--l2", type=float, default=L2, help="the selector's pull to the census")
    args = p.parse_args(argv)
    start = time.perf_counter()
    encoder, head = load_models(args)
    cells = []
    for pair in clean_pairs(args.data, args.pairs):
        left, right, gt, valid = load_resized(pair, args.width)
        cells.append(pair_cells(encoder, head, pair.pair_id, left, right, gt, valid))
        print(f"{pair.pair_id}: {left.shape[1]}x{left.shape[0]}", flush=True)
    result = write_result(args, head, study(cells, args.l2), start)
    for name, r in result["readouts"].items():
        m = r["mean"]
        print(f"  {name:32s} {m['epe']:.3f} / {m['bad1tok']:.2f}  ({r['epe_over_census']:.3f}x)")


if __name__ == "__main__":
    main()
