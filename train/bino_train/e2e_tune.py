"""The encoder's last blocks fine-tuned end to end with the native head on labeled data.

Issue 54 asks whether the learned path gains when the encoder itself, not only the head, learns
from ground truth. This run starts from a shipped encoder (`--encoder`, a `{config, encoder}`
file such as weights/bino_encoder.pt: row attention and the shared row embedding already in its
config and weights) and a native head (`--head`), freezes every encoder block but the last
`--blocks`, and trains those blocks and the head together on the native pathway: one pass on
(L, R), the phase maps into the head, the head's loss (smooth L1 + cross-entropy, head.py) on
fresh crops of `head_data.HeadSampler`: the labeled train pairs outside
`labeled.LABELED_HOLDOUT` with their ground truth, layered synthetic scenes and SGBM
pseudo-labels, the mix the shipped native head's ground-truth run used (hgt40nat_p7).

It checkpoints every `--checkpoint-minutes` and `--resume` continues exactly. At the end it
writes `encoder.pt` ({config, encoder}, for `export --checkpoint`) and `head.pt`
({head_config, head}, for `head --checkpoint`); the int8 readouts are then scored by the Rust
engine (`bino quantize`, `bino eval`), never by this module.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from .head import StereoHead, head_loss, load_head, with_candidates
from .head_data import HEAD_AUGMENT, DataConfig, HeadSampler
from .head_descriptors import gray_batch
from .model import BinoEncoder
from .pretrain_run import save_atomic
from .pretrain_trainer import rng_states, set_rng_states


@dataclass(frozen=True)
class TuneConfig:
    encoder: str
    head: str
    blocks: int = 2
    """Encoder blocks trained (the last ones); the rest and the embeddings stay frozen. 0: the
    head alone on the same data stream (the control)."""
    steps: int = 1500
    batch: int = 8
    lr_head: float = 3e-4
    lr_encoder: float = 1e-4
    min_lr_ratio: float = 0.05
    warmup: float = 0.05
    weight_decay: float = 0.01
    clip_grad: float = 5.0
    seed: int = 0
    max_disp: int = 16
    synthetic_fraction: float = 0.4
    labeled_fraction: float = 0.4
    blur_prob: float = 0.2
    flat_grain_levels: float = 0.0
    """Grain of the synthetic scenes' textureless surfaces (head_data.DataConfig)."""

    def data(self) -> DataConfig:
        return replace(
            DataConfig(),
            max_disp=self.max_disp,
            synthetic_fraction=self.synthetic_fraction,
            labeled_fraction=self.labeled_fraction,
            synthetic_kind="layered",
            label_weighting="lr",
            augment=replace(HEAD_AUGMENT, blur_prob=self.blur_prob),
            flat_grain_levels=self.flat_grain_levels,
        )


def lr_scale(step: int, cfg: TuneConfig) -> float:
    """Linear warm-up to 1, then cosine down to `min_lr_ratio` at `steps`."""
    warm = max(1, round(cfg.warmup * cfg.steps))
    if step < warm:
        return (step + 1) / warm
    progress = min((step - warm) / max(cfg.steps - warm, 1), 1.0)
    return cfg.min_lr_ratio + (1.0 - cfg.min_lr_ratio) * 0.5 * (1.0 + math.cos(math.pi * progress))


def trainable_blocks(encoder: BinoEncoder, blocks: int) -> list[nn.Parameter]:
    """Freeze the encoder but its last `blocks` blocks; return those blocks' parameters."""
    if not 0 <= blocks <= len(encoder.blocks):
        raise ValueError(f"--blocks {blocks} must be in 0..{len(encoder.blocks)}")
    encoder.requires_grad_(False)
    params: list[nn.Parameter] = []
    for block in encoder.blocks[len(encoder.blocks) - blocks :]:
        block.requires_grad_(True)
        params.extend(block.parameters())
    return params


