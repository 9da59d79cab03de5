"""Can a re-ranker of the census's own candidates beat `census+lr+ref` (issue 54, second study)?

    python -m bino_train.census_rerank --width 160 --out J [--encoder E --head H --data DIR]

`census_selector` showed that choosing per cell between the census cell and the native head's
cell cannot beat the crate's encoder-free readout `census+lr+ref` on unseen pairs, and that the
census's own RUNNER-UP (its best candidate more than one column from the winner) holds much of
what the winner misses (oracle 0.785x / 0.717x at w160 / w320). This study re-ranks, per cell,
the census WINNER against its runner-up (and, in the 3-way variant, the native head's argmax),
on the same clean labeled pairs (`census_selector.CLEAN_PAIRS`, never the eval split), each
resized to `--width` as EVAL.md profiles do, scored after the pixel refinement exactly as
`census_selector` scores.

Candidates of a cell (patch columns): the winner (`CensusCells.disparity`), the runner-up
(`CensusCells.runner_up`) and the head's argmax with a parabola step on its logits. Each is
checked by the census's own left-right test (`head_eval.consistent` against the census's right
view), so the checks need no encoder.

Pipelines (`Pipeline`) turn a per-cell choice into a refined map: the census's kept mask
(left-right and, unless `nouniq`, the uniqueness test) for cells on the winner; for a switched
cell the same mask, or with `recheck` the chosen candidate's own left-right check (so a rejected
cell whose runner-up agrees comes back, and a switched cell that disagrees is dropped); rejected
cells filled from the left (`head_eval.fill_rejected`, the core's rule) or with `bg` by the lower
of the nearest kept neighbours left and right (`census_selector.fill_background`); then
`census_companion.refined`. Every cell on the winner under the default pipeline is exactly
`census+lr+ref`.

Re-rankers (each per pipeline, leave-one-pair-out over the five pairs, each fold choosing its L2
and logit threshold by leave-one-pair-out over its own four pairs with `census_selector.fit_fold`,
started at and pulled towards "keep the winner": zero weights, bias `census_selector.INIT_BIAS`):
- `rr2-census`: winner vs runner-up on census features only (`census_features`): the aggregated
  cost of each candidate over the cell's largest, their ratio (winner / candidate: 1 - the
  uniqueness margin), the census's kept / left-right / uniqueness flags, each candidate's
  left-right agreement, each candidate's agreement (within one column) with the kept census
  neighbours left, right and above, the left view's gradient, the candidates' distance and which
  is nearer. Encoder-free.
- `rr2-head`: the same plus the native head's softmax mass within +-1 column of each candidate and
  its peak (the head as evidence, never as a disparity). Needs the encoder.
- `rr3-head`: winner vs runner-up vs head argmax: two such binary re-rankers against the winner
  (runner-up and head), the cell taking the candidate of the highest positive logit. Needs it.
- `rule-lrswap`: no fit: the runner-up where the winner fails its left-right check and the
  runner-up passes it. Encoder-free.
Each fit is labelled per cell by which of the all-winner / all-candidate refined maps has the
lower error on the cell's pixels, weighted by what that changes the pair's epe (cells where
neither choice is kept weigh 0: their own choice does not reach the map); `oracle2` / `oracle3`
take those labels (the bound of the formulation). `-q8` is the fitted re-ranker in Q8 integers
(`census_selector.choose_q8`). `insample` variants are fitted and scored on all five pairs (an
optimistic bound, not a held-out number).

For each readout: mean and per-pair epe / bad1tok, x census, the share of cells switched to
another candidate and the share whose filled cell (or kept flag) differs from census+lr's, and
whether it needs the encoder.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .census_companion import pixel_hamming, refined
from .census_rerank_cells import RerankCells as RerankCells
from .census_rerank_cells import candidate, head_logits
from .census_rerank_cells import census_features as census_features
from .census_rerank_cells import head_mass as head_mass
from .census_rerank_cells import neighbour_agreement as neighbour_agreement
from .census_rerank_cells import rerank_cells as rerank_cells
from .census_selector import clean_pairs, load_resized
from .census_selector_cells import Grid, Mask, Pixels, pair_cells
from .census_selector_fit import (
    INIT_BIAS,
    INSAMPLE_L2,
    Q8,
    SETTINGS,
    Cells,
    Selector,
    choose_q8,
    fit_fold,
    fit_pairs,
)
from .census_selector_readouts import cell_errors, fill_background
from .census_study import load_models, study_parser, write_result
from .head_eval import fill_rejected
from .probe import mean_metrics, score
from .refine import CELL

TARGET = 0.85
"""The issue's bar: epe at most this times census+lr+ref's, bad1tok below it."""


# --- pipelines -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Pipeline:
    """How a per-cell candidate choice becomes a filled grid (see the module's docstring)."""

    uniq: bool = True
    background: bool = False
    recheck: bool = False

    @property
    def name(self) -> str:
        fill = "(bg-fill)" if self.background else ""
        return f"lr{'' if self.uniq else '-nouniq'}{fill}{',recheck' if self.recheck else ''}"


PIPELINES = (
    Pipeline(),
    Pipeline(background=True),
    Pipeline(uniq=False),
    Pipeline(uniq=False, background=True),
    Pipeline(recheck=True),
    Pipeline(background=True, recheck=True),
    Pipeline(uniq=False, background=True, recheck=True),
)
"""The default (census+lr+ref's own), the classical variants and the re-checked ones."""


def assemble(r: RerankCells, pipe: Pipeline, choice: NDArray[np.int64]) -> tuple[Grid, Mask]:
    """(filled disparity, kept) of a per-cell candidate choice under `pipe`."""
    cc = r.base.census
    kept0 = cc.kept if pipe.uniq else cc.lr
    count = int(choice.max()) + 1 if choice.size else 1
    cands = [candidate(r, k) for k in range(max(count, 1))]
    pick = choice[None]
    d = np.take_along_axis(np.stack([c[0] for c in cands]), pick, 0)[0]
    if pipe.recheck:
        lr = np.take_along_axis(np.stack([c[1] for c in cands]), pick, 0)[0]
        kept = np.where(choice == 0, kept0, lr)
    else:
        kept = kept0
    filled = fill_background(d, kept) if pipe.background else fill_rejected(d, kept)
    return filled, np.asarray(kept, dtype=bool)


def predict(r: RerankCells, pipe: Pipeline, choice: NDArray[np.int64]) -> Pixels:
    """The refined pixels of a choice under `pipe`."""
    b = r.base
    grid, kept = assemble(r, pipe, choice)
    return refined(b.boxed, grid, kept, b.search)


def constant(r: RerankCells, k: int) -> NDArray[np.int64]:
    return np.full(r.base.census.disparity.shape, k, dtype=np.int64)


def training_cells(
    r: RerankCells, pipe: Pipeline, k: int, feats: Grid, pred0: Pixels, predk: Pixels
) -> Cells:
    """(features, label, weight) of one pair for a winner-vs-candidate-`k` re-ranker: label where
    the all-`k` refined map's cell error is below the all-winner map's, weight what taking it
    changes the pair's epe (0 where neither choice leaves the cell kept)."""
    s0, n = cell_errors(pred0, r.base)
    sk, _ = cell_errors(predk, r.base)
    diff = (s0 - sk) / max(float(n.sum()), 1.0)
    matters = assemble(r, pipe, constant(r, 0))[1] | assemble(r, pipe, constant(r, k))[1]
    weight = np.where(matters, np.abs(diff), 0.0)
    return feats.reshape(-1, feats.shape[-1]), (diff > 0).reshape(-1), weight.reshape(-1)


def oracle(r: RerankCells, pipe: Pipeline, preds: Sequence[Pixels]) -> NDArray[np.int64]:
    """Per cell the candidate whose all-candidate refined map is best on the cell's pixels
    (the winner where tied, unknown, or no choice is kept)."""
    errs = np.stack([cell_errors(p, r.base)[0] for p in preds])
    errs[1:] = np.where(errs[1:] < errs[0], errs[1:], np.inf)
    choice = errs.argmin(axis=0)
    matters = np.zeros_like(r.base.census.kept)
    for k in range(len(preds)):
        matters |= assemble(r, pipe, constant(r, k))[1]
    return np.asarray(np.where(matters, choice, 0), dtype=np.int64)


# --- re-rankers ----------------------------------------------------------------------------


@dataclass(frozen=True)
class Model:
    """A re-ranker: its candidates (1: runner-up, 2: head) and whether it reads the head."""

    name: str
    candidates: tuple[int, ...]
    use_head: bool

    @property
    def needs_encoder(self) -> bool:
        return self.use_head or 2 in self.candidates


MODELS = (
    Model("rr2-census", (1,), False),
    Model("rr2-head", (1,), True),
    Model("rr3-head", (1, 2), True),
)


def rule_lrswap(r: RerankCells) -> NDArray[np.int64]:
    """The runner-up where the winner fails the left-right check and the runner-up passes."""
    return np.asarray(np.where(~r.base.census.lr & r.runner_lr, 1, 0), dtype=np.int64)


def q8_logits(selector: Selector, x: Grid) -> NDArray[np.int64]:
    """`census_selector.choose_q8`'s integer logit (Q16) of each cell."""
    fq = np.rint(np.clip(x, 0.0, 1.0) * Q8).astype(np.int64)
    wq = np.rint(selector.weights * Q8).astype(np.int64)
    return np.asarray(fq @ wq + int(np.rint(selector.bias * Q8)) * Q8)


def combine(
    selectors: Sequence[Selector], feats: Sequence[Grid], candidates: Sequence[int], q8: bool
) -> NDArray[np.int64]:
    """Each cell's candidate of the highest positive logit (the winner, 0, where none is)."""
    if len(selectors) == 1 and q8:
        return np.asarray(choose_q8(selectors[0], feats[0]) * candidates[0], dtype=np.int64)
    logits = [
        (q8_logits(s, f) if q8 else s.logits(f)).astype(np.float64)
        for s, f in zip(selectors, feats, strict=True)
    ]
    stack = np.stack([np.zeros_like(logits[0])] + logits)
    best = stack.argmax(axis=0)
    labels = np.array([0, *candidates], dtype=np.int64)
    return np.asarray(labels[best], dtype=np.int64)


def selector_json(s: Selector, names: Sequence[str]) -> dict[str, Any]:
    return {
        "weights": dict(zip(names, map(float, s.weights), strict=True)),
        "bias": float(s.bias),
        "weights_q8": [int(v) for v in np.rint(s.weights * Q8)],
        "bias_q8": int(np.rint(s.bias * Q8)),
    }


@dataclass
class Variant:
    """One readout's maps and bookkeeping over the pairs."""

    preds: list[Pixels]
    choices: list[NDArray[np.int64]]
    grids: list[tuple[Grid, Mask]]
    needs_encoder: bool
    info: dict[str, Any]


def run_model(
    pairs: Sequence[RerankCells],
    pipe: Pipeline,
    model: Model,
    all_preds: Sequence[dict[int, Pixels]],
    settings: Sequence[tuple[float, float]] = SETTINGS,
) -> dict[str, Variant]:
    """Leave-one-pair-out fits of `model` under `pipe`: the held-out readout, its Q8 twin and the
    in-sample bound, {name suffix: Variant}."""
    feats: dict[int, list[Grid]] = {}
    data: dict[int, list[Cells]] = {}
    names: dict[int, list[str]] = {}
    for k in model.candidates:
        feats[k], data[k] = [], []
        for r, preds in zip(pairs, all_preds, strict=True):
            n, f = census_features(r, k, model.use_head)
            names[k] = n
            feats[k].append(f)
            data[k].append(training_cells(r, pipe, k, f, preds[0], preds[k]))
    out: dict[str, Variant] = {
        s: Variant([], [], [], model.needs_encoder, {"folds": {}}) for s in ("", "-q8", "-insample")
    }
    insample = {k: fit_pairs(data[k], INSAMPLE_L2) for k in model.candidates}
    out["-insample"].info = {f"cand{k}": selector_json(s, names[k]) for k, s in insample.items()}
    for i, r in enumerate(pairs):
        chosen = {}
        fold: dict[str, Any] = {}
        for k in model.candidates:
            rest = [d for j, d in enumerate(data[k]) if j != i]
            sel, info = fit_fold(rest, settings)
            chosen[k] = sel
            fold[f"cand{k}"] = {"setting": info["setting"], **selector_json(sel, names[k])}
        out[""].info["folds"][r.base.pair_id] = fold
        fi = [feats[k][i] for k in model.candidates]
        cand = list(model.candidates)
        takes = {
            "": combine([chosen[k] for k in cand], fi, cand, False),
            "-q8": combine([chosen[k] for k in cand], fi, cand, True),
            "-insample": combine([insample[k] for k in cand], fi, cand, False),
        }
        for suffix, choice in takes.items():
            v = out[suffix]
            v.choices.append(choice)
            v.grids.append(assemble(r, pipe, choice))
            v.preds.append(predict(r, pipe, choice))
    return out


def fixed_variant(
    pairs: Sequence[RerankCells],
    pipe: Pipeline,
    choices: Sequence[NDArray[np.int64]],
    needs_encoder: bool = False,
) -> Variant:
    """The readout of given per-cell choices (no fit)."""
    return Variant(
        preds=[predict(r, pipe, c) for r, c in zip(pairs, choices, strict=True)],
        choices=list(choices),
        grids=[assemble(r, pipe, c) for r, c in zip(pairs, choices, strict=True)],
        needs_encoder=needs_encoder,
        info={},
    )


def study(
    pairs: Sequence[RerankCells],
    pipelines: Sequence[Pipeline] = PIPELINES,
    models: Sequence[Model] = MODELS,
    settings: Sequence[tuple[float, float]] = SETTINGS,
    log: Callable[[str], None] = lambda _: None,
) -> dict[str, Any]:
    """Every readout's scores (mean and per pair, x census), its switched and changed cells,
    whether it needs the encoder, and the fits."""
    names = [r.base.pair_id for r in pairs]
    variants: dict[str, Variant] = {}
    default = Pipeline()
    for pipe in pipelines:
        if not pipe.recheck:
            variants[f"census+{pipe.name}+ref"] = fixed_variant(
                pairs, pipe, [constant(r, 0) for r in pairs]
            )
        all_preds = [{k: predict(r, pipe, constant(r, k)) for k in (0, 1, 2)} for r in pairs]
        variants[f"oracle2/{pipe.name}+ref"] = fixed_variant(
            pairs,
            pipe,
            [oracle(r, pipe, [a[0], a[1]]) for r, a in zip(pairs, all_preds, strict=True)],
        )
        variants[f"oracle3/{pipe.name}+ref"] = fixed_variant(
            pairs,
            pipe,
            [oracle(r, pipe, [a[0], a[1], a[2]]) for r, a in zip(pairs, all_preds, strict=True)],
            needs_encoder=True,
        )
        variants[f"rule-lrswap/{pipe.name}+ref"] = fixed_variant(
            pairs, pipe, [rule_lrswap(r) for r in pairs]
        )
        for model in models:
            t0 = time.perf_counter()
            for suffix, v in run_model(pairs, pipe, model, all_preds, settings).items():
                variants[f"{model.name}{suffix}/{pipe.name}+ref"] = v
            log(f"  {model.name}/{pipe.name}: {time.perf_counter() - t0:.1f} s")
    base_grids = [assemble(r, default, constant(r, 0)) for r in pairs]
    per = {
        name: [score(p, r.base.gt, r.base.valid) for p, r in zip(v.preds, pairs, strict=True)]
        for name, v in variants.items()
    }
    baseline_rows = per["census+lr+ref"]
    baseline = mean_metrics(baseline_rows)
    readouts: dict[str, Any] = {}
    for name, v in variants.items():
        rows = per[name]
        mean = mean_metrics(rows)
        switched = [float(100 * (c != 0).mean()) for c in v.choices]
        changed = [
            float(100 * ((np.abs(g - bg) > 1e-9) | (k != bk)).mean())
            for (g, k), (bg, bk) in zip(v.grids, base_grids, strict=True)
        ]
        readouts[name] = {
            "mean": mean,
            "epe_over_census": mean["epe"] / baseline["epe"],
            "meets_target": bool(
                mean["epe"] <= TARGET * baseline["epe"] and mean["bad1tok"] < baseline["bad1tok"]
            ),
            "needs_encoder": v.needs_encoder,
            "switched_pct": float(np.mean(switched)),
            "changed_pct": float(np.mean(changed)),
            "pairs": {
                n: {
                    **m,
                    "epe_over_census": m["epe"] / b["epe"],
                    "switched_pct": s,
                    "changed_pct": c,
                }
                for n, m, b, s, c in zip(names, rows, baseline_rows, switched, changed, strict=True)
            },
            **({"fit": v.info} if v.info else {}),
        }
    return {
        "pairs": names,
        "target": {"epe": TARGET * baseline["epe"], "bad1tok_below": baseline["bad1tok"]},
        "init_bias": INIT_BIAS,
        "settings": [list(s) for s in settings],
        "readouts": readouts,
    }


# --- the run -------------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> None:
    args = study_parser(__doc__).parse_args(argv)
    start = time.perf_counter()
    encoder, head = load_models(args)
    cells = []
    for pair in clean_pairs(args.data, args.pairs):
        left, right, gt, valid = load_resized(pair, args.width)
        base = pair_cells(encoder, head, pair.pair_id, left, right, gt, valid)
        hamming = pixel_hamming(left, right, CELL * head.cfg.max_disp, False)
        cells.append(rerank_cells(base, hamming, head_logits(encoder, head, left, right)))
        print(f"{pair.pair_id}: {left.shape[1]}x{left.shape[0]}", flush=True)
    result = write_result(args, head, study(cells, log=lambda s: print(s, flush=True)), start)
    for name, r in result["readouts"].items():
        m = r["mean"]
        flag = " E" if r["needs_encoder"] else "  "
        print(
            f"  {name:40s}{flag} {m['epe']:.3f} / {m['bad1tok']:5.2f}  "
            f"({r['epe_over_census']:.3f}x)  switched {r['switched_pct']:5.1f}%  "
            f"changed {r['changed_pct']:5.1f}%{'  TARGET' if r['meets_target'] else ''}"
        )


if __name__ == "__main__":
    main()
