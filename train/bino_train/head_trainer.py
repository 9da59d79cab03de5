"""A head training run's state: its configuration, its frozen encoder and the `HeadTrainer`.

`HeadTrainConfig` is what a run fixes at its start; `EncoderSource` says where the frozen
encoder came from (`build_encoder` rebuilds it, `encoder_digest` checks it is unchanged);
`HeadTrainer` holds the head, the optimiser and the data stream (a descriptor pool, or a
descriptor cache) and takes one step of AdamW on the head (`train_step`, the LR from
`cosine_lr`); `state_dict` / `load_state_dict` resume a run exactly. The command line is in
head_train.py.
"""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from .config import EncoderConfig
from .head import HeadConfig, StereoHead, head_loss, make_head
from .head_cache import DescriptorCache, load_cache
from .head_data import DataConfig, HeadSampler
from .head_descriptors import DescBatch, DescriptorPool, encode, gather
from .head_qat import HeadRanges, calibrate, check_head, qat_forward
from .head_val import ValidationSet
from .model import BinoEncoder
from .photometric import photometric_terms
from .pretrain_trainer import param_groups, rng_states, set_rng_states

QAT_CALIBRATION = 256
"""Samples the quantisation-aware run calibrates its ranges on."""


@dataclass(frozen=True)
class HeadTrainConfig:
    head: HeadConfig = field(default_factory=HeadConfig)
    data: DataConfig = field(default_factory=DataConfig)
    batch: int = 16
    pool: int = 512
    """Encoded samples kept; `pool == refresh == batch` trains on fresh samples only."""
    refresh: int = 4
    """New samples encoded per step."""
    lr: float = 2e-3
    min_lr: float = 1e-5
    warmup: float = 0.05
    """Fraction of the schedule with a linear LR warm-up."""
    weight_decay: float = 0.01
    clip_grad: float = 5.0
    ce_weight: float = 1.0
    schedule_steps: int = 5000
    seed: int = 0
    cache: str = ""
    """Descriptor cache file (head_cache.py); empty: encode into the pool as the run goes."""
    uniform_weights: bool = False
    """Every labelled cell weighs 1 (ignore the label confidence the data carries)."""
    photometric: float = 0.0
    """Weight of the self-supervised reconstruction term (photometric.py)."""
    smoothness: float = 0.0
    """Weight of the edge-aware smoothness term."""
    val_every: int = 0
    """Steps between validations (head_val.py, never the eval split); 0: none."""
    init_head: str = ""
    """Head checkpoint whose weights start the run (no weight depends on the candidate count,
    so a 12-candidate head starts a 16-candidate run); empty: a fresh head."""
    qat: bool = False
    """Train through the int8 engine's roundings (head_qat.py; the shared head only)."""

    def to_dict(self) -> dict[str, Any]:
        return {**asdict(self), "head": self.head.to_dict()}

    @staticmethod
    def from_dict(d: dict[str, Any]) -> HeadTrainConfig:
        rest = {k: v for k, v in d.items() if k not in ("head", "data")}
        return HeadTrainConfig(
            head=HeadConfig(**d["head"]), data=DataConfig.from_dict(d["data"]), **rest
        )


def check_cache_pathway(path: str, cached: str, wanted: str) -> None:
    """A cache of one pathway's maps never trains the other pathway's head."""
    if cached != wanted:
        raise ValueError(
            f"descriptor cache {path} holds {cached}-pathway maps, this run trains a head of "
            f"the {wanted} pathway (build a cache with head_cache --pathway {wanted}, or pass "
            f"--pathway {cached})"
        )


def initial_head(path: Path, cfg: HeadConfig) -> StereoHead:
    """The head of checkpoint `path` with `cfg`'s candidate count; refused unless it is `cfg`'s
    kind of head in every other setting."""
    from .head import load_head

    head = load_head(path, cfg.max_disp)
    if head.cfg != cfg:
        raise ValueError(f"--init-head {path} is a head of another kind ({head.cfg} vs {cfg})")
    return head


