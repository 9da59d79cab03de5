"""One table of a setting's scores on every validation set (issue 40: choose every setting off
the eval split), from the `bino eval --json` files `scripts/validate.sh` writes.

A run folder holds `{set}{width}.json` for the sets `heldout` (the held-out labeled train pairs,
real ground truth), `synth` and `real` (synthetic scenes with exact disparity, plain and with
real textures) and `proxy` (the held-out train pairs against confident StereoSGBM, a proxy on
textured pixels). The table gives, per readout, each set's mean epe / bad1tok; with a baseline
run folder, each set's epe ratio to the baseline's and their geometric mean, the rule the
project's settings were chosen by (better on every set; `train/experiments.json`).

    python -m bino_train.validation_table RUN [--baseline BASE]
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass
from pathlib import Path

SETS = ("heldout", "synth", "real", "proxy")
WIDTHS = (160, 320)


@dataclass(frozen=True)
class Score:
    """A readout's mean scores on one validation set."""

    epe: float
    bad1tok: float


def load_run(folder: Path) -> dict[tuple[str, int], dict[str, Score]]:
    """Every `{set}{width}.json` in `folder`: (set, width) -> readout -> mean scores."""
    run: dict[tuple[str, int], dict[str, Score]] = {}
    for width in WIDTHS:
        for name in SETS:
            path = folder / f"{name}{width}.json"
            if not path.exists():
                continue
            try:
                means = json.loads(path.read_text())["mean"]
            except (json.JSONDecodeError, KeyError) as err:
                raise ValueError(f"{path}: not a bino eval --json file ({err})") from err
            run[(name, width)] = {
                readout: Score(v["metrics"]["epe"], v["metrics"]["bad1tok"])
                for readout, v in means.items()
                if isinstance(v, dict) and "metrics" in v
            }
    if not run:
        raise ValueError(f"{folder}: no validation results ({{set}}{{width}}.json)")
    return run


def geometric_mean(values: list[float]) -> float:
    """The geometric mean of positive values."""
    return math.exp(sum(math.log(v) for v in values) / len(values))


def render(
    run: dict[tuple[str, int], dict[str, Score]],
    baseline: dict[tuple[str, int], dict[str, Score]] | None = None,
) -> str:
    """A Markdown table: a row a readout, a column a (set, width); with `baseline`, the epe
    ratios to it and their geometric mean over the sets both runs scored."""
    columns = [key for key in ((s, w) for w in WIDTHS for s in SETS) if key in run]
    readouts = sorted({r for scores in run.values() for r in scores})
    head = ["readout", *(f"{s} w{w}" for s, w in columns)]
    if baseline is not None:
        head.append("epe / baseline (geo. mean)")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for readout in readouts:
        cells = [readout]
        ratios = []
        for key in columns:
            score = run[key].get(readout)
            if score is None:
                cells.append("-")
                continue
            cell = f"{score.epe:.3f} / {score.bad1tok:.2f}"
            base = (baseline or {}).get(key, {}).get(readout)
            if base is not None and base.epe > 0:
                ratios.append(score.epe / base.epe)
                cell += f" ({ratios[-1]:.3f})"
            cells.append(cell)
        if baseline is not None:
            cells.append(f"{geometric_mean(ratios):.4f}" if ratios else "-")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("run", type=Path, help="folder of {set}{width}.json from validate.sh")
    p.add_argument("--baseline", type=Path, help="a second run folder to compare against")
    args = p.parse_args(argv)
    try:
        run = load_run(args.run)
        baseline = load_run(args.baseline) if args.baseline else None
    except ValueError as err:
        raise SystemExit(f"error: {err}") from None
    print(render(run, baseline))


if __name__ == "__main__":
    main()
