"""A pretraining run's state: its configuration, its schedules and the `Trainer`.

`Trainer` holds the student, the EMA teacher, both DINO heads, the optimiser and the crop and
mask streams; `Trainer.train_step` is one step of the one-view masked token-only distillation
(paper 3.4-3.5) and `state_dict` / `load_state_dict` resume a run exactly. The schedules (LR,
mask ratio, EMA momentum, teacher temperature) are functions of the pair count
(`schedule_position`); the command line is in pretrain.py.
"""

from __future__ import annotations

import copy
import math
import random
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from .augment import AugmentConfig, CropSampler, ParallelCropSampler, to_three_channels
from .config import EncoderConfig
from .dino import (
    DinoConfig,
    DinoHead,
    TokenDistillLoss,
    ema_momentum,
    ema_update,
    teacher_temperature,
)
from .masking import MaskConfig, OneViewMasker, mask_ratio
from .model import BinoEncoder
from .pairs import training_pairs


@dataclass(frozen=True)
class TrainConfig:
    encoder: EncoderConfig = field(default_factory=EncoderConfig)
    dino: DinoConfig = field(default_factory=DinoConfig)
    mask: MaskConfig = field(default_factory=MaskConfig)
    augment: AugmentConfig = field(default_factory=AugmentConfig)
    batch: int = 16
    lr: float = 5e-4
    min_lr: float = 1e-6
    warmup: float = 0.05
    """Fraction of the LR's cosine (`lr_decay_pairs`, else the schedule) spent warming up."""
    lr_decay_pairs: int = 0
    """0: the LR's cosine spans the schedule. Otherwise it ends after this many pairs and the LR
    stays at `min_lr` for the rest of the schedule (whose other schedules still span it all)."""
    weight_decay: float = 0.04
    clip_grad: float = 3.0
    schedule_pairs: int = 16_000
    anneal_from_pairs: int = 0
    """With `anneal_pairs`: where a resumed run's remaining schedule was compressed (a fork)."""
    anneal_pairs: int = 0
    """0: the schedules run on pairs seen. Otherwise what remained of them after
    `anneal_from_pairs` runs over this many pairs (`schedule_position`)."""
    seed: int = 0
    precision: str = "auto"
    """bf16 autocast, fp32, or auto: bf16 where the hardware has it (CUDA, or a CPU with
    bf16 instructions; on AVX2-only CPUs bf16 runs several times slower than fp32)."""

    @property
    def total_steps(self) -> int:
        return math.ceil(self.schedule_pairs / self.batch)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict[str, Any]) -> TrainConfig:
        rest = {k: v for k, v in d.items() if k not in ("encoder", "dino", "mask", "augment")}
        return TrainConfig(
            encoder=EncoderConfig(**d["encoder"]),
            dino=DinoConfig(**d["dino"]),
            mask=MaskConfig(**d["mask"]),
            augment=AugmentConfig.from_dict(d["augment"]),
            **rest,
        )


def schedule_position(pairs: int, cfg: TrainConfig) -> float:
    """Where `pairs` pairs seen put the run on its schedules, in pairs.

    Without an anneal this is `pairs`. An anneal (`--anneal-pairs` on resume) maps the pairs
    after `anneal_from_pairs` linearly onto the rest of the schedule, so every schedule (LR,
    EMA momentum, mask ratio, teacher temperature) continues from where it stood and ends
    `anneal_pairs` later: a short run's tail from a long run's middle.
    """
    start, length = cfg.anneal_from_pairs, cfg.anneal_pairs
    if length <= 0 or pairs <= start:
        return float(pairs)
    rest = max(cfg.schedule_pairs - start, 0)
    return start + min(pairs - start, length) * rest / length


def learning_rate(step: float, cfg: TrainConfig) -> float:
    """Linear warm-up to `lr`, then cosine down to `min_lr` at the end of the schedule (or after
    `lr_decay_pairs`, then `min_lr` to the end)."""
    total = cfg.total_steps
    if 0 < cfg.lr_decay_pairs < cfg.schedule_pairs:
        total = math.ceil(cfg.lr_decay_pairs / cfg.batch)
    warm = max(1, round(cfg.warmup * total))
    if step < warm:
        return cfg.lr * (step + 1) / warm
    progress = min((step - warm) / max(total - warm, 1), 1.0)
    return cfg.min_lr + (cfg.lr - cfg.min_lr) * 0.5 * (1.0 + math.cos(math.pi * progress))


