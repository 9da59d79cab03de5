"""The pretraining loop: exact resume, checkpoint contents, schedules."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import pytest
import torch

from bino_train.export import load_encoder
from bino_train.manifest import run_summary
from bino_train.pretrain import (
    TrainConfig,
    Trainer,
    build_config,
    learning_rate,
    main,
    parse_args,
    schedule_position,
    smoke_report,
)

COMMON = ["--config", "small", "--batch", "2", "--schedule-pairs", "16", "--precision", "fp32"]


def _assert_same(a: Any, b: Any, where: str = "") -> None:
    if isinstance(a, torch.Tensor):
        assert isinstance(b, torch.Tensor) and torch.equal(a, b), where
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for key in a:
            _assert_same(a[key], b[key], f"{where}/{key}")
    elif isinstance(a, list | tuple):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _assert_same(x, y, f"{where}[{i}]")
    else:
        assert a == b, where


def test_resume_is_exact(data_dir: Path, tmp_path: Path) -> None:
    data = ["--data", str(data_dir), "--no-eval", "--log-every", "1"]
    straight, split = tmp_path / "straight", tmp_path / "split"
    main(["--out", str(straight), "--pairs", "8", *COMMON, *data])
    main(["--out", str(split), "--pairs", "4", *COMMON, *data])
    halfway = torch.load(split / "last.pt", weights_only=False)
    # The resumed leg takes its configuration from the checkpoint, not from the command line.
    main(["--out", str(split), "--pairs", "8", "--resume", *data])
    a = torch.load(straight / "last.pt", weights_only=False)
    b = torch.load(split / "last.pt", weights_only=False)
    assert a["step"] == b["step"] == 4 and halfway["step"] == 2
    for key in (
        "student",
        "teacher",
        "student_head",
        "teacher_head",
        "loss",
        "optimizer",
        "data",
        "masker",
        "encoder",
        "config",
        "train_config",
        "pairs_seen",
    ):
        _assert_same(a[key], b[key], key)
    # Training did move the weights, so the equality above means something.
    assert not torch.equal(a["student"]["row_embed"], halfway["student"]["row_embed"])
    records = [json.loads(line) for line in (split / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in records if "loss" in r] == [1, 2, 3, 4]
    assert [r["step"] for r in records if r.get("kind") == "start"] == [0, 2]


def test_checkpoint_loads_in_export_as_the_teacher(data_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    main(["--out", str(out), "--pairs", "2", *COMMON, "--data", str(data_dir), "--no-eval"])
    state = torch.load(out / "last.pt", weights_only=False)
    encoder = load_encoder(out / "last.pt")
    _assert_same(encoder.state_dict(), state["teacher"])
    assert encoder.cfg.dim == 32
    assert {"python", "numpy", "torch"} <= state["rng"].keys()
    with pytest.raises(SystemExit):  # a fresh run never overwrites a checkpoint
        main(["--out", str(out), "--pairs", "2", *COMMON, "--data", str(data_dir)])


def test_trainer_draws_only_train_pairs(data_dir: Path) -> None:
    cfg = TrainConfig.from_dict(TrainConfig(batch=2).to_dict())
    trainer = Trainer(cfg, data_dir, torch.device("cpu"))
    assert {p.split for p in trainer.sampler.store.pairs} == {"train"}


def test_learning_rate_schedule_endpoints() -> None:
    cfg = TrainConfig(lr=1e-3, min_lr=1e-5, warmup=0.1, schedule_pairs=1600, batch=16)
    assert cfg.total_steps == 100
    assert learning_rate(0, cfg) == pytest.approx(1e-4)
    assert learning_rate(9, cfg) == pytest.approx(1e-3)
    assert learning_rate(100, cfg) == pytest.approx(1e-5)
    assert learning_rate(1000, cfg) == pytest.approx(1e-5)
    assert learning_rate(10, cfg) > learning_rate(50, cfg) > learning_rate(90, cfg)


def test_learning_rate_can_decay_early_then_hold_its_floor() -> None:
    """--lr-decay-pairs: p1's 30,000-pair cosine inside a longer schedule, then the floor."""
    args = parse_args(
        ["--out", "x", "--pairs", "9", "--lr-decay-pairs", "1600", "--min-lr", "2e-5"]
    )
    cfg = dataclasses.replace(
        build_config(args), lr=1e-3, warmup=0.1, schedule_pairs=16000, batch=16
    )
    assert cfg.lr_decay_pairs == 1600 and cfg.min_lr == pytest.approx(2e-5)
    assert learning_rate(0, cfg) == pytest.approx(1e-4)
    assert learning_rate(9, cfg) == pytest.approx(1e-3)
    assert learning_rate(50, cfg) < learning_rate(20, cfg)
    for step in (100, 500, 999):
        assert learning_rate(step, cfg) == pytest.approx(2e-5)
    spanning = dataclasses.replace(cfg, lr_decay_pairs=0)
    assert learning_rate(500, spanning) > 10 * learning_rate(500, cfg)
    assert TrainConfig.from_dict(cfg.to_dict()).lr_decay_pairs == 1600


def test_teacher_temperature_warmup_is_a_fraction_of_the_schedule() -> None:
    """A long schedule keeps the short warm-up that avoided collapse (p2 vs p1)."""
    args = parse_args(["--out", "x", "--pairs", "9", "--teacher-temp-warmup", "0.06"])
    assert build_config(args).dino.teacher_temp_warmup == pytest.approx(0.06)
    assert build_config(
        parse_args(["--out", "x", "--pairs", "9"])
    ).dino.teacher_temp_warmup == pytest.approx(0.3)


