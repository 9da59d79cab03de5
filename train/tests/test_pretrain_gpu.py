"""The GPU-leg options of the pretraining: batch multiplier, bf16, weights-only snapshots and
--init-from. CPU only; the CUDA path is covered up to its argument handling."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from bino_train.dino import ema_momentum
from bino_train.export import load_encoder
from bino_train.pretrain import TrainConfig, Trainer, learning_rate, main
from bino_train.pretrain_weights import MAX_FILE_BYTES

COMMON = ["--config", "small", "--batch", "2", "--schedule-pairs", "16", "--precision", "fp32"]


def _records(path: Path) -> list[dict[str, object]]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_batch_multiplier_keeps_the_pair_schedule(data_dir: Path) -> None:
    cfg = TrainConfig.from_dict(TrainConfig(batch=2, schedule_pairs=16, precision="fp32").to_dict())
    small = Trainer(cfg, data_dir, torch.device("cpu"), batch_multiplier=1)
    big = Trainer(cfg, data_dir, torch.device("cpu"), batch_multiplier=4)
    assert big.batch_size == 8 and big.lr_scale == pytest.approx(2.0)
    assert big.loss.cfg.center_momentum == pytest.approx(0.9**4)
    assert big.cfg == cfg and small.loss.cfg is cfg.dino  # the saved configuration is untouched
    first = big.train_step()
    second = big.train_step()
    assert (first["pairs"], first["batch"], big.schedule_step) == (8, 8, 8)
    assert first["lr"] == pytest.approx(2.0 * learning_rate(0, cfg))
    assert second["lr"] == pytest.approx(2.0 * learning_rate(4, cfg))
    assert second["mask_ratio"] > first["mask_ratio"]
    start = cfg.dino.momentum_start
    assert second["momentum"] == pytest.approx(ema_momentum(4, cfg.total_steps, start) ** 4)
    record = small.train_step()
    assert small.schedule_step == small.step == 1 and "batch" not in record


def test_weights_out_then_init_from_continues_the_schedule(data_dir: Path, tmp_path: Path) -> None:
    data = ["--data", str(data_dir), "--no-eval", "--log-every", "1"]
    gpu_leg, weights, cpu_leg = tmp_path / "gpu", tmp_path / "weights", tmp_path / "cpu"
    main(["--out", str(gpu_leg), "--pairs", "8", *COMMON, *data, "--batch-multiplier", "2"])
    main(["--out", str(gpu_leg), "--resume", "--pairs", "8", *data, "--weights-out", str(weights)])
    assert sorted(p.name for p in weights.iterdir()) == ["log.jsonl", "student.pt", "teacher.pt"]
    teacher = torch.load(weights / "teacher.pt")
    assert teacher["pairs_seen"] == 8 and teacher["step"] == 2
    assert all(
        v.dtype == torch.float16 for v in teacher["encoder"].values() if v.is_floating_point()
    )
    assert teacher["center"].dtype == torch.float32
    for name in ("teacher.pt", "student.pt"):
        assert (weights / name).stat().st_size < MAX_FILE_BYTES
    assert load_encoder(weights / "teacher.pt").cfg.dim == 32  # loads like a checkpoint
    assert _records(weights / "log.jsonl")[-1] == {"kind": "weights", "step": 2, "pairs": 8}

    main(["--out", str(cpu_leg), "--init-from", str(weights), "--pairs", "12", *data])
    state = torch.load(cpu_leg / "last.pt", weights_only=False)
    assert (state["step"], state["pairs_seen"]) == (4, 12)
    assert state["train_config"] == teacher["train_config"]
    records = _records(cpu_leg / "log.jsonl")
    steps = [r for r in records if "loss" in r]
    assert [r["pairs"] for r in steps] == [4, 8, 10, 12]  # the GPU leg's log, then this one
    assert steps[2]["lr"] == pytest.approx(
        learning_rate(4, TrainConfig.from_dict(state["train_config"]))
    )
    assert any(r.get("kind") == "init" and r["exact"] is False for r in records)
    # Back at the configured batch: exact --resume works from here on.
    main(["--out", str(cpu_leg), "--resume", "--pairs", "14", *data])
    assert torch.load(cpu_leg / "last.pt", weights_only=False)["pairs_seen"] == 14


def test_init_from_checks_the_log(data_dir: Path, tmp_path: Path) -> None:
    data = ["--data", str(data_dir), "--no-eval"]
    weights = tmp_path / "weights"
    main(
        [
            "--out",
            str(tmp_path / "a"),
            "--pairs",
            "2",
            *COMMON,
            *data,
            "--weights-out",
            str(weights),
        ]
    )
    (weights / "log.jsonl").write_text(
        json.dumps({"kind": "weights", "step": 9, "pairs": 99}) + "\n"
    )
    with pytest.raises(ValueError, match="ends at 99 pairs"):
        main(["--out", str(tmp_path / "b"), "--init-from", str(weights), "--pairs", "4", *data])


def test_bf16_leg_runs_on_the_cpu(data_dir: Path, tmp_path: Path) -> None:
    # bf16 autocast runs on any CPU (slowly without bf16 instructions).
    out = tmp_path / "bf16"
    small = ["--config", "small", "--batch", "2", "--schedule-pairs", "16", "--bf16"]
    args = ["--out", str(out), "--pairs", "8", *small, "--batch-multiplier", "2"]
    main(
        [*args, "--chunk-tokens", "8192", "--data", str(data_dir), "--no-eval", "--log-every", "1"]
    )
    state = torch.load(out / "last.pt", weights_only=False)
    assert state["train_config"]["precision"] == "bf16" and state["pairs_seen"] == 8
    losses = [r["loss"] for r in _records(out / "log.jsonl") if "loss" in r]
    assert len(losses) == 2 and all(math.isfinite(v) for v in losses)


@pytest.mark.parametrize(
    "extra",
    [
        ["--bf16", "--precision", "fp32"],
        ["--resume", "--init-from", "somewhere"],
    ],
)
def test_contradictory_options_are_usage_errors(tmp_path: Path, extra: list[str]) -> None:
    with pytest.raises(SystemExit) as err:
        main(["--out", str(tmp_path / "x"), "--pairs", "2", *extra])
    assert err.value.code == 2


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a GPU")
def test_device_cuda_without_a_gpu_fails_clearly(data_dir: Path, tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match="no CUDA GPU"):
        main(["--out", str(tmp_path / "x"), "--pairs", "2", *COMMON, "--device", "cuda"])


def test_data_workers_feed_the_same_schedule(data_dir: Path) -> None:
    cfg = TrainConfig.from_dict(TrainConfig(batch=2, schedule_pairs=16, precision="fp32").to_dict())
    trainer = Trainer(cfg, data_dir, torch.device("cpu"), batch_multiplier=2, data_workers=2)
    records = [trainer.train_step() for _ in range(2)]
    assert [r["pairs"] for r in records] == [4, 8]
    assert all(math.isfinite(r["loss"]) for r in records)
    assert trainer.sampler.state_dict() == {"batches": 2, "workers": 2}


def test_gpu_script_starts_a_new_run_from_a_recipe(data_dir: Path, tmp_path: Path) -> None:
    script = Path(__file__).resolve().parents[2] / "scripts" / "gpu_pretrain.sh"
    out = tmp_path / "out"
    env = os.environ | {
        "OUT": str(out),
        "BINO_PYTHON": sys.executable,
        "BINO_GPU_DEVICE": "cpu",
        "BINO_GPU_PRECISION": "fp32",
        "BINO_GPU_PACK": str(data_dir),
        "BINO_GPU_WORKERS": "1",
        "BINO_GPU_PAIRS": "8",
        "BINO_GPU_NEW": "--config small --batch 4 --schedule-pairs 400 --blur-prob 0.25",
    }
    done = subprocess.run(
        ["bash", str(script), "1", "1"], env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stdout + done.stderr
    assert "new run: --config small" in done.stdout
    snapshot = torch.load(out / "student.pt", map_location="cpu", weights_only=False)
    assert snapshot["pairs_seen"] == 8 and snapshot["train_config"]["schedule_pairs"] == 400
    assert snapshot["train_config"]["augment"]["blur_prob"] == 0.25
    assert any(r.get("kind") == "weights" for r in _records(out / "log.jsonl"))
