"""The study command line `check_variants`, `readout_variants` and `census_companion` share."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bino_train.folder_scoring import Scores, folder_width, per_variant, run_cli
from bino_train.head import StereoHead
from bino_train.model import BinoEncoder
from bino_train.synth_folder import write_folder

CHECKPOINTS = Path(__file__).resolve().parents[1] / "checkpoints"
ENCODER = CHECKPOINTS / "p7_short_blur" / "student_0030000.pt"
HEAD = CHECKPOINTS / "hgt40_p7" / "last.pt"


def test_each_variant_gets_its_mean_and_its_pairs() -> None:
    per = {"a": [{"epe": 1.0, "bad1tok": 10.0}, {"epe": 3.0, "bad1tok": 30.0}]}
    scores = per_variant(["p", "q"], per)
    assert scores["a"]["mean"]["epe"] == pytest.approx(2.0)
    assert scores["a"]["mean"]["bad1tok"] == pytest.approx(20.0)
    assert scores["a"]["pairs"]["q"]["epe"] == 3.0
    with pytest.raises(ValueError):
        per_variant(["p"], per)  # a pair without its metrics


def test_every_folder_is_scored_at_its_width_and_written(tmp_path: Path) -> None:
    folders = [tmp_path / "w160", tmp_path / "w320"]
    write_folder(folders[0], 160, 48, 1)
    write_folder(folders[1], 320, 48, 1)
    assert [folder_width(f) for f in folders] == [160, 320]
    seen: list[tuple[Path, int]] = []

    def score_folder(encoder: BinoEncoder, head: StereoHead, folder: Path) -> Scores:
        seen.append((folder, head.cfg.max_disp))
        return per_variant(["synth_00"], {"x": [{"epe": 0.5, "bad1tok": 1.0}]})

    out = tmp_path / "result.json"
    argv = ["--encoder", str(ENCODER), "--head", str(HEAD), "--out", str(out), "--folders"]
    result = run_cli("study", "head", score_folder, [*argv, *map(str, folders)])
    # The heads' candidates follow the folder's width (head.head_candidates: 12, then 16).
    assert [c for _, c in seen] == [12, 16]
    assert json.loads(out.read_text()) == json.loads(json.dumps(result))
    assert result["folders"][str(folders[1])]["width"] == 320
