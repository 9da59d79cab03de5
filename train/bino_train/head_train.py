"""Training of the shared stereo head on a frozen encoder.

    python -m bino_train.head_train --encoder runs/PRE/last.pt --out runs/NAME --minutes 30
    python -m bino_train.head_train --out runs/NAME --resume --minutes 30   # continue exactly
    python -m bino_train.head_train --random-init-seed 0 --out runs/NAME --steps 200
    python -m bino_train.head_train --random-init-seed 0 --out runs/smoke --smoke  # seconds
    python -m bino_train.head_train --encoder E --cache runs/headcache/C.pt --out runs/NAME \
        --steps 20000 --batch 8 --val-every 1000 [--photometric 1 --smoothness 0.05]
    python -m bino_train.head_train --encoder E --cache runs/headcache/N.pt --pathway native \
        [--pair-features full] --steps 4000 --batch 8 --uniform-weights --out runs/NAME

Supervision (head_data.py): synthetic scenes with known sub-pixel disparity and StereoSGBM
pseudo-labels on train-split crops (48 x 160 after resizing to 160 .. 320 px wide); never the
eval split. The encoder is frozen: descriptors are computed under no_grad and kept in a
descriptor pool (`--pool`, `--refresh`), so one encoder pass serves several head steps; or,
with `--cache` (head_cache.py), every crop is encoded once before training and a step costs
only the head. Labels carry a confidence (`--label-weighting lr`: SGBM's sub-pixel left-right
agreement; `--uniform-weights` ignores it);
`--photometric` / `--smoothness` add the self-supervised terms of photometric.py. `--pathway
native` trains a native head (head.NativeHead, NATIVE_HEADS) on the phase maps of one encoder
pass on (L, R); a cache holds one pathway's maps and a run refuses the other pathway's. The head
trains on the train split less the validation pairs, which `--val-every` scores (head_val.py).
AdamW with linear warm-up then cosine decay over `--schedule-steps` (fixed at the start).

The run folder holds `last.pt` (head, optimiser, step, encoder reference; written atomically,
resume is exact), `log.jsonl`, and with evaluation an `eval` record (head and SGBM on the eval
split at w160, see head_eval.py). `--steps` is a cumulative target; `--minutes` bounds this
invocation. Ctrl-C or SIGTERM stops after the current step and checkpoints.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import signal
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from .config import EncoderConfig
from .head import NATIVE_HEADS, HeadConfig, StereoHead, head_loss, make_head
from .head_cache import DescriptorCache, cache_pathway, load_cache, load_cache_meta
from .head_data import (
    PATHWAYS,
    DataConfig,
    DescBatch,
    DescriptorPool,
    HeadSampler,
    encode,
    gather,
)
from .head_qat import HeadRanges, calibrate, check_head, qat_forward
from .head_val import ValidationSet
from .model import BinoEncoder, parameter_count
from .photometric import photometric_terms
from .pretrain import StopFlag, param_groups, rng_states, save_atomic, set_rng_states

ASSUMED_STEPS_PER_S = {"cpu": 0.5, "cuda": 10.0}
"""Only used to turn --minutes into a schedule length when neither --steps nor
--schedule-steps is given (CPU: measured on 1 busy core; CUDA: a rough guess)."""

SMOKE_ENCODER = EncoderConfig(dim=32, depth=2, heads=2, mlp_hidden=64)
QAT_CALIBRATION = 256
"""Samples the quantisation-aware run calibrates its ranges on."""
SMOKE_HEAD = HeadConfig(proj_dim=16, groups=4, hidden=8, middle_layers=1)


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


@dataclass
class RunOptions:
    out: Path
    data_dir: Path | None
    target_steps: int | None
    minutes: float | None
    checkpoint_minutes: float = 5.0
    evaluate: bool = True
    log_every: int = 10


def run(trainer: HeadTrainer, opts: RunOptions) -> list[dict[str, Any]]:
    """Train until a stop condition; returns this invocation's step records."""
    opts.out.mkdir(parents=True, exist_ok=True)
    log_path = opts.out / "log.jsonl"

    def log(record: dict[str, Any]) -> None:
        with log_path.open("a") as f:
            f.write(json.dumps(record) + "\n")

    flag = StopFlag()
    previous = [signal.signal(s, flag) for s in (signal.SIGINT, signal.SIGTERM)]
    start = last_ckpt = time.perf_counter()
    records: list[dict[str, Any]] = []

    def done() -> bool:
        if flag.stop:
            return True
        if opts.target_steps is not None and trainer.step >= opts.target_steps:
            return True
        return opts.minutes is not None and time.perf_counter() - start >= 60.0 * opts.minutes

    log({"kind": "start", "step": trainer.step, "time": time.time()})
    try:
        while not done():
            t0 = time.perf_counter()
            record = trainer.train_step()
            trainer.train_seconds += time.perf_counter() - t0
            record["wall_s"] = round(trainer.train_seconds, 3)
            record["encode_s"] = round(trainer.encode_seconds, 3)
            records.append(record)
            if trainer.step % opts.log_every == 0:
                log(record)
                print(
                    f"step {record['step']} loss {record['loss']:.4f} "
                    f"(sl1 {record['smooth_l1']:.3f} ce {record['ce']:.3f}) "
                    f"epe {record['epe_cols']:.3f} col lr {record['lr']:.2e} "
                    f"{record['wall_s']:.0f}s (encode {record['encode_s']:.0f}s)",
                    flush=True,
                )
            every = trainer.cfg.val_every
            if trainer.validation is not None and every > 0 and trainer.step % every == 0:
                val = {
                    "kind": "val",
                    "step": trainer.step,
                    **trainer.validation.score(trainer.head),
                }
                log(val)
                print(f"val step {trainer.step}: {json.dumps(val)}", flush=True)
            if time.perf_counter() - last_ckpt >= 60.0 * opts.checkpoint_minutes:
                save_atomic(trainer.state_dict(), opts.out / "last.pt")
                last_ckpt = time.perf_counter()
        save_atomic(trainer.state_dict(), opts.out / "last.pt")
        if opts.evaluate:
            from .head_eval import evaluate_head  # reads the eval split: scoring only

            t0 = time.perf_counter()
            metrics = evaluate_head(trainer.encoder, trainer.head, opts.data_dir)  # its pathway
            record = {"kind": "eval", "step": trainer.step, **metrics}
            record["eval_s"] = round(time.perf_counter() - t0, 2)
            log(record)
            print(json.dumps(record), flush=True)
    finally:
        for s, handler in zip((signal.SIGINT, signal.SIGTERM), previous, strict=True):
            signal.signal(s, handler)
    return records