def test_smoke_report_judges_the_kl() -> None:
    rising_ce = [{"loss": 1.0 + i, "kl": 1.0 - 0.1 * i} for i in range(8)]
    assert smoke_report(rising_ce)
    assert not smoke_report([{"loss": 1.0, "kl": 0.1 * i} for i in range(8)])


def test_evaluation_logs_probe_and_benchmark_and_snapshots_teacher(
    data_dir: Path, tmp_path: Path
) -> None:
    out = tmp_path / "run"
    main(
        ["--out", str(out), "--pairs", "2", *COMMON, "--data", str(data_dir), "--bench-pairs", "2"]
    )
    records = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    evals = [r for r in records if r.get("kind") == "eval"]
    assert len(evals) == 1
    for key in ("probe_epe", "probe_bad1tok", "probe_bad2", "easy_pck0", "hard_epe_tok"):
        assert key in evals[0]
    snapshot = out / "teacher_0000002.pt"
    assert load_encoder(snapshot).cfg.dim == 32
    assert not (out / "student_0000002.pt").exists()  # only with --eval-student


def test_evaluation_with_the_student_snapshots_it_too(data_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    data = ["--data", str(data_dir), "--bench-pairs", "2", "--eval-student"]
    main(["--out", str(out), "--pairs", "2", *COMMON, *data])
    teacher, student = (load_encoder(out / f"{r}_0000002.pt") for r in ("teacher", "student"))
    assert "student_probe_epe" in (out / "log.jsonl").read_text()
    differ = [
        not torch.equal(a, b)
        for a, b in zip(teacher.state_dict().values(), student.state_dict().values(), strict=True)
    ]
    assert any(differ), "the student's own weights, not the teacher's"
    # A finished run's student alone (last.pt not kept) describes the run for the manifest.
    (out / "last.pt").unlink()
    summary = run_summary(out, upto_pairs=2, role="student")
    assert summary["pairs_seen"] == 2 and summary["train_config"]["batch"] > 0
    assert summary["shipped_checkpoint"] == "student_0000002.pt"


def test_anneal_compresses_the_rest_of_the_schedule() -> None:
    cfg = TrainConfig(lr=1e-3, min_lr=1e-5, warmup=0.1, schedule_pairs=1600, batch=16)
    fork = dataclasses.replace(cfg, anneal_from_pairs=480, anneal_pairs=160)
    # Unchanged up to the fork, continuous there, at the schedule's end 160 pairs later.
    assert schedule_position(320, fork) == 320
    assert schedule_position(480, fork) == 480
    assert schedule_position(560, fork) == pytest.approx(480 + 80 * 1120 / 160)
    assert schedule_position(640, fork) == pytest.approx(1600)
    assert schedule_position(5000, fork) == pytest.approx(1600)
    assert schedule_position(640, cfg) == 640
    assert learning_rate(schedule_position(640, fork) / 16, fork) == pytest.approx(1e-5)


def test_anneal_fork_ends_on_the_schedule_tail(data_dir: Path, tmp_path: Path) -> None:
    data = ["--data", str(data_dir), "--no-eval", "--log-every", "1"]
    run = tmp_path / "run"
    main(["--out", str(run), "--pairs", "4", *COMMON, "--schedule-pairs", "64", *data])
    # 4 pairs past the anneal's end: those steps run at the schedules' end values.
    main(["--out", str(run), "--pairs", "12", "--resume", "--anneal-pairs", "4", *data])
    state = torch.load(run / "last.pt", weights_only=False)
    assert state["train_config"]["anneal_from_pairs"] == 4
    assert state["train_config"]["anneal_pairs"] == 4
    records = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    assert [r["pairs"] for r in records if r.get("kind") == "anneal"] == [4]
    lrs = [r["lr"] for r in records if "loss" in r]
    assert len(lrs) == 6 and lrs[1] > 1e-4
    # Past the anneal's end the LR sits on the cosine's floor, as at a full schedule's end.
    assert lrs[-1] == pytest.approx(TrainConfig().min_lr)
    with pytest.raises(SystemExit, match="already anneals"):
        main(["--out", str(run), "--pairs", "16", "--resume", "--anneal-pairs", "4", *data])


def test_mask_ratio_fork_replaces_the_schedule_from_where_the_run_stands(
    data_dir: Path, tmp_path: Path
) -> None:
    data = ["--data", str(data_dir), "--no-eval", "--log-every", "1"]
    run = tmp_path / "run"
    main(["--out", str(run), "--pairs", "4", *COMMON, "--schedule-pairs", "64", *data])
    main(["--out", str(run), "--pairs", "8", "--resume", "--fork-mask-ratio", "0.5", "0.5", *data])
    state = torch.load(run / "last.pt", weights_only=False)
    mask = state["train_config"]["mask"]
    assert (mask["ratio_start"], mask["ratio_end"]) == (0.5, 0.5)
    records = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    fork = [r for r in records if r.get("kind") == "fork_mask_ratio"]
    assert len(fork) == 1 and fork[0]["pairs"] == 4 and fork[0]["ratio_after"] == 0.5
    assert fork[0]["ratio_before"] < 0.5
    ratios = [r["mask_ratio"] for r in records if "loss" in r]
    assert ratios[0] < 0.5 and ratios[-1] == pytest.approx(0.5)
    with pytest.raises(SystemExit):
        main(
            [
                "--out",
                str(tmp_path / "fresh"),
                "--pairs",
                "4",
                "--fork-mask-ratio",
                "0.5",
                "0.5",
                *data,
            ]
        )
