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
import json
import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch

from .augment import AugmentConfig
from .config import EncoderConfig
from .dino import DinoConfig
from .masking import MaskConfig, mask_ratio
from .pretrain_run import RunOptions, run
from .pretrain_run import StopFlag as StopFlag
from .pretrain_run import save_atomic as save_atomic
from .pretrain_trainer import TrainConfig as TrainConfig
from .pretrain_trainer import Trainer as Trainer
from .pretrain_trainer import learning_rate as learning_rate
from .pretrain_trainer import param_groups as param_groups
from .pretrain_trainer import rng_states as rng_states
from .pretrain_trainer import schedule_position as schedule_position
from .pretrain_trainer import set_rng_states as set_rng_states
from .pretrain_weights import init_from, load_weights, start_log

ASSUMED_PAIRS_PER_S = {"cpu": 6.9, "cuda": 150.0}
"""Only used to turn --minutes into a schedule length when none is given."""

SMALL_ENCODER = EncoderConfig(dim=32, depth=2, heads=2, mlp_hidden=64)
SMALL_DINO = DinoConfig(prototypes=64, hidden=64, bottleneck=32)


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
