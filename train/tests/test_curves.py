"""The curves figure is drawn from the log's values."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from bino_train.curves import COLOURS, main, plot, series


def records() -> list[dict[str, float | str]]:
    steps = [
        {"step": s, "pairs": 16 * s, "loss": 5.0 - 0.1 * s, "teacher_entropy": 4.0}
        for s in range(1, 20)
    ]
    evals = [
        {
            "kind": "eval",
            "step": s,
            "pairs": 16 * s,
            "probe_epe": e,
            "student_probe_epe": e - 0.1,
            "hard_pck1": p,
        }
        for s, e, p in [(5, 3.5, 40.0), (15, 3.0, 50.0)]
    ]
    return [*steps, *evals]


def test_series_separate_steps_from_evaluations() -> None:
    r = records()
    assert series(r, "loss", evals=False)[0] == (16.0, 4.9)
    assert series(r, "probe_epe", evals=True) == [(80.0, 3.5), (240.0, 3.0)]
    assert series(r, "probe_epe", evals=False) == []


def test_figure_draws_every_series(tmp_path: Path) -> None:
    image = plot(records())
    assert image.shape == (520, 920, 3)
    for colour in COLOURS.values():
        assert np.all(image == np.array(colour, np.uint8), axis=-1).any(), colour
    run = tmp_path / "run"
    run.mkdir()
    (run / "log.jsonl").write_text("\n".join(json.dumps(r) for r in records()))
    out = tmp_path / "curves.png"
    main(["--run", str(run), "--out", str(out)])
    written = cv2.imread(str(out))
    assert written is not None and written.shape == image.shape
    with pytest.raises(SystemExit):
        main(["--run", str(tmp_path / "missing"), "--out", str(out)])