def smoke_report(records: list[dict[str, Any]]) -> bool:
    """Did the loss fall? Mean of the first quarter of steps against the last quarter."""
    if not records:
        print("smoke: no steps ran")
        return False
    n = max(1, len(records) // 4)
    losses = [float(r["loss"]) for r in records]
    first, last = sum(losses[:n]) / n, sum(losses[-n:]) / n
    ok = all(math.isfinite(v) for v in losses) and last < first
    print(f"smoke: loss {first:.4f} -> {last:.4f}: {'decreased' if ok else 'did NOT decrease'}")
    return ok


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    source = p.add_mutually_exclusive_group()
    source.add_argument("--encoder", type=Path, help="frozen encoder checkpoint (pretrain last.pt)")
    source.add_argument("--random-init-seed", type=int, help="frozen encoder at a seeded init")
    p.add_argument("--out", type=Path, required=True, help="run folder (runs/NAME)")
    p.add_argument("--resume", action="store_true", help="continue from OUT/last.pt")
    p.add_argument("--minutes", type=float, help="wall-clock budget of this invocation")
    p.add_argument("--steps", type=int, help="cumulative steps to reach")
    p.add_argument("--schedule-steps", type=int, help="LR schedule length (default: --steps)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--batch", type=int)
    p.add_argument("--pool", type=int, help="encoded samples kept (default 512)")
    p.add_argument("--refresh", type=int, help="samples encoded per step (default 4)")
    p.add_argument("--lr", type=float)
    p.add_argument("--synthetic-fraction", type=float, help="share of synthetic samples")
    p.add_argument("--widths", type=int, nargs=2, metavar=("MIN", "MAX"), help="resize widths")
    p.add_argument(
        "--max-disp",
        type=int,
        help="candidates of the head and its labels (default 12; 16 reaches 60 px at w320)",
    )
    p.add_argument("--data", type=Path, default=None, help="folder with PAIRS.tsv")
    p.add_argument("--synthetic-only", action="store_true", help="no SGBM pseudo-labels")
    p.add_argument("--cache", type=Path, help="descriptor cache (head_cache.py): no encoding")
    p.add_argument(
        "--label-weighting", choices=("binary", "lr"), help="SGBM label confidence (no --cache)"
    )
    p.add_argument("--pathway", choices=PATHWAYS, default="export", help="the maps the head reads")
    p.add_argument(
        "--pair-features",
        choices=tuple(NATIVE_HEADS),
        help="native head's pair features: [a, b] (concat, default) or [a, b, |a-b|, a*b] (full)",
    )
    p.add_argument("--uniform-weights", action="store_true", help="ignore label confidence")
    p.add_argument("--init-head", type=Path, help="head checkpoint that starts the run's weights")
    p.add_argument(
        "--qat", action="store_true", help="train through the int8 head's roundings (head_qat.py)"
    )
    p.add_argument("--photometric", type=float, help="weight of the photometric term")
    p.add_argument("--smoothness", type=float, help="weight of the edge-aware smoothness term")
    p.add_argument("--val-every", type=int, help="steps between validations (0: none)")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    p.add_argument("--checkpoint-minutes", type=float, default=5.0)
    p.add_argument("--no-eval", action="store_true", help="skip the eval-split score at the end")
    p.add_argument("--log-every", type=int, default=10)
    p.add_argument(
        "--smoke", action="store_true", help="tiny run of seconds; exit 1 unless the loss fell"
    )
    args = p.parse_args(argv)
    if args.smoke:
        args.steps, args.no_eval, args.log_every = args.steps or 60, True, 10
        args.synthetic_only = True
    if args.pair_features is not None and args.pathway != "native":
        p.error("--pair-features needs --pathway native")
    if not args.resume and args.encoder is None and args.random_init_seed is None:
        p.error("give --encoder or --random-init-seed (or --resume)")
    if args.steps is None and args.minutes is None:
        p.error("give --steps and/or --minutes")
    return args


def _given(**values: Any) -> dict[str, Any]:
    return {k: v for k, v in values.items() if v is not None}


def head_config(pathway: str, pair_features: str | None, desc_dim: int) -> HeadConfig:
    """The head a pathway trains: the shared head (export), a native head (NATIVE_HEADS)."""
    if pathway == "native":
        return replace(NATIVE_HEADS[pair_features or "concat"], desc_dim=desc_dim)
    return HeadConfig(desc_dim=desc_dim)


def build_config(args: argparse.Namespace, desc_dim: int, device: torch.device) -> HeadTrainConfig:
    fraction = 1.0 if args.synthetic_only else args.synthetic_fraction
    if args.cache is not None:
        if fraction is not None or args.widths is not None or args.label_weighting is not None:
            sys.exit("error: with --cache the data comes from the cache")
        meta = load_cache_meta(args.cache)
        try:
            check_cache_pathway(str(args.cache), cache_pathway(meta), args.pathway)
        except ValueError as err:
            sys.exit(f"error: {err}")
        data = DataConfig.from_dict(meta["data"])
    else:
        data = DataConfig(
            **_given(synthetic_fraction=fraction, label_weighting=args.label_weighting)
        )
    if args.widths is not None:
        data = replace(data, min_width=args.widths[0], max_width=args.widths[1])
    head = head_config(args.pathway, args.pair_features, desc_dim)
    if args.max_disp is not None:
        if args.cache is not None and args.max_disp != data.max_disp:
            sys.exit(f"error: the cache {args.cache} holds labels for {data.max_disp} candidates")
        data = replace(data, max_disp=args.max_disp)
        head = replace(head, max_disp=args.max_disp)
    schedule = args.schedule_steps or args.steps
    if schedule is None:
        schedule = round(60.0 * args.minutes * ASSUMED_STEPS_PER_S[device.type])
    cfg = HeadTrainConfig(
        head=head,
        data=data,
        seed=args.seed,
        schedule_steps=schedule,
        cache=str(args.cache.resolve()) if args.cache is not None else "",
        uniform_weights=args.uniform_weights,
        init_head=str(args.init_head.resolve()) if args.init_head is not None else "",
        qat=args.qat,
        **_given(
            batch=args.batch,
            pool=args.pool,
            refresh=args.refresh,
            lr=args.lr,
            photometric=args.photometric,
            smoothness=args.smoothness,
            val_every=args.val_every,
        ),
    )
    if args.smoke:
        # Tiny encoder, head and crops: CPU seconds, still the full data and loss path.
        cfg = replace(
            cfg,
            head=replace(SMOKE_HEAD, desc_dim=desc_dim, pair_features=cfg.head.pair_features),
            data=replace(cfg.data, crop_h=32, crop_w=96),
            batch=args.batch or 8,
            pool=args.pool or 8,
            refresh=args.refresh or 8,
            lr=args.lr or 5e-3,
        )
    return cfg


def encoder_source(args: argparse.Namespace) -> EncoderSource:
    if args.encoder is not None:
        if not args.encoder.is_file():
            sys.exit(f"error: encoder checkpoint {args.encoder} does not exist")
        return EncoderSource("checkpoint", path=str(args.encoder.resolve()))
    config = SMOKE_ENCODER.to_dict() if args.smoke else None
    return EncoderSource("random-init", seed=args.random_init_seed, config=config)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    elif args.smoke:
        # Tiny tensors: extra threads only add barrier waits (ruinous on a busy machine).
        torch.set_num_threads(1)
    use_cuda = args.device == "cuda" or (args.device == "auto" and torch.cuda.is_available())
    device = torch.device("cuda" if use_cuda else "cpu")
    ckpt = args.out / "last.pt"
    if args.resume:
        if args.encoder is not None or args.random_init_seed is not None:
            sys.exit("error: a resumed run takes its encoder from the checkpoint")
        state = torch.load(ckpt, map_location="cpu", weights_only=False)
        cfg = HeadTrainConfig.from_dict(state["train_config"])
        source = EncoderSource(**state["encoder_source"])
        encoder = build_encoder(source)
        if encoder_digest(encoder) != source.sha256:
            sys.exit(f"error: the encoder at {source.path or source.kind} changed since the start")
        trainer = HeadTrainer(cfg, encoder, source, args.data, device)
        trainer.load_state_dict(state)
        print(f"resumed {ckpt} at step {trainer.step}")
    else:
        if ckpt.exists() and not args.smoke:
            sys.exit(f"error: {ckpt} exists; pass --resume or choose another --out")
        if args.smoke and (args.out / "log.jsonl").exists():
            (args.out / "log.jsonl").unlink()
        source = encoder_source(args)
        encoder = build_encoder(source)
        cfg = build_config(args, encoder.cfg.dim, device)
        source = replace(source, sha256=encoder_digest(encoder))
        trainer = HeadTrainer(cfg, encoder, source, args.data, device)
        print(
            f"head {parameter_count(trainer.head):,} parameters; encoder {source.kind} "
            f"{source.path or source.seed}; schedule {cfg.schedule_steps} steps",
            flush=True,
        )
    opts = RunOptions(
        out=args.out,
        data_dir=args.data,
        target_steps=args.steps,
        minutes=args.minutes,
        checkpoint_minutes=args.checkpoint_minutes,
        evaluate=not args.no_eval,
        log_every=args.log_every,
    )
    records = run(trainer, opts)
    print(f"done: step {trainer.step}, checkpoint {ckpt}")
    if args.smoke:
        sys.exit(0 if smoke_report(records) else 1)


if __name__ == "__main__":
    main()
