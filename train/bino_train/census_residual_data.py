"""Training data of the census residual net (census_residual.py): banks of whole views with
their census maps and dense ground truth, and random crops of them.

Real items: the labeled train pairs outside `labeled.LABELED_HOLDOUT` (`train_pairs`; the train
split only, never an eval pair), each resized by the EVAL.md profile rule (`census_selector.
load_resized`) to widths around the study's (`WIDTH_SCALES`), as they are and with independent
photometric changes, noise and one-view blur (`augment.appearance` with `AUGMENT`: the geometry
untouched; no flip, which would need the right view's ground truth). Synthetic items: layered
scenes with exact disparity (`synth_train.layered_scene`: slanted planes, thin structures,
textureless and repetitive surfaces) over the census's range, with the same nuisances. The census
(and, for the encoder variant, the native head) runs on each whole item once; training cuts
crops of the stored maps.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray
from torch import Tensor

from .augment import AugmentConfig, appearance
from .census_residual_maps import census_maps
from .census_selector import load_resized
from .census_selector_cells import Mask, Pixels
from .labeled import LABELED_HOLDOUT, labeled_pairs
from .pairs import Pair
from .profile import to_u8
from .refine import CELL
from .synth_train import layered_scene

Logits = Callable[[NDArray[np.uint8], NDArray[np.uint8]], NDArray[np.float64]]
"""The native head's (D, T, P) logits of a u8 view pair (the encoder variant's evidence)."""

AUGMENT = AugmentConfig(
    flip_prob=0.0,
    photometric_prob=0.8,
    noise_prob=0.5,
    noise_std=0.02,
    occlusion_prob=0.0,
    blur_prob=0.2,
)
WIDTH_SCALES = (0.8, 1.0, 1.25)
"""Real items at these multiples of the study's width (rounded to 8 px, at most the original)."""
SYNTH_SHAPE = (96, 192)


@dataclass(frozen=True)
class Item:
    features: NDArray[np.float16]
    """(C, H, W), `census_residual_maps.channel_names` order."""
    anchor: Pixels
    gt: Pixels
    valid: Mask
    synthetic: bool


def train_pairs(data_dir: Path | None, holdout: Sequence[str] = LABELED_HOLDOUT) -> list[Pair]:
    """Labeled train-split pairs not held out (never the eval split)."""
    pairs = [p for p in labeled_pairs(data_dir) if p.pair_id not in holdout]
    if not pairs:
        raise ValueError("no labeled train pairs outside the holdout")
    return pairs


def item_of(
    left: NDArray[np.float32],
    right: NDArray[np.float32],
    gt: Pixels,
    valid: Mask,
    disparities: int,
    anchor: str,
    logits: Logits | None,
    synthetic: bool,
) -> Item:
    l8, r8 = to_u8(left), to_u8(right)
    maps = census_maps(l8, r8, disparities, anchor, logits(l8, r8) if logits else None)
    return Item(maps.features.astype(np.float16), maps.anchor, gt, valid, synthetic)


def real_items(
    pairs: Sequence[Pair],
    width: int,
    disparities: int,
    anchor: str,
    augments: int,
    rng: np.random.Generator,
    logits: Logits | None = None,
) -> list[Item]:
    """Each pair at each `WIDTH_SCALES` width, clean and `augments - 1` times with nuisances."""
    items = []
    for pair in pairs:
        for scale in WIDTH_SCALES:
            w = min(int(round(width * scale / 8)) * 8, pair.width)
            left, right, gt, valid = load_resized(pair, w)
            for a in range(augments):
                lf = left.astype(np.float32) / np.float32(255.0)
                rf = right.astype(np.float32) / np.float32(255.0)
                if a > 0:
                    lf, rf = appearance(lf, rf, rng, AUGMENT)
                items.append(item_of(lf, rf, gt, valid, disparities, anchor, logits, False))
    return items


def synthetic_items(
    count: int,
    disparities: int,
    anchor: str,
    rng: np.random.Generator,
    logits: Logits | None = None,
) -> list[Item]:
    """`count` layered scenes of `SYNTH_SHAPE`, disparities 0 .. disparities - 4 px."""
    h, w = SYNTH_SHAPE
    items = []
    for _ in range(count):
        left, right, gt = layered_scene(rng, h, w, float(disparities - CELL))
        lf, rf = appearance(left, right, rng, AUGMENT)
        valid = np.ones(gt.shape, dtype=bool)
        items.append(item_of(lf, rf, gt, valid, disparities, anchor, logits, True))
    return items


def crop_batch(
    items: Sequence[Item],
    batch: int,
    crop: tuple[int, int],
    rng: np.random.Generator,
    real_share: float,
    channels: Sequence[int] | None = None,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """(features (B, C, h, w), anchor, gt, valid (B, h, w)) of random crops: real items with
    probability `real_share`, synthetic ones otherwise (whichever exist)."""
    real = [i for i, it in enumerate(items) if not it.synthetic]
    synth = [i for i, it in enumerate(items) if it.synthetic]
    ch, cw = crop
    feats, anchors, gts, valids = [], [], [], []
    for _ in range(batch):
        pool = real if (rng.random() < real_share and real) or not synth else synth
        it = items[pool[int(rng.integers(len(pool)))]]
        _, h, w = it.features.shape
        if h < ch or w < cw:
            raise ValueError(f"item {h}x{w} smaller than the crop {ch}x{cw}")
        y, x = int(rng.integers(0, h - ch + 1)), int(rng.integers(0, w - cw + 1))
        f = it.features[:, y : y + ch, x : x + cw]
        feats.append(f if channels is None else f[list(channels)])
        anchors.append(it.anchor[y : y + ch, x : x + cw])
        gts.append(it.gt[y : y + ch, x : x + cw])
        valids.append(it.valid[y : y + ch, x : x + cw])
    return (
        torch.from_numpy(np.stack(feats).astype(np.float32)),
        torch.from_numpy(np.stack(anchors)),
        torch.from_numpy(np.stack(gts)),
        torch.from_numpy(np.stack(valids)),
    )