def param_groups(modules: list[nn.Module], weight_decay: float) -> list[dict[str, Any]]:
    """No weight decay on biases, norms and the row embedding."""
    decay: list[nn.Parameter] = []
    plain: list[nn.Parameter] = []
    for module in modules:
        for name, p in module.named_parameters():
            (plain if p.ndim <= 1 or name.endswith("row_embed") else decay).append(p)
    return [{"params": decay, "weight_decay": weight_decay}, {"params": plain, "weight_decay": 0.0}]


def use_bf16(precision: str, device: torch.device) -> bool:
    if precision not in ("auto", "bf16", "fp32"):
        raise ValueError(f"unknown precision {precision!r}")
    if precision != "auto":
        return precision == "bf16"
    if device.type == "cuda":
        return bool(torch.cuda.is_bf16_supported())
    return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())


def rng_states() -> dict[str, Any]:
    states: dict[str, Any] = {
        "python": random.getstate(),
        "numpy": np.random.get_state(),
        "torch": torch.get_rng_state(),
    }
    if torch.cuda.is_available():
        states["cuda"] = torch.cuda.get_rng_state_all()
    return states


def set_rng_states(states: dict[str, Any]) -> None:
    random.setstate(states["python"])
    np.random.set_state(states["numpy"])
    torch.set_rng_state(states["torch"])
    if "cuda" in states and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(states["cuda"])