class Tuner:
    """Encoder, head, optimiser and data stream of one run."""

    def __init__(self, cfg: TuneConfig, data_dir: Path) -> None:
        from .export import load_encoder

        self.cfg = cfg
        torch.manual_seed(cfg.seed)
        self.encoder = load_encoder(Path(cfg.encoder))
        self.head: StereoHead = with_candidates(load_head(Path(cfg.head)), cfg.max_disp)
        if self.head.cfg.pathway != "native":
            raise ValueError(f"--head {cfg.head} is not a native-pathway head")
        encoder_params = trainable_blocks(self.encoder, cfg.blocks)
        self.opt = torch.optim.AdamW(
            [
                {"params": encoder_params, "lr": cfg.lr_encoder, "base": cfg.lr_encoder},
                {"params": list(self.head.parameters()), "lr": cfg.lr_head, "base": cfg.lr_head},
            ],
            weight_decay=cfg.weight_decay,
        )
        self.sampler = HeadSampler(cfg.data(), cfg.seed, data_dir)
        self.step = 0
        self.seconds = 0.0

    def train_step(self) -> dict[str, Any]:
        cfg = self.cfg
        t0 = time.perf_counter()
        first = self.step * cfg.batch
        samples = self.sampler.samples(range(first, first + cfg.batch))
        left = gray_batch([s.left for s in samples], torch.device("cpu"))
        right = gray_batch([s.right for s in samples], torch.device("cpu"))
        label = torch.from_numpy(np.stack([s.label for s in samples]))
        weight = torch.from_numpy(np.stack([s.label_weight() for s in samples]))
        scale = lr_scale(self.step, cfg)
        for group in self.opt.param_groups:
            group["lr"] = group["base"] * scale
        self.encoder.train()
        self.head.train()
        even, odd = self.encoder.phase_maps(left, right)
        parts = head_loss(self.head(even, odd), label, 1.0, weight)
        self.opt.zero_grad(set_to_none=True)
        parts.loss.backward()
        params = [p for g in self.opt.param_groups for p in g["params"]]
        grad_norm = float(nn.utils.clip_grad_norm_(params, cfg.clip_grad))
        self.opt.step()
        self.step += 1
        self.seconds += time.perf_counter() - t0
        return {
            "step": self.step,
            "loss": float(parts.loss.detach()),
            "epe_cols": parts.epe_cols,
            "cells": parts.cells,
            "synthetic": float(np.mean([s.synthetic for s in samples])),
            "lr_scale": scale,
            "grad_norm": grad_norm,
        }

    def state_dict(self) -> dict[str, Any]:
        return {
            "tune_config": asdict(self.cfg),
            "encoder": self.encoder.state_dict(),
            "head": self.head.state_dict(),
            "optimizer": self.opt.state_dict(),
            "rng": rng_states(),
            "step": self.step,
            "seconds": self.seconds,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.encoder.load_state_dict(state["encoder"])
        self.head.load_state_dict(state["head"])
        self.opt.load_state_dict(state["optimizer"])
        set_rng_states(state["rng"])
        self.step = int(state["step"])
        self.seconds = float(state["seconds"])

    def write_weights(self, out: Path) -> None:
        """encoder.pt ({config, encoder}) and head.pt ({head_config, head}) of the run as it is."""
        self.encoder.eval()
        self.head.eval()
        save_atomic(
            {"config": self.encoder.cfg.to_dict(), "encoder": self.encoder.state_dict()},
            out / "encoder.pt",
        )
        save_atomic(
            {"head_config": asdict(self.head.cfg), "head": self.head.state_dict()}, out / "head.pt"
        )


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    p.add_argument("--out", type=Path, required=True, help="run folder (checkpoint, log, weights)")
    p.add_argument("--resume", action="store_true", help="continue the run in --out")
    p.add_argument("--encoder", type=Path, help="{config, encoder} file to start from")
    p.add_argument("--head", type=Path, help="native head checkpoint to start from")
    p.add_argument("--data", type=Path, default=Path("../../shared/data"))
    p.add_argument("--blocks", type=int, default=2)
    p.add_argument("--steps", type=int, default=1500)
    p.add_argument("--batch", type=int, default=8)
    p.add_argument("--lr-head", type=float, default=3e-4)
    p.add_argument("--lr-encoder", type=float, default=1e-4)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--flat-grain",
        type=float,
        default=0.0,
        help="grey levels of grain on the synthetic textureless surfaces (0: the shipped heads')",
    )
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--checkpoint-minutes", type=float, default=10.0)
    p.add_argument("--log-every", type=int, default=25)
    return p.parse_args(argv)


def config_from_args(args: argparse.Namespace) -> TuneConfig:
    for flag, path in (("--encoder", args.encoder), ("--head", args.head)):
        if path is None:
            sys.exit(f"error: {flag} is required for a new run")
        if not path.is_file():
            sys.exit(f"error: {flag} {path} does not exist")
    if args.flat_grain < 0.0:
        sys.exit(f"error: --flat-grain {args.flat_grain} is negative")
    if args.steps < 1 or args.batch < 1:
        sys.exit(f"error: --steps {args.steps} and --batch {args.batch} must be at least 1")
    return TuneConfig(
        encoder=str(args.encoder.resolve()),
        head=str(args.head.resolve()),
        blocks=args.blocks,
        steps=args.steps,
        batch=args.batch,
        lr_head=args.lr_head,
        lr_encoder=args.lr_encoder,
        seed=args.seed,
        flat_grain_levels=args.flat_grain,
    )


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    ckpt = args.out / "checkpoint.pt"
    if args.resume:
        if not ckpt.is_file():
            sys.exit(f"error: --resume: no checkpoint at {ckpt}")
        state = torch.load(ckpt, map_location="cpu", weights_only=False)
        cfg = TuneConfig(**state["tune_config"])
    else:
        if ckpt.exists():
            sys.exit(f"error: {ckpt} exists; pass --resume or another --out")
        cfg = config_from_args(args)
        state = None
    if not args.data.is_dir():
        sys.exit(f"error: --data {args.data} is not a folder")
    try:
        tuner = Tuner(cfg, args.data)
    except ValueError as err:
        sys.exit(f"error: {err}")
    if state is not None:
        tuner.load_state_dict(state)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "config.json").write_text(json.dumps(asdict(cfg), indent=2) + "\n")
    last = time.perf_counter()
    with (args.out / "log.jsonl").open("a") as log:
        while tuner.step < cfg.steps:
            record = tuner.train_step()
            if tuner.step % args.log_every == 0 or tuner.step == cfg.steps:
                record["seconds"] = round(tuner.seconds, 1)
                log.write(json.dumps(record) + "\n")
                log.flush()
                print(json.dumps(record), flush=True)
            if time.perf_counter() - last >= 60.0 * args.checkpoint_minutes:
                save_atomic(tuner.state_dict(), ckpt)
                last = time.perf_counter()
    save_atomic(tuner.state_dict(), ckpt)
    tuner.write_weights(args.out)
    print(f"wrote {args.out / 'encoder.pt'} and {args.out / 'head.pt'} after {tuner.step} steps")


if __name__ == "__main__":
    main()
