"""Training curves of a head run as a PNG, from its `log.jsonl` (curves.py draws pretraining).

    python -m bino_train.head_curves --run runs/hgt40_p7 --out checkpoints/hgt40_p7/curves.png

Four panels over steps: the training loss (every logged step, and its mean over windows of 20
records), the held-out labeled pairs' float head+lr epe at w160 and w320 against their real
ground truth (`val_gt_w160`, `val_gt_w320` of head_val), the same pairs' bad1tok, and the
synthetic validation crops' epe with the held-out pairs' agreement with confident StereoSGBM
(`val_synthetic`, `val_sgbm_lr`), at each `"kind": "val"` record. Drawn with OpenCV.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from .curves import PANEL_H, PANEL_W, draw_panel, plot_run_cli

HEAD_COLOURS = {
    "loss": (60, 60, 60),
    "w160": (180, 90, 20),
    "w320": (40, 140, 230),
    "synthetic": (40, 150, 60),
    "sgbm_lr": (160, 60, 160),
}
"""BGR colours of a head run's series."""


def step_series(records: Sequence[dict[str, Any]], key: str) -> list[tuple[float, float]]:
    """(step, value) of `key` over the step records (no "kind")."""
    return [
        (float(r["step"]), float(r[key]))
        for r in records
        if "kind" not in r and r.get(key) is not None
    ]


def smoothed(values: list[tuple[float, float]], window: int = 20) -> list[tuple[float, float]]:
    """Means over consecutive windows of `window` points, at each window's last step."""
    out = []
    for i in range(window, len(values) + 1, window):
        chunk = values[i - window : i]
        out.append((chunk[-1][0], sum(v for _, v in chunk) / window))
    return out


def val_series(records: Sequence[dict[str, Any]], *path: str) -> list[tuple[float, float]]:
    """(step, record[path[0]][path[1]]...) over the val records that hold the path."""
    out = []
    for r in records:
        if r.get("kind") != "val":
            continue
        value: Any = r
        for key in path:
            value = value.get(key) if isinstance(value, dict) else None
        if value is not None:
            out.append((float(r["step"]), float(value)))
    return out


def plot(records: Sequence[dict[str, Any]]) -> np.ndarray:
    """The 2x2 figure of a head run's records (BGR image)."""
    canvas = np.full((2 * PANEL_H, 2 * PANEL_W, 3), 255, np.uint8)
    loss = step_series(records, "loss")
    panels = [
        ("training loss", {"loss": loss, "loss mean": smoothed(loss)}),
        (
            "held-out labeled head+lr epe (px)",
            {
                "w160": val_series(records, "val_gt_w160", "head_lr", "epe"),
                "w320": val_series(records, "val_gt_w320", "head_lr", "epe"),
            },
        ),
        (
            "held-out labeled head+lr bad1tok (%)",
            {
                "w160": val_series(records, "val_gt_w160", "head_lr", "bad1tok"),
                "w320": val_series(records, "val_gt_w320", "head_lr", "bad1tok"),
            },
        ),
        (
            "synthetic crops epe / vs confident SGBM (px)",
            {
                "synthetic": val_series(records, "val_synthetic", "epe"),
                "sgbm_lr": val_series(records, "val_sgbm_lr", "epe"),
            },
        ),
    ]
    for i, (title, lines) in enumerate(panels):
        origin = ((i % 2) * PANEL_W, (i // 2) * PANEL_H)
        draw_panel(canvas, origin, title, lines, x_unit="steps", colours=HEAD_COLOURS)
    return canvas


def main(argv: list[str] | None = None) -> None:
    plot_run_cli(plot, __doc__, argv)


if __name__ == "__main__":
    main()
