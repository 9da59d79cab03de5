"""Quantisation-aware head training (`head_qat`): the int8 engine's roundings in the forward."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
import torch
from conftest import TINY_SYNTHETIC_DATA, cpu_trainer, save_tiny_cache, tiny_cached_config

import bino_train.head_qat as qat
from bino_train.export import random_encoder
from bino_train.head import HeadConfig, StereoHead, make_head
from bino_train.head_train import SMOKE_ENCODER, SMOKE_HEAD

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def tiny_head(seed: int = 0) -> StereoHead:
    torch.manual_seed(seed)
    head = StereoHead(replace(SMOKE_HEAD, desc_dim=32, max_disp=6))
    with torch.no_grad():  # an affine LayerNorm, so that folding it is tested
        head.norm.weight.uniform_(0.5, 1.5)
        head.norm.bias.uniform_(-0.2, 0.2)
    return head


def maps(seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.randn(2, 4, 12, 32, generator=g), torch.randn(2, 4, 12, 32, generator=g)


def test_fake_quant_rounds_to_the_grid_and_passes_gradients_straight() -> None:
    x = torch.tensor([-3.0, -0.26, 0.0, 0.24, 0.9, 5.0], requires_grad=True)
    y = qat.fake_quant(x, 0.5, -4, 4)
    assert y.tolist() == [-2.0, -0.5, 0.0, 0.0, 1.0, 2.0]
    y.sum().backward()
    assert x.grad is not None and x.grad.tolist() == [1.0] * 6
    u = qat.fake_quant_unsigned(torch.tensor([-1.0, 0.3, 2.0]), 1.0)
    assert u[0] == 0 and u[2] == 1.0 and abs(float(u[1]) - 0.3) <= 0.5 / 255


def test_weights_round_per_output_channel_to_127_levels() -> None:
    w = torch.tensor([[1.0, -0.5, 0.003], [100.0, 3.0, -40.0]])
    q = qat.fake_quant_weight(w)
    for row, qrow in zip(w, q, strict=True):
        step = float(row.abs().max()) / 127
        codes = qrow / step
        assert torch.allclose(codes, codes.round(), atol=1e-4)
        assert float((qrow - row).abs().max()) <= step / 2 + 1e-6
    assert q[0, 2] == 0.0  # below half a step of its own channel


def test_without_rounding_the_forward_is_the_float_heads(monkeypatch: pytest.MonkeyPatch) -> None:
    head, (left, right) = tiny_head(), maps(1)
    ranges = qat.calibrate(head, left, right)
    assert len(ranges.hidden) == head.cfg.middle_layers + 1
    assert min(ranges.z, ranges.proj, ranges.corr, *ranges.hidden) > 0
    monkeypatch.setattr(qat, "fake_quant", lambda x, *a, **k: x)
    monkeypatch.setattr(qat, "fake_quant_unsigned", lambda x, top: x)
    monkeypatch.setattr(qat, "fake_quant_weight", lambda w: w)
    with torch.no_grad():
        ours, float_head = qat.qat_forward(head, ranges, left, right), head(left, right)
    assert torch.allclose(ours.logits, float_head.logits, atol=1e-4)
    assert torch.allclose(ours.disparity, float_head.disparity, atol=1e-5)


def test_rounding_moves_the_disparity_a_little_and_keeps_gradients() -> None:
    head, (left, right) = tiny_head(), maps(2)
    ranges = qat.calibrate(head, left, right)
    out = qat.qat_forward(head, ranges, left, right)
    with torch.no_grad():
        gap = (out.disparity - head(left, right).disparity).abs().mean()
    assert 0 < float(gap) < 0.5
    out.disparity.sum().backward()
    assert head.stem.weight.grad is not None and head.proj.weight.grad is not None
    assert float(head.stem.weight.grad.abs().sum()) > 0


def test_only_the_shared_head_trains_quantisation_aware() -> None:
    native = HeadConfig(pair_features="concat")
    with pytest.raises(ValueError, match="shared"):
        qat.check_head(make_head(native))


def test_a_qat_run_keeps_its_ranges_and_resumes_exactly(tmp_path: Path) -> None:
    encoder = random_encoder(0, SMOKE_ENCODER)
    path = tmp_path / "cache.pt"
    save_tiny_cache(path, encoder, TINY_SYNTHETIC_DATA, 0, 8)
    cfg = replace(tiny_cached_config(path, TINY_SYNTHETIC_DATA), qat=True)
    straight = cpu_trainer(cfg, encoder)
    for _ in range(4):
        straight.train_step()
    assert straight.qat_ranges is not None
    split = cpu_trainer(cfg, encoder)
    for _ in range(2):
        split.train_step()
    resumed = cpu_trainer(cfg, encoder)
    resumed.load_state_dict(split.state_dict())
    assert resumed.qat_ranges == split.qat_ranges == straight.qat_ranges
    for _ in range(2):
        resumed.train_step()
    for name, tensor in straight.head.state_dict().items():
        assert torch.equal(tensor, resumed.head.state_dict()[name]), name