def cosine_lr(step: int, cfg: HeadTrainConfig) -> float:
    """Linear warm-up to `lr`, then cosine down to `min_lr` at `schedule_steps`."""
    warm = max(1, round(cfg.warmup * cfg.schedule_steps))
    if step < warm:
        return cfg.lr * (step + 1) / warm
    progress = min((step - warm) / max(cfg.schedule_steps - warm, 1), 1.0)
    return cfg.min_lr + (cfg.lr - cfg.min_lr) * 0.5 * (1.0 + math.cos(math.pi * progress))


@dataclass(frozen=True)
class EncoderSource:
    """Where the frozen encoder came from; stored in the head checkpoint."""

    kind: str
    """"checkpoint" or "random-init"."""
    path: str = ""
    seed: int = 0
    config: dict[str, Any] | None = None
    """Random-init only: the encoder config (None: the paper config)."""
    sha256: str = ""
    """Hash of the encoder weights: head_eval warns when another encoder is paired with it."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def encoder_digest(encoder: nn.Module) -> str:
    h = hashlib.sha256()
    for name, tensor in sorted(encoder.state_dict().items()):
        h.update(name.encode())
        h.update(tensor.detach().cpu().contiguous().numpy().tobytes())
    return h.hexdigest()


def build_encoder(source: EncoderSource) -> BinoEncoder:
    from .export import load_encoder, random_encoder  # export pulls in onnx

    if source.kind == "checkpoint":
        return load_encoder(Path(source.path))
    cfg = EncoderConfig(**source.config) if source.config else None
    return random_encoder(source.seed, cfg)


class HeadTrainer:
    """Head, optimiser and data stream: the whole run state (the encoder is frozen)."""

    def __init__(
        self,
        cfg: HeadTrainConfig,
        encoder: BinoEncoder,
        source: EncoderSource,
        data_dir: Path | None,
        device: torch.device,
    ) -> None:
        if encoder.cfg.dim != cfg.head.desc_dim:
            raise ValueError(f"encoder dim {encoder.cfg.dim} != head desc_dim {cfg.head.desc_dim}")
        if cfg.data.max_disp != cfg.head.max_disp:
            raise ValueError("data and head disagree on max_disp")
        if cfg.batch > cfg.pool:
            raise ValueError(f"batch {cfg.batch} larger than the pool {cfg.pool}")
        self.cfg = cfg
        self.device = device
        self.encoder = encoder.to(device).eval().requires_grad_(False)
        self.source = source
        torch.manual_seed(cfg.seed)
        self.head = make_head(cfg.head).to(device)
        if cfg.init_head:
            self.head.load_state_dict(initial_head(Path(cfg.init_head), cfg.head).state_dict())
        self.pathway = cfg.head.pathway
        self.opt = torch.optim.AdamW(param_groups([self.head], cfg.weight_decay), lr=cfg.lr)
        self.cache: DescriptorCache | None = None
        if cfg.cache:
            self.cache = load_cache(Path(cfg.cache))
            check_cache_pathway(cfg.cache, self.cache.pathway, self.pathway)
            if self.cache.meta["encoder_sha256"] != source.sha256:
                raise ValueError(f"descriptor cache {cfg.cache} was made by another encoder")
            if DataConfig.from_dict(self.cache.meta["data"]) != cfg.data:
                raise ValueError(f"descriptor cache {cfg.cache} holds other data ({cfg.data})")
        else:
            self.sampler = HeadSampler(cfg.data, cfg.seed, data_dir)
        self.pool = DescriptorPool(cfg.pool, cfg.refresh)
        self.validation: ValidationSet | None = None
        if cfg.val_every > 0:
            self.validation = ValidationSet.build(
                self.encoder, data_dir, cfg.data, device=device, pathway=self.pathway
            )
        if cfg.qat:
            check_head(self.head)
        self.qat_ranges: HeadRanges | None = None
        self.step = 0
        self.train_seconds = 0.0
        self.encode_seconds = 0.0

    def refill(self, step: int) -> None:
        """Encode the samples that step `step` adds to the pool."""
        r = self.cfg.refresh
        samples = self.sampler.samples(range(step * r, (step + 1) * r))
        self.pool.insert(step, encode(self.encoder, samples, self.device, self.pathway))

    def rebuild_pool(self) -> None:
        """The pool as it was after step `self.step - 1` (used on resume)."""
        if self.cache is not None:
            return
        for s in range(max(0, self.step - self.pool.groups), self.step):
            self.refill(s)

    def batch(self) -> DescBatch:
        rng = np.random.default_rng([self.cfg.seed, 1, self.step])
        if self.cache is not None:
            data = self.cache.data
            if self.step == 0 and not self.cfg.init_head:
                n = min(self.cfg.refresh, self.cache.count)
                self.head.init_from(data.left[:n], data.right[:n])
            idx = torch.from_numpy(rng.choice(self.cache.count, size=self.cfg.batch))
            return gather(data, idx)
        t0 = time.perf_counter()
        self.refill(self.step)
        self.encode_seconds += time.perf_counter() - t0
        if self.step == 0 and self.pool.data is not None and not self.cfg.init_head:
            # Fresh run: start the projection from the descriptor statistics (head.py).
            n = self.cfg.refresh
            self.head.init_from(self.pool.data.left[:n], self.pool.data.right[:n])
        return self.pool.draw(rng, self.cfg.batch)

    def train_step(self) -> dict[str, Any]:
        cfg = self.cfg
        data = self.batch()
        lr = cosine_lr(self.step, cfg)
        for group in self.opt.param_groups:
            group["lr"] = lr
        self.head.train()
        if cfg.qat and self.qat_ranges is None:
            self.qat_ranges = self.calibrate_qat()
        if self.qat_ranges is not None:
            out = qat_forward(self.head, self.qat_ranges, data.left.float(), data.right.float())
        else:
            out = self.head(data.left, data.right)
        weight = None if cfg.uniform_weights else data.weight
        parts = head_loss(out, data.label, cfg.ce_weight, weight)
        loss = parts.loss
        extra: dict[str, float] = {}
        if (cfg.photometric > 0 or cfg.smoothness > 0) and data.images is not None:
            photo = photometric_terms(out.disparity, data.images)
            loss = loss + cfg.photometric * photo.reconstruction + cfg.smoothness * photo.smoothness
            extra = {
                "photometric": float(photo.reconstruction.detach()),
                "smoothness": float(photo.smoothness.detach()),
            }
        self.opt.zero_grad(set_to_none=True)
        loss.backward()
        grad_norm = float(nn.utils.clip_grad_norm_(self.head.parameters(), cfg.clip_grad))
        self.opt.step()
        self.step += 1
        return {
            "step": self.step,
            "loss": float(loss.detach()),
            **extra,
            "smooth_l1": parts.smooth_l1,
            "ce": parts.ce,
            "epe_cols": parts.epe_cols,
            "cells": parts.cells,
            "synthetic": float(data.synthetic.float().mean()),
            "lr": lr,
            "grad_norm": grad_norm,
        }

    def calibrate_qat(self) -> HeadRanges:
        """The fake-quantised forward's ranges, from the head as it starts on the first
        QAT_CALIBRATION samples (the cache's, else the pool's)."""
        data = self.cache.data if self.cache is not None else self.pool.data
        if data is None:
            raise ValueError("no descriptors to calibrate the quantisation-aware head on")
        n = min(QAT_CALIBRATION, int(data.left.shape[0]))
        ranges = calibrate(self.head, data.left[:n].float(), data.right[:n].float())
        print(f"qat ranges: {ranges.to_dict()}", flush=True)
        return ranges

    def state_dict(self) -> dict[str, Any]:
        return {
            "qat_ranges": None if self.qat_ranges is None else self.qat_ranges.to_dict(),
            "head_config": self.cfg.head.to_dict(),
            "head": self.head.state_dict(),
            "train_config": self.cfg.to_dict(),
            "encoder_source": self.source.to_dict(),
            "optimizer": self.opt.state_dict(),
            "rng": rng_states(),
            "step": self.step,
            "train_seconds": self.train_seconds,
            "encode_seconds": self.encode_seconds,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.head.load_state_dict(state["head"])
        ranges = state.get("qat_ranges")
        self.qat_ranges = None if ranges is None else HeadRanges.from_dict(ranges)
        self.opt.load_state_dict(state["optimizer"])
        set_rng_states(state["rng"])
        self.step = int(state["step"])
        self.train_seconds = float(state["train_seconds"])
        self.encode_seconds = float(state["encode_seconds"])
        self.rebuild_pool()
