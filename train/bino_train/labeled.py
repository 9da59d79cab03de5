"""Labeled train pairs: dense real ground truth for head training (issue 40).

The 11 MiddEval3-Q train pairs and Middlebury 2006 Monopoly carry ground truth (DATA.md
"Labeled training pairs"); they stay in the train split. `LABELED_HOLDOUT` names the ones no head
is trained on: they are scored (labeled_folder.py) to choose recipes, never the eval split. The
choice mixes a textureless scene (Recycle) with textured and cluttered ones (Playroom, Shelves,
Vintage) and a glossy one no head has seen (Monopoly), and keeps each scene and its other-lighting
twin (Piano / PianoL, Playtable / PlaytableP) on the same side: both twins train.

A labeled crop is cut like a pseudo-labelled one (head_data.PseudoLabelSource): both views
area-resized to a width in [min_width, max_width] (a multiple of width_step), a random
crop_h x crop_w window; its ground truth is the stored map resized like EVAL.md's profiles
(nearest neighbour at pixel centres, `INTER_NEAREST_EXACT`, disparity times width / W) and turned
into token-grid labels by `head_data.cell_labels`. Bad input is a one-line ValueError naming the
pair: a ground truth whose size is not its left image's, a colour PFM (pairs.load_gt).
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np
from numpy.typing import NDArray

from .augment import ImageStore, nuisances, width_range
from .pairs import Pair, load_gt, training_pairs

if TYPE_CHECKING:
    from .head_data import DataConfig, Sample

LABELED_HOLDOUT = (
    "middv3Q_Playroom",
    "middv3Q_Recycle",
    "middv3Q_Shelves",
    "middv3Q_Vintage",
    "mb2006_Monopoly",
)
"""Labeled train pairs held out of head training (validation of recipes, issues 40 and 54).
Middlebury 2006 Monopoly came to the data after every shipped head was trained, so no head saw
it: a glossy, weakly textured scene unlike the MiddEval3-Q ones."""

Disparity = NDArray[np.float32]
Mask = NDArray[np.bool_]


def labeled_pairs(data_dir: Path | None = None) -> list[Pair]:
    """Train-split pairs that carry ground truth (never the eval split), in file order."""
    return [p for p in training_pairs(data_dir) if p.gt is not None]


def heldout_labeled_pairs(data_dir: Path | None = None) -> list[Pair]:
    """The labeled train pairs of `LABELED_HOLDOUT` that the folder holds."""
    return [p for p in labeled_pairs(data_dir) if p.pair_id in LABELED_HOLDOUT]


def load_checked_gt(pair: Pair, image_shape: tuple[int, int]) -> tuple[Disparity, Mask]:
    """`pairs.load_gt`, refusing a map whose size is not the left image's `(H, W)`."""
    disparity, valid = load_gt(pair)
    if disparity.shape != image_shape:
        gh, gw = disparity.shape
        ih, iw = image_shape
        raise ValueError(
            f"pair {pair.pair_id}: ground truth {pair.gt} is {gw}x{gh}, "
            f"its left image {pair.left} is {iw}x{ih}"
        )
    return disparity, valid


def resize_labels(disparity: Disparity, valid: Mask, width: int) -> tuple[Disparity, Mask]:
    """Ground truth at `width` px (height round(H * width / W), half up, as ImageStore.resized):
    nearest neighbour at pixel centres, disparity times width / W."""
    h, w = disparity.shape
    if width == w:
        return disparity, valid
    height = int(math.floor(h * width / w + 0.5))
    size = (width, height)
    disp = cv2.resize(disparity, size, interpolation=cv2.INTER_NEAREST_EXACT)
    mask = cv2.resize(valid.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST_EXACT)
    scaled = np.asarray(disp, dtype=np.float32) * np.float32(width / w)
    return np.ascontiguousarray(scaled), np.ascontiguousarray(np.asarray(mask).astype(bool))


class LabeledSource:
    """Crops of labeled train pairs with their dense ground truth as token-grid labels.

    Every pair's ground truth is read and checked against its left image when the source is
    made, so bad input fails before any training starts.
    """

    def __init__(self, pairs: list[Pair], cfg: DataConfig) -> None:
        if not pairs:
            raise ValueError("no labeled train pairs to train on")
        self.cfg = cfg
        self.store = ImageStore(pairs, cfg.augment.cache_mb)  # raises on non-train pairs
        self.crop = replace(
            cfg.augment,
            crop_h=cfg.crop_h,
            crop_w=cfg.crop_w,
            min_width=cfg.min_width,
            max_width=cfg.max_width,
            width_step=cfg.width_step,
        )
        self.gt: list[tuple[Disparity, Mask]] = []
        for index, pair in enumerate(pairs):
            if pair.gt is None:
                raise ValueError(f"pair {pair.pair_id} has no ground truth")
            shape = self.store.original(index, 0).shape
            self.gt.append(load_checked_gt(pair, (int(shape[0]), int(shape[1]))))
        self._resized: dict[tuple[int, int], tuple[Disparity, Mask]] = {}

    def labels(self, index: int, width: int) -> tuple[Disparity, Mask]:
        key = (index, width)
        hit = self._resized.get(key)
        if hit is None:
            hit = resize_labels(*self.gt[index], width)
            self._resized[key] = hit
        return hit

    def sample(self, rng: np.random.Generator) -> Sample:
        from .head_data import Sample, cell_labels

        cfg = self.cfg
        index = int(rng.integers(len(self.store.pairs)))
        lo, hi = width_range(self.store.pairs[index], self.crop)
        width = math.exp(rng.uniform(math.log(lo), math.log(hi))) if hi > lo else float(lo)
        step = cfg.width_step
        width_q = int(min(hi, max(lo, round(width / step) * step)))
        views = [self.store.resized(index, v, width_q) for v in (0, 1)]
        disparity, valid = self.labels(index, width_q)
        h, w = views[0].shape
        if disparity.shape != (h, w):  # the two resizes agree by construction
            raise AssertionError(f"labels {disparity.shape} vs views {(h, w)}")
        y = int(rng.integers(0, h - cfg.crop_h + 1))
        x = int(rng.integers(0, w - cfg.crop_w + 1))
        window = (slice(y, y + cfg.crop_h), slice(x, x + cfg.crop_w))
        left, right = (v[window].astype(np.float32) / np.float32(255.0) for v in views)
        label = cell_labels(disparity[window], valid[window], cfg.min_valid, cfg.max_spread)
        clean = (left, right)
        left, right = nuisances(left, right, rng, cfg.augment)
        return Sample(left, right, label, synthetic=False, clean=clean)
