"""Token distillation loss, head, EMA, and schedules."""

from __future__ import annotations

import copy
import math

import pytest
import torch
import torch.nn.functional as F

from bino_train.dino import (
    DinoConfig,
    DinoHead,
    TokenDistillLoss,
    ema_momentum,
    ema_update,
    teacher_temperature,
)

CFG = DinoConfig(prototypes=3000, hidden=48, bottleneck=16, masked_weight=2.0, unmasked_weight=0.5)


def _setup(chunk: int):  # type: ignore[no-untyped-def]
    torch.manual_seed(0)
    cfg = DinoConfig(**{**CFG.to_dict(), "chunk_tokens": chunk})
    student_head, teacher_head = DinoHead(32, cfg), DinoHead(32, cfg)
    loss = TokenDistillLoss(cfg)
    loss.center.normal_(0.0, 0.1)
    tokens = torch.randn(2500, 32, requires_grad=True)
    teacher_tokens = torch.randn(2500, 32)
    mask = torch.rand(2500) < 0.3
    return cfg, student_head, teacher_head, loss, tokens, teacher_tokens, mask


def _reference(cfg, student_head, teacher_head, center, tokens, teacher_tokens, mask, temp):  # type: ignore[no-untyped-def]
    """The paper's formula, written plainly over all tokens at once."""
    pt = F.softmax((teacher_head(teacher_tokens) - center) / temp, dim=-1).detach()
    log_ps = F.log_softmax(student_head(tokens) / cfg.student_temp, dim=-1)
    weights = torch.where(mask, cfg.masked_weight, cfg.unmasked_weight)
    return (-(pt * log_ps).sum(-1) * weights).sum() / weights.sum()


def test_chunked_cross_entropy_equals_the_unchunked_formula() -> None:
    results = []
    for chunk in (1024, 100_000):
        cfg, s_head, t_head, loss, tokens, t_tokens, mask = _setup(chunk)
        center = loss.center.clone()
        out = loss(tokens, t_tokens, s_head, t_head, mask, teacher_temp=0.05)
        out.loss.backward()
        ref = _reference(cfg, s_head, t_head, center, tokens.detach(), t_tokens, mask, 0.05)
        assert float(out.loss.detach()) == pytest.approx(float(ref.detach()), rel=1e-5)
        results.append((out, tokens.grad.clone(), s_head.prototypes.grad.clone(), loss.center))
    (a, ga, pa, ca), (b, gb, pb, cb) = results
    assert float(a.loss.detach()) == pytest.approx(float(b.loss.detach()), rel=1e-6)
    assert torch.allclose(ga, gb, atol=1e-7, rtol=1e-4)
    assert torch.allclose(pa, pb, atol=1e-7, rtol=1e-4)
    assert torch.allclose(ca, cb, atol=1e-6)
    assert a.prototypes_used == b.prototypes_used
    assert a.teacher_entropy == pytest.approx(b.teacher_entropy, rel=1e-5)
    assert a.kl == pytest.approx(b.kl, rel=1e-4) and a.kl >= 0.0


def test_center_is_an_ema_of_the_batch_mean_teacher_logits() -> None:
    cfg, s_head, t_head, loss, tokens, t_tokens, mask = _setup(1024)
    before = loss.center.clone()
    loss(tokens, t_tokens, s_head, t_head, mask, teacher_temp=0.05)
    with torch.no_grad():
        batch_mean = t_head(t_tokens).mean(0, keepdim=True)
    m = cfg.center_momentum
    assert torch.allclose(loss.center, m * before + (1 - m) * batch_mean, atol=1e-6)


def test_uniform_weights_make_the_loss_a_plain_token_mean() -> None:
    torch.manual_seed(1)
    cfg = DinoConfig(prototypes=64, hidden=16, bottleneck=8)
    head = DinoHead(8, cfg)
    x, y = torch.randn(50, 8), torch.randn(50, 8)
    all_masked = TokenDistillLoss(cfg)(x, y, head, head, torch.ones(50, dtype=torch.bool), 0.04)
    none_masked = TokenDistillLoss(cfg)(x, y, head, head, torch.zeros(50, dtype=torch.bool), 0.04)
    assert float(all_masked.loss.detach()) == pytest.approx(
        float(none_masked.loss.detach()), rel=1e-6
    )


def test_head_gives_cosine_logits() -> None:
    head = DinoHead(32, DinoConfig(prototypes=10, hidden=16, bottleneck=8))
    head.prototypes.data[0] *= 100.0  # weight norm with fixed gain: the scale does not matter
    with torch.no_grad():
        logits = head(torch.randn(5, 32))
    assert logits.shape == (5, 10) and float(logits.abs().max()) <= 1.0 + 1e-5


def test_ema_update_moves_teacher_towards_student() -> None:
    student = torch.nn.Linear(3, 3)
    teacher = copy.deepcopy(student)
    with torch.no_grad():
        student.weight.add_(1.0)
    old = teacher.weight.clone()
    ema_update(teacher, student, 0.9)
    assert torch.allclose(teacher.weight, 0.9 * old + 0.1 * student.weight)
    ema_update(teacher, student, 1.0)
    assert torch.allclose(teacher.weight, 0.9 * old + 0.1 * student.weight)


def test_schedule_endpoints() -> None:
    assert ema_momentum(0, 100, 0.996) == pytest.approx(0.996)
    assert ema_momentum(50, 100, 0.996) == pytest.approx(0.998)
    assert ema_momentum(100, 100, 0.996) == pytest.approx(1.0)
    assert ema_momentum(200, 100, 0.996) == pytest.approx(1.0)
    assert teacher_temperature(0, 30, 0.04, 0.07) == pytest.approx(0.04)
    assert teacher_temperature(15, 30, 0.04, 0.07) == pytest.approx(0.055)
    assert teacher_temperature(30, 30, 0.04, 0.07) == pytest.approx(0.07)
    assert teacher_temperature(0, 0, 0.04, 0.07) == pytest.approx(0.07)
    assert math.isclose(teacher_temperature(10**6, 30, 0.04, 0.07), 0.07)
