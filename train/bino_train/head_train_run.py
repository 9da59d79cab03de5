"""The head training loop: train a `HeadTrainer` until a stop condition, writing the run folder.

`run` logs to `log.jsonl`, validates every `val_every` steps (head_val.py), checkpoints
`last.pt` atomically, stops cleanly on Ctrl-C or SIGTERM and, with evaluation, ends with an
`eval` record (head_eval.py); see head_train.py.
"""

from __future__ import annotations

import json
import signal
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from .head_trainer import HeadTrainer
from .pretrain_run import StopFlag, save_atomic


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
