"""Self-supervised pretraining: one-view masked token-only distillation (paper 3.4-3.5).

    python -m bino_train.pretrain --out runs/NAME --minutes 9          # a fresh run
    python -m bino_train.pretrain --out runs/NAME --resume --minutes 9 # continue it exactly
    python -m bino_train.pretrain --out runs/NAME --pairs 16000 --config paper --seed 0
    python -m bino_train.pretrain --out runs/smoke --smoke             # seconds, for CI
    python -m bino_train.pretrain --out runs/NAME --resume --device cuda --bf16 \
        --batch-multiplier 4 --minutes 8 --weights-out OUT                # a GPU leg
    python -m bino_train.pretrain --out runs/NAME2 --init-from OUT --minutes 9  # back on CPU

The EMA teacher sees the full pair, the student the pair with one view masked. `--pairs N`
is a cumulative target over all invocations of a run; `--minutes M` bounds this invocation.
Schedules (LR, mask ratio, EMA momentum, teacher temperature) run over `--schedule-pairs`
(default: --pairs, else M minutes at an assumed throughput), fixed when the run starts.

The run folder holds `last.pt` (everything needed to resume exactly; also loadable by
`python -m bino_train.export --checkpoint`, whose `config` and `encoder` keys are the teacher
encoder), `log.jsonl` (one record per logged step, plus `"kind": "eval"` records with the
no-linkage probe and the controlled benchmark of the teacher), and a `teacher_<pairs>.pt`
snapshot at each evaluation (and `student_<pairs>.pt` with `--eval-student`). Ctrl-C or
SIGTERM stops after the current step and checkpoints.

Schedules are functions of the pair count: the schedule step is `pairs // batch` (the
configured batch), which is the step itself in a run at that batch. `--batch-multiplier M`
trains a leg at M times the batch (a GPU's large batch) on the same schedules, scaling the LR
by sqrt(M) (Adam's square-root rule; `--lr-scale` overrides) and raising the teacher's EMA
momentum and the centre momentum to the power M (the EMA scaling rule), so the averages span
the same number of pairs. `--weights-out DIR` writes fp16 teacher and student weights and the
log at each checkpoint (pretrain_weights.py); `--init-from DIR` starts a run folder from them,
not exactly (fresh optimiser): see pretrain_weights.py.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import random
import signal
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from types import FrameType
from typing import Any

import numpy as np
import torch
from torch import nn

from .augment import AugmentConfig, CropSampler, ParallelCropSampler, to_three_channels
from .benchmark import BenchPair, make_benchmark, run_all
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
from .pretrain_weights import init_from, load_weights, save_weights, start_log
from .probe import ProbeItem, encoder_describe, load_probe_set, run_probe

ASSUMED_PAIRS_PER_S = {"cpu": 6.9, "cuda": 150.0}
"""Only used to turn --minutes into a schedule length when none is given."""

SMALL_ENCODER = EncoderConfig(dim=32, depth=2, heads=2, mlp_hidden=64)
SMALL_DINO = DinoConfig(prototypes=64, hidden=64, bottleneck=32)


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


def save_atomic(obj: dict[str, Any], path: Path) -> None:
    """Write then rename, so a crash mid-write never leaves a broken checkpoint."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


class Evaluator:
    """Probe (eval split, w160) and controlled benchmark of an encoder; data loaded once."""

    def __init__(self, data_dir: Path | None, bench_pairs: int, probe: bool) -> None:
        self.data_dir = data_dir
        self.bench_pairs = bench_pairs
        self.probe = probe
        self._probe_items: list[ProbeItem] | None = None
        self._bench: dict[str, list[BenchPair]] | None = None

    def __call__(self, encoder: BinoEncoder) -> dict[str, float]:
        describe = encoder_describe(encoder)
        out: dict[str, float] = {}
        if self.probe:
            if self._probe_items is None:
                self._probe_items = load_probe_set(self.data_dir, "w160")
            probe = run_probe(describe, self._probe_items)
            out.update({f"probe_{k}": probe[k] for k in ("epe", "bad1tok", "bad2")})
        if self.bench_pairs > 0:
            if self._bench is None:
                self._bench = make_benchmark(self.data_dir, self.bench_pairs, seed=0)
            out.update(run_all(describe, self._bench))
        return out


