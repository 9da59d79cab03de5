"""The end-to-end fine-tuning run: which weights it trains, and that it resumes exactly."""

from __future__ import annotations

from dataclasses import asdict, replace
from pathlib import Path

import pytest
import torch

from bino_train.e2e_tune import TuneConfig, Tuner, lr_scale, main, trainable_blocks
from bino_train.export import random_encoder
from bino_train.head import make_head
from bino_train.head_train import SMOKE_ENCODER, SMOKE_HEAD

pytestmark = pytest.mark.usefixtures("one_torch_thread")

TINY_ENCODER = replace(SMOKE_ENCODER, depth=3)
TINY_NATIVE = replace(SMOKE_HEAD, desc_dim=TINY_ENCODER.dim, pair_features="concat", max_disp=8)


def _start_files(tmp_path: Path) -> tuple[Path, Path]:
    encoder = random_encoder(0, TINY_ENCODER)
    torch.save(
        {"config": encoder.cfg.to_dict(), "encoder": encoder.state_dict()}, tmp_path / "e.pt"
    )
    torch.manual_seed(1)
    head = make_head(TINY_NATIVE)
    torch.save({"head_config": asdict(head.cfg), "head": head.state_dict()}, tmp_path / "h.pt")
    return tmp_path / "e.pt", tmp_path / "h.pt"


def _config(tmp_path: Path, blocks: int, steps: int = 4) -> TuneConfig:
    encoder, head = _start_files(tmp_path)
    # Synthetic crops only: the test needs no labeled pairs.
    return TuneConfig(
        encoder=str(encoder),
        head=str(head),
        blocks=blocks,
        steps=steps,
        batch=2,
        max_disp=8,
        synthetic_fraction=1.0,
        labeled_fraction=0.0,
    )


def test_only_the_last_blocks_train() -> None:
    encoder = random_encoder(0, TINY_ENCODER)
    params = trainable_blocks(encoder, 2)
    trained = {id(p) for p in params}
    assert trained == {id(p) for b in encoder.blocks[1:] for p in b.parameters()}
    assert all(p.requires_grad == (id(p) in trained) for p in encoder.parameters())
    assert trainable_blocks(encoder, 0) == []
    assert not any(p.requires_grad for p in encoder.parameters())
    with pytest.raises(ValueError, match="--blocks 4"):
        trainable_blocks(encoder, 4)


def test_lr_warms_up_then_decays_to_its_floor() -> None:
    cfg = TuneConfig(encoder="", head="", steps=100, warmup=0.1, min_lr_ratio=0.05)
    scales = [lr_scale(s, cfg) for s in range(100)]
    assert scales[0] == pytest.approx(0.1) and scales[9] == pytest.approx(1.0)
    assert all(a >= b for a, b in zip(scales[9:], scales[10:], strict=False))
    assert lr_scale(1000, cfg) == pytest.approx(0.05)


def test_a_step_moves_the_trained_blocks_and_the_head_only(tmp_path: Path) -> None:
    tuner = Tuner(_config(tmp_path, blocks=1), tmp_path)
    before = {k: v.clone() for k, v in tuner.encoder.state_dict().items()}
    head_before = {k: v.clone() for k, v in tuner.head.state_dict().items()}
    tuner.train_step()
    tuner.train_step()
    after = tuner.encoder.state_dict()
    moved = {k for k in before if not torch.equal(before[k], after[k])}
    assert moved and all(k.startswith("blocks.2.") for k in moved)
    assert any(not torch.equal(v, tuner.head.state_dict()[k]) for k, v in head_before.items())


def test_resume_continues_exactly(tmp_path: Path) -> None:
    cfg = _config(tmp_path, blocks=1)
    straight = Tuner(cfg, tmp_path)
    for _ in range(4):
        straight.train_step()
    first = Tuner(cfg, tmp_path)
    first.train_step()
    first.train_step()
    state = first.state_dict()
    resumed = Tuner(cfg, tmp_path)
    resumed.load_state_dict(state)
    resumed.train_step()
    resumed.train_step()
    for k, v in straight.encoder.state_dict().items():
        assert torch.equal(v, resumed.encoder.state_dict()[k]), k
    for k, v in straight.head.state_dict().items():
        assert torch.equal(v, resumed.head.state_dict()[k]), k


def test_command_refuses_a_missing_start_and_an_existing_run(tmp_path: Path) -> None:
    encoder, _ = _start_files(tmp_path)
    run = tmp_path / "run"
    with pytest.raises(SystemExit, match="--head .*nope.pt does not exist"):
        main(["--out", str(run), "--encoder", str(encoder), "--head", str(tmp_path / "nope.pt")])
    assert not run.exists()
    run.mkdir()
    (run / "checkpoint.pt").write_bytes(b"")
    with pytest.raises(SystemExit, match="exists; pass --resume"):
        main(["--out", str(run), "--encoder", str(encoder)])
    with pytest.raises(SystemExit, match="no checkpoint"):
        main(["--out", str(tmp_path / "other"), "--resume"])