class Trainer:
    """Student, EMA teacher, heads, optimiser, data and mask streams: the whole run state."""

    def __init__(
        self,
        cfg: TrainConfig,
        data_dir: Path | None,
        device: torch.device,
        *,
        batch_multiplier: int = 1,
        lr_scale: float | None = None,
        chunk_tokens: int | None = None,
        data_workers: int = 0,
    ) -> None:
        if batch_multiplier < 1:
            raise ValueError(f"batch multiplier {batch_multiplier} < 1")
        self.cfg = cfg
        self.device = device
        self.batch_multiplier = batch_multiplier
        self.lr_scale = math.sqrt(batch_multiplier) if lr_scale is None else lr_scale
        torch.manual_seed(cfg.seed)
        self.student = BinoEncoder(cfg.encoder).to(device)
        self.student_head = DinoHead(cfg.encoder.dim, cfg.dino).to(device)
        self.teacher = copy.deepcopy(self.student).requires_grad_(False)
        self.teacher_head = copy.deepcopy(self.student_head).requires_grad_(False)
        self.loss = TokenDistillLoss(cfg.dino).to(device)
        if batch_multiplier != 1 or chunk_tokens is not None:
            # Run-time only: the configuration saved with the run keeps its own values.
            self.loss.cfg = replace(
                cfg.dino,
                center_momentum=cfg.dino.center_momentum**batch_multiplier,
                chunk_tokens=chunk_tokens or cfg.dino.chunk_tokens,
            )
        self.opt = torch.optim.AdamW(
            param_groups([self.student, self.student_head], cfg.weight_decay), lr=cfg.lr
        )
        pairs = training_pairs(data_dir)
        self.sampler: CropSampler | ParallelCropSampler = (
            ParallelCropSampler(pairs, cfg.augment, cfg.seed, self.batch_size, data_workers)
            if data_workers > 0
            else CropSampler(pairs, cfg.augment, seed=cfg.seed)
        )
        cell = (cfg.encoder.patch_h, cfg.encoder.view_cell_w)
        self.masker = OneViewMasker(cfg.mask, cell, seed=cfg.seed + 1)
        self.bf16 = use_bf16(cfg.precision, device)
        self.step = 0
        self.pairs_seen = 0
        self.train_seconds = 0.0

    @property
    def batch_size(self) -> int:
        """Pairs per optimiser step."""
        return self.cfg.batch * self.batch_multiplier

    @property
    def schedule_step(self) -> float:
        """Position on the schedules in steps of the configured batch (= step at that batch,
        unless annealing: `schedule_position`)."""
        return schedule_position(self.pairs_seen, self.cfg) / self.cfg.batch

    def train_step(self) -> dict[str, Any]:
        cfg, step, dev = self.cfg, self.schedule_step, self.device
        multiplier = self.batch_multiplier
        clean_left, clean_right, left, right = self.sampler.next_batch_with_clean(self.batch_size)
        if not cfg.augment.teacher_clean:
            clean_left, clean_right = left, right
        ratio = mask_ratio(step, cfg.total_steps, cfg.mask)
        masked = self.masker(left, right, ratio)
        lr = learning_rate(step, cfg)
        if self.lr_scale != 1.0:
            lr *= self.lr_scale
        for group in self.opt.param_groups:
            group["lr"] = lr
        temp = teacher_temperature(
            step,
            round(cfg.dino.teacher_temp_warmup * cfg.total_steps),
            cfg.dino.teacher_temp_start,
            cfg.dino.teacher_temp_end,
        )
        views = [
            to_three_channels(v.to(dev))
            for v in (clean_left, clean_right, masked.left, masked.right)
        ]
        with torch.autocast(dev.type, dtype=torch.bfloat16, enabled=self.bf16):
            with torch.no_grad():
                t_tokens = self.teacher(views[0], views[1])
            s_tokens = self.student(views[2], views[3])
            d = s_tokens.shape[-1]
            out = self.loss(
                s_tokens.reshape(-1, d),
                t_tokens.reshape(-1, d),
                self.student_head,
                self.teacher_head,
                masked.token_mask.reshape(-1).to(dev),
                temp,
            )
        self.opt.zero_grad(set_to_none=True)
        out.loss.backward()
        params = [p for g in self.opt.param_groups for p in g["params"]]
        grad_norm = float(nn.utils.clip_grad_norm_(params, cfg.clip_grad))
        self.opt.step()
        momentum = ema_momentum(step, cfg.total_steps, cfg.dino.momentum_start)
        if multiplier != 1:
            momentum **= multiplier
        ema_update(self.teacher, self.student, momentum)
        ema_update(self.teacher_head, self.student_head, momentum)
        self.step += 1
        self.pairs_seen += self.batch_size
        record: dict[str, Any] = {
            "step": self.step,
            "pairs": self.pairs_seen,
            "loss": float(out.loss.detach()),
            "kl": out.kl,
            "ce_masked": out.ce_masked,
            "ce_unmasked": out.ce_unmasked,
            "teacher_entropy": out.teacher_entropy,
            "marginal_entropy": out.marginal_entropy,
            "prototypes_used": out.prototypes_used,
            "lr": lr,
            "mask_ratio": ratio,
            "teacher_temp": temp,
            "momentum": momentum,
            "grad_norm": grad_norm,
        }
        if multiplier != 1:
            record["batch"] = self.batch_size
        return record

    def run_fields(self) -> dict[str, Any]:
        """The run's configuration and progress, kept in every file the run writes (checkpoint,
        evaluation snapshots, weights-only snapshots) so each one describes the run alone."""
        return {
            "train_config": self.cfg.to_dict(),
            "step": self.step,
            "pairs_seen": self.pairs_seen,
            "train_seconds": self.train_seconds,
        }

    def state_dict(self) -> dict[str, Any]:
        return {
            "config": self.cfg.encoder.to_dict(),
            "encoder": self.teacher.state_dict(),
            **self.run_fields(),
            "student": self.student.state_dict(),
            "teacher": self.teacher.state_dict(),
            "student_head": self.student_head.state_dict(),
            "teacher_head": self.teacher_head.state_dict(),
            "loss": self.loss.state_dict(),
            "optimizer": self.opt.state_dict(),
            "data": self.sampler.state_dict(),
            "masker": self.masker.state_dict(),
            "rng": rng_states(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.student.load_state_dict(state["student"])
        self.teacher.load_state_dict(state["teacher"])
        self.student_head.load_state_dict(state["student_head"])
        self.teacher_head.load_state_dict(state["teacher_head"])
        self.loss.load_state_dict(state["loss"])
        self.opt.load_state_dict(state["optimizer"])
        self.sampler.load_state_dict(state["data"])
        self.masker.load_state_dict(state["masker"])
        set_rng_states(state["rng"])
        self.step = int(state["step"])
        self.pairs_seen = int(state["pairs_seen"])
        self.train_seconds = float(state["train_seconds"])
