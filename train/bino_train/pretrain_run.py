"""The pretraining loop: train a `Trainer` until a stop condition, writing the run folder.

`run` logs to `log.jsonl`, checkpoints `last.pt` atomically (`save_atomic`), evaluates the
teacher (no-linkage probe and controlled benchmark, `Evaluator`) into `teacher_<pairs>.pt`
snapshots and stops cleanly on Ctrl-C or SIGTERM (`StopFlag`); see pretrain.py.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from types import FrameType
from typing import Any

import torch

from .benchmark import BenchPair, make_benchmark, run_all
from .model import BinoEncoder
from .pretrain_trainer import Trainer
from .pretrain_weights import save_weights
from .probe import ProbeItem, encoder_describe, load_probe_set, run_probe


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