@dataclass
class RunOptions:
    out: Path
    data_dir: Path | None
    target_pairs: int | None
    minutes: float | None
    checkpoint_minutes: float = 10.0
    eval_minutes: float = 10.0
    eval_at_end: bool = True
    probe: bool = True
    bench_pairs: int = 32
    log_every: int = 5
    eval_student: bool = False
    """Also evaluate the student: the EMA teacher lags it, so short runs show trends earlier."""
    weights_out: Path | None = None
    """Also write fp16 teacher/student weights and the log here at each checkpoint."""


class StopFlag:
    """Signal handler for SIGINT/SIGTERM: finish the current step, checkpoint, stop."""

    def __init__(self) -> None:
        self.stop = False

    def __call__(self, signum: int, frame: FrameType | None) -> None:
        print(f"signal {signum}: stopping after this step", file=sys.stderr)
        self.stop = True


def run(trainer: Trainer, opts: RunOptions) -> list[dict[str, Any]]:
    """Train until a stop condition; returns this invocation's step records."""
    opts.out.mkdir(parents=True, exist_ok=True)
    log_path = opts.out / "log.jsonl"
    evaluator = Evaluator(opts.data_dir, opts.bench_pairs, opts.probe)
    flag = StopFlag()
    previous = [signal.signal(s, flag) for s in (signal.SIGINT, signal.SIGTERM)]
    start = last_ckpt = last_eval = time.perf_counter()
    records: list[dict[str, Any]] = []

    def log(record: dict[str, Any]) -> None:
        with log_path.open("a") as f:
            f.write(json.dumps(record) + "\n")

    def evaluate() -> None:
        t0 = time.perf_counter()
        metrics = evaluator(trainer.teacher)
        roles = [("teacher", trainer.teacher)]
        if opts.eval_student:
            metrics |= {f"student_{k}": v for k, v in evaluator(trainer.student).items()}
            trainer.student.train()
            # Either encoder may probe lower; both are kept (p6's best student was lost).
            roles.append(("student", trainer.student))
        for role, encoder in roles:
            # With the run's fields, a finished run's snapshot alone makes the manifest (its
            # last.pt, the optimiser state, is not kept).
            torch.save(
                {
                    "config": trainer.cfg.encoder.to_dict(),
                    "encoder": encoder.state_dict(),
                    **trainer.run_fields(),
                    "role": role,
                },
                opts.out / f"{role}_{trainer.pairs_seen:07d}.pt",
            )
        record = {"kind": "eval", "step": trainer.step, "pairs": trainer.pairs_seen, **metrics}
        record["eval_s"] = round(time.perf_counter() - t0, 2)
        log(record)
        print(json.dumps(record), flush=True)

    def done() -> bool:
        if flag.stop:
            return True
        if opts.target_pairs is not None and trainer.pairs_seen >= opts.target_pairs:
            return True
        return opts.minutes is not None and time.perf_counter() - start >= 60.0 * opts.minutes

    def checkpoint() -> None:
        save_atomic(trainer.state_dict(), opts.out / "last.pt")
        if opts.weights_out is not None:
            log({"kind": "weights", "step": trainer.step, "pairs": trainer.pairs_seen})
            sizes = save_weights(trainer, opts.weights_out, log_path)
            print(f"weights at {trainer.pairs_seen} pairs: {opts.weights_out} {sizes}", flush=True)

    log({"kind": "start", "step": trainer.step, "pairs": trainer.pairs_seen, "time": time.time()})
    try:
        while not done():
            t0 = time.perf_counter()
            record = trainer.train_step()
            trainer.train_seconds += time.perf_counter() - t0
            record["wall_s"] = round(trainer.train_seconds, 3)
            record["pairs_per_s"] = round(trainer.batch_size / (time.perf_counter() - t0), 3)
            records.append(record)
            if trainer.step % opts.log_every == 0:
                log(record)
                print(
                    f"step {record['step']} pairs {record['pairs']} loss {record['loss']:.4f} "
                    f"H_t {record['teacher_entropy']:.3f} protos {record['prototypes_used']} "
                    f"{record['pairs_per_s']:.2f} pairs/s",
                    flush=True,
                )
            now = time.perf_counter()
            if opts.eval_minutes > 0 and now - last_eval >= 60.0 * opts.eval_minutes:
                evaluate()
                last_eval = time.perf_counter()
            if now - last_ckpt >= 60.0 * opts.checkpoint_minutes:
                checkpoint()
                last_ckpt = time.perf_counter()
        checkpoint()
        if opts.eval_at_end and (opts.probe or opts.bench_pairs > 0):
            evaluate()
    finally:
        for s, handler in zip((signal.SIGINT, signal.SIGTERM), previous, strict=True):
            signal.signal(s, handler)
    return records


