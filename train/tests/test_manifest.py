"""The manifest's pieces: artifact hashes and the metrics folder."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pytest
import torch

from bino_train.manifest import check_head_metrics, collect_metrics, file_hashes, run_summary


def test_file_hashes_cover_artifacts_but_not_docs_or_the_manifest(tmp_path: Path) -> None:
    (tmp_path / "bino_int8.bin").write_bytes(b"\x00\x01blob")
    (tmp_path / "README.md").write_text("docs")
    (tmp_path / "MANIFEST.json").write_text("{}")
    (tmp_path / "sub").mkdir()
    hashes = file_hashes(tmp_path)
    assert hashes == {"bino_int8.bin": hashlib.sha256(b"\x00\x01blob").hexdigest()}


def test_collect_metrics_keys_each_json_by_its_stem(tmp_path: Path) -> None:
    (tmp_path / "probe_trained.json").write_text(json.dumps({"epe": 2.37}))
    (tmp_path / "benchmark_random.json").write_text(json.dumps({"hard_pck1": 40.5}))
    (tmp_path / "notes.txt").write_text("not a metric")
    metrics = collect_metrics(tmp_path)
    assert list(metrics) == ["benchmark_random", "probe_trained"]
    assert metrics["probe_trained"]["epe"] == 2.37


def test_collect_metrics_names_a_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match="does not exist"):
        collect_metrics(tmp_path / "absent")


def test_collect_metrics_rejects_broken_json(tmp_path: Path) -> None:
    (tmp_path / "broken.json").write_text("{not json")
    with pytest.raises(SystemExit, match="broken.json is not valid JSON"):
        collect_metrics(tmp_path)


def _write_run(run: Path) -> None:
    """A pretraining run of two sessions that went on past its snapshot at 32 pairs."""
    run.mkdir()
    torch.save({"train_config": {"lr": 5e-4}, "step": 4, "pairs_seen": 64}, run / "last.pt")
    torch.save({"config": {}, "encoder": {}}, run / "teacher_0000032.pt")
    records = [
        {"kind": "start", "step": 0, "pairs": 0},
        {"step": 1, "pairs": 16, "wall_s": 10.0},
        {"step": 2, "pairs": 32, "wall_s": 20.0},
        {"kind": "start", "step": 2, "pairs": 32},
        {"kind": "eval", "step": 2, "pairs": 32, "probe_epe": 2.5},
        {"step": 3, "pairs": 48, "wall_s": 5.0},
        {"kind": "eval", "step": 3, "pairs": 48, "probe_epe": 2.7},
        {"step": 4, "pairs": 64, "wall_s": 9.0},
    ]
    (run / "log.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))


def test_run_summary_stops_at_a_shipped_teacher_snapshot(tmp_path: Path) -> None:
    run = tmp_path / "p"
    _write_run(run)
    whole = run_summary(run)
    assert (whole["pairs_seen"], len(whole["evaluations"])) == (64, 2)
    shipped = run_summary(run, 32)
    assert shipped["shipped_checkpoint"] == "teacher_0000032.pt"
    assert (shipped["steps"], shipped["pairs_seen"], shipped["run_pairs_seen"]) == (2, 32, 64)
    assert [e["probe_epe"] for e in shipped["evaluations"]] == [2.5]
    assert shipped["train_config"] == {"lr": 5e-4}
    assert shipped["train_seconds"] == 20.0
    assert shipped["sessions"] == 2


def test_run_summary_ships_a_finished_runs_student_without_last_pt(tmp_path: Path) -> None:
    run = tmp_path / "p"
    _write_run(run)
    (run / "last.pt").unlink()
    state = {"train_config": {"lr": 1e-3}, "step": 2, "pairs_seen": 32, "train_seconds": 19.0}
    torch.save({"config": {}, "encoder": {}, **state}, run / "student_0000032.pt")
    shipped = run_summary(run, 32, "student")
    assert shipped["shipped_checkpoint"] == "student_0000032.pt"
    assert shipped["train_config"] == {"lr": 1e-3}  # from the snapshot: last.pt is gone
    assert [e["probe_epe"] for e in shipped["evaluations"]] == [2.5]
    with pytest.raises(SystemExit, match="no train_config"):
        run_summary(run, 32, "teacher")  # a bare teacher snapshot holds no recipe


def test_run_summary_names_a_missing_snapshot(tmp_path: Path) -> None:
    run = tmp_path / "p"
    _write_run(run)
    with pytest.raises(SystemExit, match="teacher_0000048.pt"):
        run_summary(run, 48)


def test_run_summary_says_when_a_head_is_interpolated(tmp_path: Path) -> None:
    run = tmp_path / "mid"
    run.mkdir()
    mix = {"start": "a/last.pt", "end": "b/last.pt", "alpha": 0.5}
    torch.save({"train_config": {"lr": 1e-3}, "step": 20, "interpolated": mix}, run / "last.pt")
    assert run_summary(run)["interpolated"] == mix
    torch.save({"train_config": {"lr": 1e-3}, "step": 20}, run / "last.pt")
    assert "interpolated" not in run_summary(run)


def test_head_metrics_must_score_the_shipped_head(tmp_path: Path) -> None:
    run = tmp_path / "hgt"
    run.mkdir()
    torch.save({"train_config": {"lr": 1e-3}, "step": 20000}, run / "last.pt")
    head = run_summary(run)
    check_head_metrics({"head_eval_w160": {"head_step": 20000}}, head)
    check_head_metrics({}, head)
    with pytest.raises(SystemExit, match="step 1000, the shipped head \\(hgt\\) is at step 20000"):
        check_head_metrics({"head_eval_w160": {"head_step": 1000}}, head)
