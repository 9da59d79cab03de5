"""Training curves of a pretraining run as a PNG, from its `log.jsonl`.

    python -m bino_train.curves --run runs/p2_clean150k --out checkpoints/p2_clean150k/curves.png

Four panels over pairs seen: the loss and the teacher's entropy (every logged step), the
no-linkage probe's epe and bad1tok (EVAL.md, w160) and the controlled benchmark's HARD PCK@1,
teacher and student, at each `"kind": "eval"` record. Drawn with OpenCV (no plotting library
in the environment); every value comes from the log.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

PANEL_W, PANEL_H, MARGIN = 460, 260, 48
COLOURS = {"teacher": (180, 90, 20), "student": (40, 140, 230), "loss": (60, 60, 60)}
"""BGR colours of the series."""


def read_log(path: Path) -> list[dict[str, Any]]:
    """The records of a run's log.jsonl, in order."""
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def series(records: Sequence[dict[str, Any]], key: str, evals: bool) -> list[tuple[float, float]]:
    """(pairs, value) of `key` over the eval records (`evals`) or the step records."""
    out = []
    for r in records:
        if (r.get("kind") == "eval") == evals and key in r and r[key] is not None:
            out.append((float(r["pairs"]), float(r[key])))
    return out


def draw_panel(
    canvas: np.ndarray,
    origin: tuple[int, int],
    title: str,
    lines: dict[str, list[tuple[float, float]]],
    x_unit: str = "pairs",
    colours: dict[str, tuple[int, int, int]] | None = None,
) -> None:
    """One panel: axes with their value range, one polyline (or dot) per series, a legend.

    `x_unit` names the x axis's quantity (pairs seen, or steps); `colours` maps a series name's
    first word to its BGR colour (default `COLOURS`)."""
    x0, y0 = origin
    w, h = PANEL_W - 2 * MARGIN, PANEL_H - 2 * MARGIN
    cv2.rectangle(
        canvas, (x0 + MARGIN, y0 + MARGIN), (x0 + MARGIN + w, y0 + MARGIN + h), (0, 0, 0), 1
    )
    cv2.putText(
        canvas, title, (x0 + MARGIN, y0 + MARGIN - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1
    )
    points = [p for values in lines.values() for p in values]
    if not points:
        cv2.putText(
            canvas, "no data yet", (x0 + MARGIN + 10, y0 + MARGIN + h // 2), 0, 0.45, (0, 0, 0), 1
        )
        return
    xs, ys = [p[0] for p in points], [p[1] for p in points]
    x_lo, x_hi = 0.0, max(max(xs), 1.0)
    y_lo, y_hi = min(ys), max(ys)
    if y_hi - y_lo < 1e-9:
        y_lo, y_hi = y_lo - 0.5, y_hi + 0.5

    def at(p: tuple[float, float]) -> tuple[int, int]:
        px = x0 + MARGIN + int(round((p[0] - x_lo) / (x_hi - x_lo) * w))
        py = y0 + MARGIN + h - int(round((p[1] - y_lo) / (y_hi - y_lo) * h))
        return px, py

    small = 0.38
    cv2.putText(canvas, f"{y_hi:.3g}", (x0 + 2, y0 + MARGIN + 4), 0, small, (0, 0, 0), 1)
    cv2.putText(canvas, f"{y_lo:.3g}", (x0 + 2, y0 + MARGIN + h), 0, small, (0, 0, 0), 1)
    cv2.putText(
        canvas,
        f"{int(x_hi):,} {x_unit}",
        (x0 + MARGIN + w - 90, y0 + MARGIN + h + 16),
        0,
        small,
        (0, 0, 0),
        1,
    )
    for i, (name, values) in enumerate(lines.items()):
        colour = (colours or COLOURS).get(name.split()[0], (0, 0, 0))
        pts = np.array([at(p) for p in values], dtype=np.int32)
        if len(pts) > 1:
            cv2.polylines(canvas, [pts], False, colour, 1, cv2.LINE_AA)
        for p in pts:
            cv2.circle(canvas, (int(p[0]), int(p[1])), 2, colour, -1)
        label = f"{name}: {values[-1][1]:.3f}" if values else name
        cv2.putText(
            canvas, label, (x0 + MARGIN + 6, y0 + MARGIN + 14 + 14 * i), 0, small, colour, 1
        )


def plot(records: Sequence[dict[str, Any]]) -> np.ndarray:
    """The 2x2 figure of a run's records (BGR image)."""
    canvas = np.full((2 * PANEL_H, 2 * PANEL_W, 3), 255, np.uint8)
    panels = [
        ("loss (cross-entropy)", {"loss": series(records, "loss", False)}),
        ("teacher entropy (nats)", {"teacher": series(records, "teacher_entropy", False)}),
        (
            "no-linkage probe epe, eval w160 (px)",
            {
                "teacher": series(records, "probe_epe", True),
                "student": series(records, "student_probe_epe", True),
            },
        ),
        (
            "controlled benchmark HARD PCK@1 (%)",
            {
                "teacher": series(records, "hard_pck1", True),
                "student": series(records, "student_hard_pck1", True),
            },
        ),
    ]
    for i, (title, lines) in enumerate(panels):
        draw_panel(canvas, ((i % 2) * PANEL_W, (i // 2) * PANEL_H), title, lines)
    return canvas


def plot_run_cli(
    plot_records: Callable[[Sequence[dict[str, Any]]], np.ndarray],
    description: str | None,
    argv: list[str] | None = None,
) -> None:
    """The command line of a run's curves: `--run` (the folder holding log.jsonl), `--out`
    (the PNG, written as a partial file and renamed into place)."""
    parser = argparse.ArgumentParser(
        description=description, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--run", type=Path, required=True, help="run folder holding log.jsonl")
    parser.add_argument("--out", type=Path, required=True, help="PNG to write")
    args = parser.parse_args(argv)
    log = args.run / "log.jsonl"
    if not log.is_file():
        raise SystemExit(f"error: {log} does not exist")
    image = plot_records(read_log(log))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    partial = args.out.with_name(args.out.name + ".partial.png")
    if not cv2.imwrite(str(partial), image):
        raise SystemExit(f"error: cannot write {args.out}")
    partial.replace(args.out)
    print(f"wrote {args.out}")


def main(argv: list[str] | None = None) -> None:
    plot_run_cli(plot, __doc__, argv)


if __name__ == "__main__":
    main()
