"""DINO-style token self-distillation (paper section 3.4): head, centred and sharpened teacher,
token-only cross-entropy, EMA teacher, and the momentum and temperature schedules.

The loss runs over token chunks (default 1024 tokens) so that no (tokens x K) tensor larger
than a chunk is ever allocated at once: with K = 4096 a whole-batch allocation dominated the
step time (notes/training-cpu.md).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor, nn


@dataclass(frozen=True)
class DinoConfig:
    prototypes: int = 1024
    hidden: int = 512
    bottleneck: int = 128
    student_temp: float = 0.1
    teacher_temp_start: float = 0.04
    teacher_temp_end: float = 0.07
    teacher_temp_warmup: float = 0.3
    """Fraction of the schedule over which the teacher temperature rises linearly."""
    center_momentum: float = 0.9
    momentum_start: float = 0.996
    """EMA momentum at step 0; it follows a cosine up to 1 at the end of the schedule."""
    masked_weight: float = 1.0
    unmasked_weight: float = 1.0
    """Token weights in the cross-entropy: uniform (the paper's best) when equal."""
    chunk_tokens: int = 1024
    head_bn: bool = False
    """BatchNorm after the head's hidden layer (DINO's `use_bn`): removes the component all
    tokens share, which otherwise dominates the cosine logits and flattens the teacher."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def ema_momentum(step: float, total_steps: int, start: float) -> float:
    """Cosine from `start` at step 0 to 1 at `total_steps` (then held at 1)."""
    progress = min(max(step / max(total_steps, 1), 0.0), 1.0)
    return 1.0 - (1.0 - start) * (math.cos(math.pi * progress) + 1.0) / 2.0


def teacher_temperature(step: float, warmup_steps: int, start: float, end: float) -> float:
    """Linear warm-up from `start` to `end` over `warmup_steps`, then `end`."""
    if step >= warmup_steps:
        return end
    return start + (end - start) * step / warmup_steps


class DinoHead(nn.Module):
    """MLP d -> hidden -> bottleneck, L2-normalised, then cosine logits against K prototypes.

    The prototype layer is weight-normalised with its gain fixed to 1 (DINO's
    norm_last_layer), written out as a normalisation of the weight rows.
    """

    def __init__(self, in_dim: int, cfg: DinoConfig) -> None:
        super().__init__()
        norm: nn.Module = nn.BatchNorm1d(cfg.hidden) if cfg.head_bn else nn.Identity()
        self.mlp = nn.Sequential(
            nn.Linear(in_dim, cfg.hidden), norm, nn.GELU(), nn.Linear(cfg.hidden, cfg.bottleneck)
        )
        self.prototypes = nn.Parameter(torch.empty(cfg.prototypes, cfg.bottleneck))
        for m in self.mlp:
            if isinstance(m, nn.Linear):
                nn.init.trunc_normal_(m.weight, std=0.02)
                nn.init.zeros_(m.bias)
        nn.init.trunc_normal_(self.prototypes, std=0.02)

    def forward(self, x: Tensor) -> Tensor:
        z = F.normalize(self.mlp(x).float(), dim=-1)
        # Cosine logits get divided by temperatures of ~0.05: keep them out of bf16.
        with torch.autocast(z.device.type, enabled=False):
            return F.linear(z, F.normalize(self.prototypes.float(), dim=-1))


class LossOutput(NamedTuple):
    loss: Tensor
    teacher_entropy: float
    """Mean entropy of the per-token teacher distributions (nats)."""
    marginal_entropy: float
    """Entropy of the batch-mean teacher distribution (nats; ln K at most)."""
    prototypes_used: int
    """Distinct teacher argmax prototypes in the batch."""
    kl: float
    """Weighted mean KL(p_t || p_s): the part of the loss the student can still reduce."""
    ce_masked: float
    ce_unmasked: float


class TokenDistillLoss(nn.Module):
    """Token-only cross-entropy H(p_t, p_s) over all tokens, with a running teacher centre."""

    center: Tensor

    def __init__(self, cfg: DinoConfig) -> None:
        super().__init__()
        self.cfg = cfg
        self.register_buffer("center", torch.zeros(1, cfg.prototypes))

    def forward(
        self,
        student_tokens: Tensor,
        teacher_tokens: Tensor,
        student_head: DinoHead,
        teacher_head: DinoHead,
        token_mask: Tensor,
        teacher_temp: float,
        update_center: bool = True,
    ) -> LossOutput:
        """Tokens (N, d) aligned by slot; `token_mask` (N,) marks tokens of masked cells."""
        cfg = self.cfg
        n, k = student_tokens.shape[0], cfg.prototypes
        mask = token_mask.reshape(-1).to(student_tokens.device)
        weights = torch.where(mask, cfg.masked_weight, cfg.unmasked_weight).float()
        total = student_tokens.new_zeros((), dtype=torch.float32)
        teacher_sum = torch.zeros(k, device=student_tokens.device)
        prob_sum = torch.zeros(k, device=student_tokens.device)
        entropy_sum = torch.zeros((), device=student_tokens.device)
        kl_sum = torch.zeros((), device=student_tokens.device)
        ce_tokens = []
        used = torch.zeros(k, dtype=torch.bool, device=student_tokens.device)
        for i in range(0, n, cfg.chunk_tokens):
            j = min(i + cfg.chunk_tokens, n)
            log_ps = F.log_softmax(student_head(student_tokens[i:j]).float() / cfg.student_temp, -1)
            with torch.no_grad():
                zt = teacher_head(teacher_tokens[i:j]).float()
                log_pt = F.log_softmax((zt - self.center) / teacher_temp, dim=-1)
                pt = log_pt.exp()
                teacher_sum += zt.sum(0)
                prob_sum += pt.sum(0)
                entropy_tok = -(pt * log_pt).sum(-1)
                entropy_sum += entropy_tok.sum()
                used[pt.argmax(-1)] = True
            ce = -(pt * log_ps).sum(-1)
            ce_tokens.append(ce.detach())
            kl_sum += ((ce.detach() - entropy_tok) * weights[i:j]).sum()
            total = total + (ce * weights[i:j]).sum()
        weight_sum = weights.sum().clamp_min(1e-12)
        loss = total / weight_sum
        if update_center:
            self._update_center(teacher_sum / n)
        ce_all = torch.cat(ce_tokens)
        marginal = prob_sum / n
        return LossOutput(
            loss=loss,
            teacher_entropy=float(entropy_sum) / n,
            marginal_entropy=float(-(marginal * marginal.clamp_min(1e-12).log()).sum()),
            prototypes_used=int(used.sum()),
            kl=float(kl_sum / weight_sum),
            ce_masked=float(ce_all[mask].mean()) if bool(mask.any()) else float("nan"),
            ce_unmasked=float(ce_all[~mask].mean()) if bool((~mask).any()) else float("nan"),
        )

    @torch.no_grad()
    def _update_center(self, batch_mean: Tensor) -> None:
        m = self.cfg.center_momentum
        self.center.mul_(m).add_(batch_mean.reshape(1, -1), alpha=1.0 - m)


@torch.no_grad()
def ema_update(teacher: nn.Module, student: nn.Module, momentum: float) -> None:
    """teacher <- momentum * teacher + (1 - momentum) * student, parameter by parameter."""
    t_params: list[Tensor] = list(teacher.parameters())
    s_params: list[Tensor] = list(student.parameters())
    if len(t_params) != len(s_params):
        raise ValueError("teacher and student have different parameter lists")
    torch._foreach_lerp_(t_params, s_params, 1.0 - momentum)