def _given(**values: Any) -> dict[str, Any]:
    """The command-line values that were set."""
    return {k: v for k, v in values.items() if v is not None}


def build_config(args: argparse.Namespace) -> TrainConfig:
    """A fresh run's configuration: the preset, then any overrides from the command line."""
    small = args.config == "small"
    dino = replace(
        SMALL_DINO if small else DinoConfig(),
        **_given(
            prototypes=args.prototypes,
            masked_weight=args.masked_weight,
            unmasked_weight=args.unmasked_weight,
            momentum_start=args.momentum,
        ),
    )
    if args.head_bn:
        dino = replace(dino, head_bn=True)
    if args.teacher_temp is not None:
        dino = replace(dino, teacher_temp_start=args.teacher_temp[0])
        dino = replace(dino, teacher_temp_end=args.teacher_temp[1])
    if args.teacher_temp_warmup is not None:
        dino = replace(dino, teacher_temp_warmup=args.teacher_temp_warmup)
    mask = MaskConfig()
    if args.mask_ratio is not None:
        mask = replace(mask, ratio_start=args.mask_ratio[0], ratio_end=args.mask_ratio[1])
    if args.mask_block is not None:
        bh, bw = (int(v) for v in args.mask_block.lower().split("x"))
        mask = replace(mask, block_h=bh, block_w=bw)
    augment = replace(
        AugmentConfig(),
        **_given(min_width=args.crop_widths and args.crop_widths[0]),
        **_given(max_width=args.crop_widths and args.crop_widths[1]),
        teacher_clean=args.teacher_clean,
        **_given(blur_prob=args.blur_prob),
        **_given(blur_sigma=args.blur_sigma and tuple(args.blur_sigma)),
    )
    return TrainConfig(
        encoder=SMALL_ENCODER if small else EncoderConfig(),
        dino=dino,
        mask=mask,
        augment=augment,
        seed=args.seed,
        **_given(
            batch=args.batch or (4 if small else None),
            lr=args.lr,
            min_lr=args.min_lr,
            lr_decay_pairs=args.lr_decay_pairs,
            precision=args.precision,
        ),
    )


