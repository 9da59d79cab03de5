"""Weights-only snapshots of a pretraining run, and a run started from one.

A GPU lease brings back little (a few files of at most 16 MiB), so a leg trained there ends
with `--weights-out DIR`: `teacher.pt` and `student.pt` (fp16 encoder and DINO head state
dicts, plus the run's configuration, step, pair count and, for the teacher, the loss centre)
and the run's `log.jsonl`. `teacher.pt` also loads where a checkpoint does
(`export.load_encoder`: `config` + `encoder`).

`--init-from DIR` starts a new run folder from such a snapshot: the configuration, weights
and pair count come from it (the schedules continue at that pair count), the optimiser
starts fresh, and the crop and mask streams are re-seeded from the pair count. Unlike
`--resume` this is not exact (no AdamW moments, fp16-rounded weights, other crops); from the
first checkpoint of the new folder on, `--resume` is exact again.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
from torch import Tensor

if TYPE_CHECKING:
    from .pretrain import Trainer

WEIGHTS_FORMAT = "bino-pretrain-weights/1"
MAX_FILE_BYTES = 16 * 1024 * 1024
ROLES = ("teacher", "student")
LOG_NAME = "log.jsonl"


def half(state: dict[str, Tensor]) -> dict[str, Tensor]:
    """Floating-point tensors to fp16 on the CPU; integer buffers (BatchNorm counts) as is."""
    return {
        k: (v.detach().to("cpu", torch.float16) if v.is_floating_point() else v.detach().cpu())
        for k, v in state.items()
    }


def snapshot(trainer: Trainer, role: str) -> dict[str, Any]:
    encoder = trainer.teacher if role == "teacher" else trainer.student
    head = trainer.teacher_head if role == "teacher" else trainer.student_head
    out: dict[str, Any] = {
        "format": WEIGHTS_FORMAT,
        "role": role,
        "config": trainer.cfg.encoder.to_dict(),
        "encoder": half(encoder.state_dict()),
        "head": half(head.state_dict()),
        **trainer.run_fields(),
    }
    if role == "teacher":
        out["center"] = trainer.loss.center.detach().cpu().float()
    return out


def save_weights(trainer: Trainer, folder: Path, log_path: Path) -> dict[str, int]:
    """Write teacher.pt, student.pt and a copy of the log; returns the file sizes."""
    folder.mkdir(parents=True, exist_ok=True)
    sizes: dict[str, int] = {}
    for role in ROLES:
        path = folder / f"{role}.pt"
        tmp = path.with_suffix(".pt.tmp")
        torch.save(snapshot(trainer, role), tmp)
        tmp.replace(path)
        sizes[path.name] = path.stat().st_size
        if sizes[path.name] >= MAX_FILE_BYTES:
            raise ValueError(f"{path} is {sizes[path.name]} bytes, not under 16 MiB")
    if log_path.exists():
        shutil.copyfile(log_path, folder / LOG_NAME)
        sizes[LOG_NAME] = (folder / LOG_NAME).stat().st_size
    return sizes


def load_weights(folder: Path) -> dict[str, dict[str, Any]]:
    """{"teacher": ..., "student": ...}, checked to be one snapshot of one run."""
    states = {r: torch.load(folder / f"{r}.pt", map_location="cpu") for r in ROLES}
    for role, state in states.items():
        if state.get("format") != WEIGHTS_FORMAT or state.get("role") != role:
            raise ValueError(f"{folder / role}.pt is not a {WEIGHTS_FORMAT} {role} file")
    t, s = states["teacher"], states["student"]
    if (t["pairs_seen"], t["step"]) != (s["pairs_seen"], s["step"]):
        raise ValueError(f"{folder}: teacher and student come from different steps")
    return states


def logged_pairs(log_path: Path) -> int | None:
    """Pair count of the log's last `weights` record (written with each snapshot)."""
    pairs = None
    for line in log_path.read_text().splitlines():
        record = json.loads(line)
        if record.get("kind") == "weights":
            pairs = int(record["pairs"])
    return pairs


def stream_seed(seed: int, pairs: int, stream: int) -> int:
    return int(np.random.SeedSequence([seed, pairs, stream]).generate_state(1, np.uint64)[0])


def init_from(trainer: Trainer, states: dict[str, dict[str, Any]]) -> None:
    """Load a snapshot's weights and counters into a freshly built trainer; re-seed streams."""
    t, s = states["teacher"], states["student"]
    trainer.teacher.load_state_dict(t["encoder"])
    trainer.teacher_head.load_state_dict(t["head"])
    trainer.student.load_state_dict(s["encoder"])
    trainer.student_head.load_state_dict(s["head"])
    trainer.loss.center.copy_(t["center"])
    trainer.step = int(t["step"])
    trainer.pairs_seen = int(t["pairs_seen"])
    trainer.train_seconds = float(t["train_seconds"])
    seed = trainer.cfg.seed
    trainer.sampler.reseed(stream_seed(seed, trainer.pairs_seen, 0))
    trainer.masker.gen.manual_seed(stream_seed(seed, trainer.pairs_seen, 1))


def start_log(folder: Path, out: Path, pairs: int) -> Path:
    """Copy the snapshot's log into the new run folder (one continuous log); check its count."""
    source = folder / LOG_NAME
    if not source.exists():
        raise FileNotFoundError(f"no {LOG_NAME} in {folder}")
    logged = logged_pairs(source)
    if logged != pairs:
        raise ValueError(f"{source} ends at {logged} pairs, the weights at {pairs}")
    out.mkdir(parents=True, exist_ok=True)
    target = out / LOG_NAME
    shutil.copyfile(source, target)
    return target
