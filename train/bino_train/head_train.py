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
import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch

from .config import EncoderConfig
from .head import NATIVE_HEADS, HeadConfig
from .head_cache import cache_pathway, load_cache_meta
from .head_data import DataConfig
from .head_descriptors import PATHWAYS
from .head_train_run import RunOptions, run
from .head_trainer import EncoderSource as EncoderSource
from .head_trainer import HeadTrainConfig as HeadTrainConfig
from .head_trainer import HeadTrainer as HeadTrainer
from .head_trainer import build_encoder as build_encoder
from .head_trainer import check_cache_pathway
from .head_trainer import cosine_lr as cosine_lr
from .head_trainer import encoder_digest as encoder_digest
from .head_trainer import initial_head as initial_head
from .model import parameter_count

ASSUMED_STEPS_PER_S = {"cpu": 0.5, "cuda": 10.0}
"""Only used to turn --minutes into a schedule length when neither --steps nor
--schedule-steps is given (CPU: measured on 1 busy core; CUDA: a rough guess)."""

SMOKE_ENCODER = EncoderConfig(dim=32, depth=2, heads=2, mlp_hidden=64)
SMOKE_HEAD = HeadConfig(proj_dim=16, groups=4, hidden=8, middle_layers=1)


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