def schedule_length(args: argparse.Namespace, device: torch.device) -> int:
    if args.schedule_pairs is not None:
        return int(args.schedule_pairs)
    if args.pairs is not None:
        return int(args.pairs)
    return round(60.0 * args.minutes * ASSUMED_PAIRS_PER_S[device.type])


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--out", type=Path, required=True, help="run folder (runs/NAME)")
    p.add_argument("--resume", action="store_true", help="continue from OUT/last.pt")
    p.add_argument("--minutes", type=float, help="wall-clock budget of this invocation")
    p.add_argument("--pairs", type=int, help="cumulative training pairs to reach")
    p.add_argument("--schedule-pairs", type=int, help="schedule length in pairs (fresh runs)")
    p.add_argument(
        "--anneal-pairs",
        type=int,
        help="with --resume: run what remains of every schedule over the next N pairs (a fork "
        "that anneals a long run early; copy the run folder first)",
    )
    p.add_argument(
        "--fork-mask-ratio",
        type=float,
        nargs=2,
        metavar=("START", "END"),
        help="with --resume: replace the mask ratio's schedule (linear from START at step 0 to "
        "END at the schedule's end, so it jumps where the run stands; a fork: copy the run "
        "folder first)",
    )
    p.add_argument("--config", choices=("small", "paper"), default="paper")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--batch", type=int)
    p.add_argument("--lr", type=float)
    p.add_argument("--min-lr", type=float, help="the LR's floor (default 1e-6)")
    p.add_argument(
        "--lr-decay-pairs",
        type=int,
        help="the LR's warm-up and cosine end after N pairs, then it stays at --min-lr (fresh "
        "runs; default: the cosine spans the schedule)",
    )
    p.add_argument("--prototypes", type=int, help="K")
    p.add_argument("--mask-ratio", type=float, nargs=2, metavar=("START", "END"))
    p.add_argument("--mask-block", help="mask block in cells, e.g. 2x3")
    p.add_argument("--masked-weight", type=float, help="loss weight of masked tokens")
    p.add_argument("--unmasked-weight", type=float, help="loss weight of other tokens")
    p.add_argument("--teacher-temp", type=float, nargs=2, metavar=("START", "END"))
    p.add_argument(
        "--teacher-temp-warmup",
        type=float,
        help="fraction of the schedule over which the teacher temperature rises (default 0.3)",
    )
    p.add_argument("--momentum", type=float, help="EMA momentum at step 0")
    p.add_argument(
        "--precision",
        choices=("auto", "bf16", "fp32"),
        help="default auto; with --resume/--init-from it overrides the run's setting",
    )
    p.add_argument("--bf16", action="store_true", help="same as --precision bf16")
    p.add_argument(
        "--batch-multiplier",
        type=int,
        default=1,
        help="pairs per step = M x the run's batch; schedules stay in pairs (a GPU leg)",
    )
    p.add_argument("--lr-scale", type=float, help="LR factor (default sqrt(batch multiplier))")
    p.add_argument(
        "--data-workers",
        type=int,
        default=0,
        help="cut crops in N processes (a GPU leg; not an exact resume; 0: in-process)",
    )
    p.add_argument("--chunk-tokens", type=int, help="loss chunk size (run-time; GPU: large)")
    p.add_argument(
        "--weights-out", type=Path, help="write fp16 teacher/student + log here at checkpoints"
    )
    p.add_argument(
        "--init-from",
        type=Path,
        help="start OUT from a --weights-out folder (config, weights, pair count; fresh optimiser)",
    )
    p.add_argument(
        "--crop-widths",
        type=int,
        nargs=2,
        metavar=("MIN", "MAX"),
        help="range of image widths the 48x160 crops are cut from (crop scale)",
    )
    p.add_argument("--eval-student", action="store_true", help="evaluate the student too")
    p.add_argument("--head-bn", action="store_true", help="BatchNorm in the projection head")
    p.add_argument(
        "--teacher-clean",
        action="store_true",
        help="teacher sees the pair before photometric/noise/occlusion nuisances",
    )
    p.add_argument(
        "--blur-prob", type=float, help="chance of a gaussian blur of one view (default 0)"
    )
    p.add_argument(
        "--blur-sigma",
        type=float,
        nargs=2,
        metavar=("MIN", "MAX"),
        help="range of that blur's standard deviation in crop pixels (default 0.5 1.5)",
    )
    p.add_argument("--data", type=Path, default=None, help="folder with PAIRS.tsv")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"), default="auto")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    p.add_argument("--checkpoint-minutes", type=float, default=10.0)
    p.add_argument("--eval-minutes", type=float, default=10.0, help="0: no periodic evaluation")
    p.add_argument("--no-eval", action="store_true", help="no evaluation at all")
    p.add_argument("--no-probe", action="store_true", help="never read the eval split")
    p.add_argument("--bench-pairs", type=int, default=32, help="controlled benchmark pairs")
    p.add_argument("--log-every", type=int, default=5)
    p.add_argument(
        "--smoke", action="store_true", help="tiny CPU-seconds run; checks the loss falls"
    )
    args = p.parse_args(argv)
    if args.bf16:
        if args.precision not in (None, "bf16"):
            p.error("--bf16 contradicts --precision " + args.precision)
        args.precision = "bf16"
    if args.resume and args.init_from is not None:
        p.error("--resume and --init-from exclude each other")
    if args.anneal_pairs is not None and (not args.resume or args.anneal_pairs <= 0):
        p.error("--anneal-pairs needs --resume and a positive pair count")
    if args.fork_mask_ratio is not None and (
        not args.resume or not all(0.0 <= r < 1.0 for r in args.fork_mask_ratio)
    ):
        p.error("--fork-mask-ratio needs --resume and ratios in [0, 1)")
    if args.smoke:
        args.config, args.pairs, args.no_eval, args.log_every = "small", 80, True, 5
        args.schedule_pairs = args.schedule_pairs or 400
    if args.pairs is None and args.minutes is None:
        p.error("give --pairs and/or --minutes")
    return args


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    device = pick_device(args.device)
    ckpt = args.out / "last.pt"
    scaling: dict[str, Any] = {
        "batch_multiplier": args.batch_multiplier,
        "lr_scale": args.lr_scale,
        "chunk_tokens": args.chunk_tokens,
        "data_workers": args.data_workers,
    }
    if args.resume:
        state = torch.load(ckpt, map_location="cpu", weights_only=False)  # RNG states stay on CPU
        cfg = with_precision(TrainConfig.from_dict(state["train_config"]), args.precision)
        trainer = Trainer(cfg, args.data, device, **scaling)
        trainer.load_state_dict(state)
        print(f"resumed {ckpt} at step {trainer.step} ({trainer.pairs_seen} pairs)")
        if args.anneal_pairs is not None:
            record = start_anneal(trainer, args.anneal_pairs)
            with (args.out / "log.jsonl").open("a") as f:
                f.write(json.dumps(record) + "\n")
        if args.fork_mask_ratio is not None:
            record = fork_mask_ratio(trainer, args.fork_mask_ratio[0], args.fork_mask_ratio[1])
            with (args.out / "log.jsonl").open("a") as f:
                f.write(json.dumps(record) + "\n")
    else:
        if ckpt.exists() and not args.smoke:
            sys.exit(f"error: {ckpt} exists; pass --resume or choose another --out")
        if args.smoke and (args.out / "log.jsonl").exists():
            (args.out / "log.jsonl").unlink()
        if args.init_from is not None:
            trainer = initialised_trainer(args, device, scaling)
        else:
            cfg = replace(build_config(args), schedule_pairs=schedule_length(args, device))
            trainer = Trainer(cfg, args.data, device, **scaling)
    print(
        f"device {device}, bf16 {trainer.bf16}, {trainer.batch_size} pairs/step, "
        f"lr x{trainer.lr_scale:.3g}",
        flush=True,
    )
    opts = RunOptions(
        out=args.out,
        data_dir=args.data,
        target_pairs=args.pairs,
        minutes=args.minutes,
        checkpoint_minutes=args.checkpoint_minutes,
        eval_minutes=0.0 if args.no_eval else args.eval_minutes,
        eval_at_end=not args.no_eval,
        probe=not args.no_probe,
        bench_pairs=args.bench_pairs,
        log_every=args.log_every,
        eval_student=args.eval_student,
        weights_out=args.weights_out,
    )
    records = run(trainer, opts)
    print(f"done: step {trainer.step}, {trainer.pairs_seen} pairs, checkpoint {ckpt}")
    if args.smoke:
        sys.exit(0 if smoke_report(records) else 1)


