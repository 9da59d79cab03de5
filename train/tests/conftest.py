"""A tiny stand-in for ../shared/data: noise images in train and eval splits, written per test."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

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
