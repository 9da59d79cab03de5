"""The controlled dual-view benchmark (paper section 4.1) on train-split images.

    python -m bino_train.benchmark --checkpoint runs/NAME/last.pt
    python -m bino_train.benchmark --random-init-seed 0
    python -m bino_train.benchmark --baseline window12

A pair is a 48 x 160 crop (random scale) and a copy of it shifted left by d = 4k pixels,
k = 0 .. max_shift_cols, with reflect padding on the right: left(x) = right(x - d), and the
truth is an integer number of patch columns. EASY: clean. HARD: independent photometric
change and noise in each view plus an occluding rectangle in one view. Each left token is
matched to its nearest neighbour (cosine) among the right tokens of the same row; PCK@0/1/2
is the share of left tokens whose matched column offset is within 0/1/2 of k, EPE the mean
absolute error in tokens. Left tokens whose match lies outside the right view are not scored.
Everything is drawn from one seed, so the benchmark is the same set on every call.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from numpy.typing import NDArray
from torch import Tensor

from .augment import CLEAN, AugmentConfig, ImageStore, dataset_weights, nuisances, sample_window
from .pairs import training_pairs
from .probe import CELL, Describe, describe_from_args

Gray = NDArray[np.float32]

HARD = AugmentConfig(flip_prob=0.0, photometric_prob=1.0, noise_prob=1.0, occlusion_prob=1.0)
SETTINGS = {"easy": CLEAN, "hard": HARD}


@dataclass(frozen=True)
class BenchPair:
    left: Gray
    right: Gray
    shift_cols: int


def shifted_views(crop: Gray, shift_px: int) -> tuple[Gray, Gray]:
    """(left, right) with right(u) = left(u + d): the right view is reflect-padded."""
    padded = np.pad(crop, ((0, 0), (0, shift_px)), mode="reflect")
    right = np.ascontiguousarray(padded[:, shift_px : shift_px + crop.shape[1]])
    return crop.copy(), right


def make_benchmark(
    data_dir: Path | None, pairs: int, seed: int, max_shift_cols: int = 9
) -> dict[str, list[BenchPair]]:
    """EASY and HARD sets sharing crops and shifts; deterministic given `seed`."""
    train = training_pairs(data_dir)
    store = ImageStore(train, cache_mb=64)
    weights = dataset_weights(train, balance=True)
    geometry = np.random.default_rng(seed)
    nuisance = np.random.default_rng(seed + 1)
    sets: dict[str, list[BenchPair]] = {name: [] for name in SETTINGS}
    for _ in range(pairs):
        crop, _unused = sample_window(store, geometry, CLEAN, weights)
        k = int(geometry.integers(0, max_shift_cols + 1))
        left, right = shifted_views(crop, CELL * k)
        sets["easy"].append(BenchPair(left, right, k))
        hard_left, hard_right = nuisances(left, right, nuisance, HARD)
        sets["hard"].append(BenchPair(hard_left, hard_right, k))
    return sets


def match_offsets(dl: Tensor, dr: Tensor) -> Tensor:
    """(T, P) column offset p - p* of each left token's row-wise nearest right token."""
    sims = torch.einsum(
        "rpd,rqd->rpq", F.normalize(dl.float(), dim=-1), F.normalize(dr.float(), dim=-1)
    )
    cols = torch.arange(dl.shape[1])
    return cols.view(1, -1) - sims.argmax(dim=-1)


def offset_metrics(errors: Tensor) -> dict[str, float]:
    err = errors.abs().float()
    return {
        "pck0": float(100.0 * (err <= 0).float().mean()),
        "pck1": float(100.0 * (err <= 1).float().mean()),
        "pck2": float(100.0 * (err <= 2).float().mean()),
        "epe_tok": float(err.mean()),
    }


def run_benchmark(describe: Describe, items: Sequence[BenchPair]) -> dict[str, float]:
    """PCK@0/1/2 (%) and EPE (tokens) over all scored left tokens of `items`."""
    descs = describe([*(p.left for p in items), *(p.right for p in items)])
    errors = []
    for i, pair in enumerate(items):
        offsets = match_offsets(descs[i], descs[len(items) + i])
        scored = offsets[:, pair.shift_cols :]  # left tokens whose match is inside the right view
        errors.append((scored - pair.shift_cols).reshape(-1))
    return offset_metrics(torch.cat(errors))


def run_all(describe: Describe, sets: dict[str, list[BenchPair]]) -> dict[str, float]:
    """Flat dict: easy_pck0, ..., hard_epe_tok."""
    out = {}
    for name, items in sets.items():
        for key, value in run_benchmark(describe, items).items():
            out[f"{name}_{key}"] = value
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--checkpoint", type=Path, help="checkpoint with config + encoder keys")
    source.add_argument("--random-init-seed", type=int, help="encoder at a seeded random init")
    source.add_argument("--baseline", help="windowN: zero-mean normalised N x N pixel window")
    parser.add_argument("--data", type=Path, default=None, help="folder with PAIRS.tsv")
    parser.add_argument("--pairs", type=int, default=32, help="pairs per setting")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-shift-cols", type=int, default=9)
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    args = parser.parse_args(argv)
    if args.threads > 0:
        torch.set_num_threads(args.threads)

    start = time.perf_counter()
    describe, method = describe_from_args(args.baseline, args.checkpoint, args.random_init_seed)
    sets = make_benchmark(args.data, args.pairs, args.seed, args.max_shift_cols)
    result: dict[str, object] = {"method": method, "pairs": args.pairs, "seed": args.seed}
    result.update(run_all(describe, sets))
    result["seconds"] = round(time.perf_counter() - start, 2)
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