def start_anneal(trainer: Trainer, pairs: int) -> dict[str, Any]:
    """Compress the rest of the run's schedules into the next `pairs` pairs (once per run);
    returns the log record."""
    cfg = trainer.cfg
    if cfg.anneal_pairs > 0:
        sys.exit(f"error: this run already anneals from {cfg.anneal_from_pairs} pairs")
    if trainer.pairs_seen >= cfg.schedule_pairs:
        sys.exit(f"error: the schedule ended at {cfg.schedule_pairs} pairs; nothing to anneal")
    trainer.cfg = replace(cfg, anneal_from_pairs=trainer.pairs_seen, anneal_pairs=pairs)
    end = trainer.pairs_seen + pairs
    rest = cfg.schedule_pairs - trainer.pairs_seen
    print(f"annealing: the schedules' remaining {rest} pairs run over {pairs} (to {end} pairs)")
    return {"kind": "anneal", "step": trainer.step, "pairs": trainer.pairs_seen, "until": end}


def fork_mask_ratio(trainer: Trainer, start: float, end: float) -> dict[str, Any]:
    """Replace the mask ratio's schedule of a resumed run (a fork asking whether the share of
    masked cells, not the learning rate, drives a long run's probe); returns the log record."""
    cfg = trainer.cfg
    before = mask_ratio(trainer.schedule_step, cfg.total_steps, cfg.mask)
    trainer.cfg = replace(cfg, mask=replace(cfg.mask, ratio_start=start, ratio_end=end))
    after = mask_ratio(trainer.schedule_step, cfg.total_steps, trainer.cfg.mask)
    print(f"fork: mask ratio {before:.3f} -> {after:.3f} (schedule {start} -> {end})")
    return {
        "kind": "fork_mask_ratio",
        "step": trainer.step,
        "pairs": trainer.pairs_seen,
        "mask_ratio": [start, end],
        "ratio_before": before,
        "ratio_after": after,
    }


