"""Shared test set-up: a tiny stand-in for ../shared/data (noise images in train and eval
splits, written per test), and the tiny data, caches and trainers of the head tests."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from bino_train.head_cache import DescriptorCache, build_cache, save_cache
from bino_train.head_data import DataConfig
from bino_train.head_train import (
    SMOKE_ENCODER,
    SMOKE_HEAD,
    EncoderSource,
    HeadTrainConfig,
    HeadTrainer,
    encoder_digest,
)
from bino_train.model import BinoEncoder

HEADER = "pair_id split dataset left right gt gt_format gt_scale gt_invalid width height".split()


def _noise(rng: np.random.Generator, h: int, w: int, channels: int = 1) -> np.ndarray:
    shape = (h, w) if channels == 1 else (h, w, channels)
    return rng.integers(0, 256, size=shape, dtype=np.uint8)


def write_dataset(folder: Path, seed: int = 0) -> Path:
    """Three gray and one colour train pair, two eval pairs with ground truth."""
    rng = np.random.default_rng(seed)
    rows = []
    specs = [
        ("t0", "train", "a", 1, 240, 100),
        ("t1", "train", "a", 1, 320, 120),
        ("t2", "train", "b", 1, 200, 96),
        ("t3", "train", "c", 3, 260, 110),
        ("e0", "eval", "mb", 3, 300, 200),
        ("e1", "eval", "mb", 1, 240, 180),
    ]
    for pair_id, split, dataset, channels, w, h in specs:
        sub = folder / split
        sub.mkdir(parents=True, exist_ok=True)
        left, right = sub / f"{pair_id}_l.png", sub / f"{pair_id}_r.png"
        cv2.imwrite(str(left), _noise(rng, h, w, channels))
        cv2.imwrite(str(right), _noise(rng, h, w, channels))
        gt = ""
        if split == "eval":
            gt_path = sub / f"{pair_id}_gt.png"
            cv2.imwrite(str(gt_path), rng.integers(0, 60, size=(h, w), dtype=np.uint8))
            gt = str(gt_path.relative_to(folder))
        rows.append(
            [
                pair_id,
                split,
                dataset,
                str(left.relative_to(folder)),
                str(right.relative_to(folder)),
                gt,
                "png_u8" if gt else "",
                "4" if gt else "",
                "0" if gt else "",
                str(w),
                str(h),
            ]
        )
    lines = ["\t".join(HEADER)] + ["\t".join(r) for r in rows]
    (folder / "PAIRS.tsv").write_text("\n".join(lines) + "\n")
    return folder


@pytest.fixture
def data_dir(tmp_path: Path) -> Path:
    return write_dataset(tmp_path / "data")


# The head tests (test_head*.py, test_native_head.py, test_int8_cache.py) share the set-up below:
# one definition, so their tiny data, caches and trainers cannot drift apart.


@pytest.fixture
def one_torch_thread() -> Iterator[None]:
    """Tiny tensors: extra threads only add barrier waits (minutes on a busy machine). Not
    autouse here: the head test modules opt in with `pytestmark`, other modules keep torch's
    default."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


TINY_DATA = DataConfig(crop_h=32, crop_w=96, min_width=96, max_width=160)
"""Crops small enough that caches and training steps of the head tests take milliseconds."""

TINY_SYNTHETIC_DATA = replace(TINY_DATA, synthetic_fraction=1.0)
"""The same crops, all synthetic: no data folder needed and the samples depend on the seed
alone."""


def save_tiny_cache(
    path: Path,
    encoder: BinoEncoder,
    data: DataConfig,
    seed: int,
    count: int,
    data_dir: Path | None = None,
    pathway: str = "export",
) -> DescriptorCache:
    """Encode `count` crops of `data` into a descriptor cache at `path`, quietly (no progress
    bar); returned for tests that alter its meta."""
    cache = build_cache(
        encoder, encoder_digest(encoder), data, seed, count, data_dir, False, pathway
    )
    save_cache(cache, path)
    return cache


def tiny_cached_config(cache: Path, data: DataConfig) -> HeadTrainConfig:
    """A smoke head trained from the cache at `cache` in small numbers (4-crop batches, a pool of
    8 with 4 new crops a step, a 6-step schedule) so a resume test runs in seconds; tests
    `replace` the rest of their recipe."""
    return HeadTrainConfig(
        head=replace(SMOKE_HEAD, desc_dim=SMOKE_ENCODER.dim),
        data=data,
        batch=4,
        refresh=4,
        pool=8,
        schedule_steps=6,
        cache=str(cache),
    )


def cpu_trainer(
    cfg: HeadTrainConfig, encoder: BinoEncoder, data_dir: Path | None = None
) -> HeadTrainer:
    """A trainer on `random_encoder(0, SMOKE_ENCODER)`, on the CPU (resume tests compare runs
    bit for bit). The source carries the encoder's digest, which a cached run checks against
    its cache's."""
    source = EncoderSource(
        "random-init", seed=0, config=SMOKE_ENCODER.to_dict(), sha256=encoder_digest(encoder)
    )
    return HeadTrainer(cfg, encoder, source, data_dir, torch.device("cpu"))