def pick_device(name: str) -> torch.device:
    """auto: CUDA where torch sees a GPU, else the CPU; cuda without a GPU is an error."""
    if name == "cuda" and not torch.cuda.is_available():
        sys.exit("error: --device cuda, but torch sees no CUDA GPU")
    if name == "cuda" or (name == "auto" and torch.cuda.is_available()):
        # TF32 stays off (PyTorch's default for matmuls): the head's cosine logits, kept out of
        # bf16 on purpose, are divided by temperatures of ~0.05.
        return torch.device("cuda")
    return torch.device("cpu")


def with_precision(cfg: TrainConfig, precision: str | None) -> TrainConfig:
    return cfg if precision is None else replace(cfg, precision=precision)


def initialised_trainer(
    args: argparse.Namespace, device: torch.device, scaling: dict[str, Any]
) -> Trainer:
    """--init-from: the snapshot's configuration and weights, its log continued in OUT."""
    states = load_weights(args.init_from)
    cfg = TrainConfig.from_dict(states["teacher"]["train_config"])
    trainer = Trainer(with_precision(cfg, args.precision), args.data, device, **scaling)
    init_from(trainer, states)
    log_path = start_log(args.init_from, args.out, trainer.pairs_seen)
    record = {
        "kind": "init",
        "from": str(args.init_from),
        "step": trainer.step,
        "pairs": trainer.pairs_seen,
        "exact": False,
    }
    with log_path.open("a") as f:
        f.write(json.dumps(record) + "\n")
    print(f"initialised from {args.init_from} at step {trainer.step} ({trainer.pairs_seen} pairs)")
    return trainer


def smoke_report(records: list[dict[str, Any]]) -> bool:
    """Did the loss fall? Judged on KL(teacher || student): the cross-entropy also holds the
    teacher's entropy, which rises early on as centring spreads the teacher, so the raw loss
    of a short run can rise while the student is in fact catching up."""
    n = max(1, len(records) // 4)

    def trend(key: str) -> tuple[float, float]:
        values = [float(r[key]) for r in records]
        return sum(values[:n]) / n, sum(values[-n:]) / n

    (l0, l1), (k0, k1) = trend("loss"), trend("kl")
    finite = all(math.isfinite(float(r["loss"])) for r in records)
    ok = finite and k1 < k0
    print(f"smoke: cross-entropy {l0:.4f} -> {l1:.4f}, KL(teacher||student) {k0:.4f} -> {k1:.4f}")
    print(f"smoke: loss {'decreased' if ok else 'did NOT decrease'} (judged on the KL)")
    return ok


if __name__ == "__main__":
    main()
