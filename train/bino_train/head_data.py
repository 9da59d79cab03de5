"""Labelled training crops for the stereo head: synthetic scenes and SGBM pseudo-labels.

Sign convention everywhere: left(x, y) = right(x - d, y), d >= 0 (the rectified geometry
the encoder and EVAL.md use); labels are left-view disparities.

Synthetic: a slanted textured background plane and, often, a fronto-parallel textured rectangle
in front of it (larger disparity, so it occludes), rendered at sub-pixel disparities
0 .. 4 (D-1) px, i.e. every candidate 0 .. D-1 patch columns and the sub-token steps between.

Pseudo-labels: OpenCV StereoSGBM with the EVAL.md settings (numDisparities scaled with the
resize width: 32 px per 160 px) on the resized full train image, so that crops do not lose
their left context. Its internal left-right check (disp12MaxDiff=1) and uniqueness test
(uniquenessRatio=10) leave only confident pixels valid; SGBM never sees the eval split: pairs
come from `training_pairs()` and the image store re-checks the split.

Token-grid labels (both sources): a 4x4 cell gets the mean of its valid pixel disparities,
in patch columns (px / 4), if at least `min_valid` of its 16 pixels are valid and their spread
(max - min) is at most `max_spread` px; otherwise NaN (a cell straddling a depth edge has no
single disparity). The mean is what the eval compares against: the token value is bilinearly
upsampled to the cell's pixels.

Every sample is a pure function of (seed, index), so a training run can regenerate any part
of its data stream, which is what makes resume exact even with a descriptor pool.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from .augment import AugmentConfig, ImageStore, dataset_weights, nuisances, width_range
from .head_descriptors import PATHWAYS as PATHWAYS
from .head_descriptors import DescBatch as DescBatch
from .head_descriptors import DescriptorPool as DescriptorPool
from .head_descriptors import batch_fields as batch_fields
from .head_descriptors import check_pathway as check_pathway
from .head_descriptors import encode as encode
from .head_descriptors import encode_maps as encode_maps
from .head_descriptors import gather as gather
from .head_descriptors import stored_batch as stored_batch
from .labeled import LABELED_HOLDOUT, LabeledSource
from .pairs import Pair, training_pairs
from .probe import CELL
from .synthetic import smooth_texture

Gray = NDArray[np.float32]

HEAD_AUGMENT = AugmentConfig(flip_prob=0.0, occlusion_prob=0.0)
"""Photometric and noise nuisances only: a flip+swap or an occluder would change the labels.
(Crop size and resize widths come from DataConfig.)"""


@dataclass(frozen=True)
class DataConfig:
    crop_h: int = 48
    crop_w: int = 160
    max_disp: int = 12
    """Patch columns; synthetic disparities cover 0 .. max_disp - 1."""
    synthetic_fraction: float = 0.5
    """Share of synthetic samples; the rest are SGBM pseudo-labels (1: no train pairs read)."""
    min_width: int = 160
    max_width: int = 320
    width_step: int = 16
    """Resize widths are multiples of this, so resized images and SGBM maps get reused."""
    balance_datasets: bool = True
    """Pick datasets uniformly: the driving sequence holds most of the train pairs."""
    min_valid: int = 12
    max_spread: float = 2.0
    label_weighting: str = "binary"
    """"binary": every labelled cell weighs 1. "lr": SGBM is also run on the mirrored pair (the
    right view's disparity), and a cell weighs the mean over its valid pixels of
    exp(-(lr_diff / LR_SCALE_PX)^2) times its valid fraction (synthetic cells weigh 1)."""
    augment: AugmentConfig = field(default_factory=lambda: HEAD_AUGMENT)
    sgbm_cache_mb: int = 256
    labeled_fraction: float = 0.0
    """Share of crops from the labeled train pairs with their dense ground truth (labeled.py;
    the held-out ones excluded); taken out of the pseudo-label share: synthetic_fraction +
    labeled_fraction <= 1, SGBM pseudo-labels get the rest."""
    synthetic_kind: str = "plane"
    """"plane": `synthetic_sample` (a slanted plane and a rectangle); "layered":
    synth_train.layered_sample (slanted layers, thin structures, textureless and repetitive
    surfaces, exact occlusion, disparities over the whole candidate range)."""
    flat_grain_levels: float = 0.0
    """Grain of the layered scenes' textureless surfaces, grey levels rms of its high-pass: 0 the
    sub-grey-level grain the shipped heads were trained with, synth_folder.FLAT_GRAIN_LEVELS
    (1.5) what real flat regions carry (`bino_train.flat_texture`)."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict[str, Any]) -> DataConfig:
        rest = {k: v for k, v in d.items() if k != "augment"}
        return DataConfig(augment=AugmentConfig.from_dict(d["augment"]), **rest)


@dataclass(frozen=True)
class Sample:
    left: Gray
    right: Gray
    label: NDArray[np.float32]
    """(crop_h / 4, crop_w / 4) patch columns, NaN where unknown."""
    synthetic: bool
    weight: NDArray[np.float32] | None = None
    """(crop_h / 4, crop_w / 4) confidence of each label in [0, 1] (None: 1 where labelled)."""
    clean: tuple[Gray, Gray] | None = None
    """The crops before the nuisances (photometric terms compare these; None: left, right)."""

    def label_weight(self) -> NDArray[np.float32]:
        if self.weight is not None:
            return self.weight
        return np.isfinite(self.label).astype(np.float32)


def cell_labels(
    disparity: NDArray[np.float32],
    valid: NDArray[np.bool_],
    min_valid: int = 12,
    max_spread: float = 2.0,
) -> NDArray[np.float32]:
    """Pixel disparities (H, W) in px -> token grid (H/4, W/4) in patch columns (NaN: unknown)."""
    h, w = disparity.shape
    if h % CELL or w % CELL:
        raise ValueError(f"label size {disparity.shape} is not a multiple of {CELL}")
    cells = (h // CELL, CELL, w // CELL, CELL)
    d = disparity.reshape(cells).transpose(0, 2, 1, 3).reshape(h // CELL, w // CELL, -1)
    v = valid.reshape(cells).transpose(0, 2, 1, 3).reshape(h // CELL, w // CELL, -1)
    count = v.sum(-1)
    total = np.where(v, d, 0.0).sum(-1)
    hi = np.where(v, d, -np.inf).max(-1)
    lo = np.where(v, d, np.inf).min(-1)
    ok = (count >= min_valid) & (hi - lo <= max_spread)
    mean = total / np.maximum(count, 1)
    return np.where(ok, mean / CELL, np.nan).astype(np.float32)


# --- synthetic scenes ---------------------------------------------------------------------


LR_SCALE_PX = 0.5
"""Left-right disagreement (px) at which an SGBM pixel's confidence falls to exp(-1)."""

LR_LIMIT_PX = 1.0
"""SGBM pixels whose left and right disparities differ by more are not labels (SGBM's own
disp12MaxDiff=1 works on integer pixels; this works on its 1/16 px output)."""


def cell_weights(
    confidence: NDArray[np.float32], valid: NDArray[np.bool_], label: NDArray[np.float32]
) -> NDArray[np.float32]:
    """Per-cell weight: mean pixel confidence over the valid pixels x valid fraction; 0 where the
    cell has no label."""
    h, w = confidence.shape
    cells = (h // CELL, CELL, w // CELL, CELL)
    c = confidence.reshape(cells).transpose(0, 2, 1, 3).reshape(h // CELL, w // CELL, -1)
    v = valid.reshape(cells).transpose(0, 2, 1, 3).reshape(h // CELL, w // CELL, -1)
    weight = np.where(v, c, 0.0).sum(-1) / float(CELL * CELL)
    return np.where(np.isfinite(label), weight, 0.0).astype(np.float32)


def _texture(rng: np.random.Generator, h: int, w: int) -> Gray:
    """Value noise at a random contrast, sometimes with hard-edged blobs (as real edges)."""
    tex = smooth_texture(rng, h, w)
    if rng.random() < 0.5:
        for _ in range(int(rng.integers(2, 8))):
            y, x = int(rng.integers(0, h)), int(rng.integers(0, w))
            ry, rx = int(rng.integers(2, 12)), int(rng.integers(2, 24))
            tex[max(0, y - ry) : y + ry, max(0, x - rx) : x + rx] = rng.random()
    contrast = math.exp(rng.uniform(math.log(0.15), 0.0))  # low-texture scenes included
    return np.clip(0.5 + (tex - tex.mean()) * contrast * 1.6, 0.0, 1.0).astype(np.float32)


def _sample_along_x(texture: Gray, x: NDArray[np.float32]) -> Gray:
    """texture[y, x[y, col]] with bilinear interpolation along x (x in texture coordinates)."""
    ys = np.broadcast_to(np.arange(x.shape[0], dtype=np.float32)[:, None], x.shape)
    return np.asarray(
        cv2.remap(texture, x.astype(np.float32), np.ascontiguousarray(ys), cv2.INTER_LINEAR),
        dtype=np.float32,
    )


@dataclass(frozen=True)
class Scene:
    """Left-view disparity in px: background a + bx * (x - w/2) + by * (y - h/2), and an optional
    fronto-parallel rectangle [y0, y1) x [x0, x1) (left-view coordinates) at disparity fg."""

    a: float
    bx: float = 0.0
    by: float = 0.0
    rect: tuple[int, int, int, int] | None = None
    fg: float = 0.0
    jitter: float = 0.0
    """Sub-pixel offset of both views in texture coordinates (both get interpolated alike)."""


def background_disparity(scene: Scene, h: int, w: int) -> NDArray[np.float32]:
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    return (scene.a + scene.bx * (xs - w / 2) + scene.by * (ys - h / 2)).astype(np.float32)


def render_scene(
    scene: Scene, background: Gray, foreground: Gray, h: int, w: int, margin: int
) -> tuple[Gray, Gray, NDArray[np.float32]]:
    """(left, right, left disparity px). Textures are (h, w + margin) in right-view coordinates
    shifted by `margin`: right(x') = T(x' + margin), left(x) = T(x - d(x) + margin)."""
    xs = np.broadcast_to(np.arange(w, dtype=np.float32)[None, :], (h, w))
    base = xs + np.float32(margin + scene.jitter)
    d_bg = background_disparity(scene, h, w)
    if float(d_bg.min()) < 0 or float(d_bg.max()) > margin:
        raise ValueError("background disparity outside [0, margin]")
    left = _sample_along_x(background, base - d_bg)
    right = _sample_along_x(background, base)
    disparity = d_bg
    if scene.rect is not None:
        y0, y1, x0, x1 = scene.rect
        left_fg = _sample_along_x(foreground, base - np.float32(scene.fg))
        right_fg = _sample_along_x(foreground, base)
        left[y0:y1, x0:x1] = left_fg[y0:y1, x0:x1]
        # The rectangle covers [x0 - fg, x1 - fg) in the right view (pixel centres inside).
        r0 = max(0, math.ceil(x0 - scene.fg))
        r1 = min(w, math.ceil(x1 - scene.fg))
        if r1 > r0:
            right[y0:y1, r0:r1] = right_fg[y0:y1, r0:r1]
        disparity = disparity.copy()
        disparity[y0:y1, x0:x1] = scene.fg
    return left, right, disparity


def random_scene(rng: np.random.Generator, h: int, w: int, max_px: float) -> Scene:
    """Disparities within [0, max_px]: a slanted plane, often with a nearer rectangle."""
    bx = float(rng.uniform(-0.04, 0.04)) if rng.random() < 0.6 else 0.0
    by = float(rng.uniform(-0.08, 0.08)) if rng.random() < 0.4 else 0.0
    spread = abs(bx) * w / 2 + abs(by) * h / 2
    a = float(rng.uniform(spread, max(spread, max_px - spread)))
    rect, fg = None, 0.0
    if rng.random() < 0.6:
        d_max = a + spread
        fg = float(rng.uniform(min(d_max + 2.0, max_px), max_px))
        rh, rw = int(rng.integers(h // 4, h + 1)), int(rng.integers(w // 8, w // 2))
        y0, x0 = int(rng.integers(0, h - rh + 1)), int(rng.integers(0, w - rw + 1))
        rect = (y0, y0 + rh, x0, x0 + rw)
    return Scene(a, bx, by, rect, fg, float(rng.uniform(0.0, 1.0)))


def synthetic_sample(rng: np.random.Generator, cfg: DataConfig) -> Sample:
    h, w = cfg.crop_h, cfg.crop_w
    max_px = CELL * (cfg.max_disp - 1)
    margin = int(max_px) + 2
    scene = random_scene(rng, h, w, max_px)
    textures = [_texture(rng, h, w + margin + 2) for _ in range(2)]
    left, right, disparity = render_scene(scene, textures[0], textures[1], h, w, margin)
    label = cell_labels(disparity, np.ones_like(disparity, dtype=bool), cfg.min_valid, 2.0)
    clean = (left, right)
    left, right = nuisances(left, right, rng, cfg.augment)
    return Sample(left, right, label, synthetic=True, clean=clean)


# --- SGBM pseudo-labels -------------------------------------------------------------------


def make_sgbm(width: int) -> cv2.StereoSGBM:
    """EVAL.md StereoSGBM; numDisparities is 32 px per 160 px of width, a multiple of 16."""
    return cv2.StereoSGBM.create(
        minDisparity=0,
        numDisparities=16 * math.ceil(2 * width / 160),
        blockSize=5,
        P1=8 * 3 * 25,
        P2=32 * 3 * 25,
        disp12MaxDiff=1,
        uniquenessRatio=10,
        speckleWindowSize=0,
        speckleRange=0,
        mode=cv2.STEREO_SGBM_MODE_SGBM,
    )


def sgbm_disparity(
    left: NDArray[np.uint8], right: NDArray[np.uint8]
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Left-view disparity in px and the pixels SGBM kept (LR check and uniqueness passed)."""
    raw = make_sgbm(left.shape[1]).compute(left, right)
    return raw.astype(np.float32) / np.float32(16.0), raw >= 0


def lr_disagreement(
    left: NDArray[np.uint8], right: NDArray[np.uint8], disparity: NDArray[np.float32]
) -> NDArray[np.float32]:
    """|d_L(x) - d_R(x - d_L(x))| in px from SGBM on the mirrored pair (inf where the right
    view has no value or x - d_L falls outside it)."""
    mirrored, ok = sgbm_disparity(
        np.ascontiguousarray(right[:, ::-1]), np.ascontiguousarray(left[:, ::-1])
    )
    right_disp = np.where(ok, mirrored, np.inf)[:, ::-1]
    h, w = disparity.shape
    target = np.arange(w)[None, :] - np.floor(disparity + 0.5).astype(np.int64)
    inside = (target >= 0) & (target < w)
    landed = np.take_along_axis(right_disp, np.clip(target, 0, w - 1), axis=1)
    return np.where(inside, np.abs(landed - disparity), np.inf).astype(np.float32)


def consistent_sgbm(
    left: NDArray[np.uint8], right: NDArray[np.uint8]
) -> tuple[NDArray[np.float32], NDArray[np.bool_], NDArray[np.float32]]:
    """SGBM kept pixels that also pass the sub-pixel left-right check: (disparity px, valid,
    confidence exp(-(lr_diff / LR_SCALE_PX)^2))."""
    disp, valid = sgbm_disparity(left, right)
    diff = lr_disagreement(left, right, disp)
    valid = valid & (diff <= LR_LIMIT_PX)
    confidence = np.exp(-np.square(np.where(valid, diff, 0.0) / LR_SCALE_PX))
    return disp, valid, confidence.astype(np.float32)


class PseudoLabelSource:
    """Crops of resized train pairs with SGBM labels; SGBM maps cached per (pair, width)."""

    def __init__(self, pairs: list[Pair], cfg: DataConfig) -> None:
        self.cfg = cfg
        self.store = ImageStore(pairs, cfg.augment.cache_mb)  # raises on non-train pairs
        self.weights = dataset_weights(pairs, cfg.balance_datasets)
        self.crop = replace(
            cfg.augment,
            crop_h=cfg.crop_h,
            crop_w=cfg.crop_w,
            min_width=cfg.min_width,
            max_width=cfg.max_width,
            width_step=cfg.width_step,
        )
        self._sgbm: OrderedDict[tuple[int, int], NDArray[np.int16]] = OrderedDict()
        self._bytes = 0

    def sgbm(self, index: int, width: int) -> NDArray[np.int16]:
        """(2, H, W): disparity x 16 (SGBM's own fixed point), -16 where invalid, and the
        confidence x 4096 (4096 under binary weighting); LRU-cached."""
        key = (index, width)
        hit = self._sgbm.get(key)
        if hit is not None:
            self._sgbm.move_to_end(key)
            return hit
        left, right = (self.store.resized(index, v, width) for v in (0, 1))
        if self.cfg.label_weighting == "lr":
            disp, valid, confidence = consistent_sgbm(left, right)
        else:
            disp, valid = sgbm_disparity(left, right)
            confidence = np.ones_like(disp)
        packed = np.stack(
            [
                np.where(valid, np.rint(disp * 16.0), -16),
                np.rint(np.where(valid, confidence, 0.0) * 4096.0),
            ]
        ).astype(np.int16)
        self._sgbm[key] = packed
        self._bytes += packed.nbytes
        while self._bytes > self.cfg.sgbm_cache_mb * 1024 * 1024 and len(self._sgbm) > 1:
            _, old = self._sgbm.popitem(last=False)
            self._bytes -= old.nbytes
        return packed

    def sample(self, rng: np.random.Generator) -> Sample:
        cfg = self.cfg
        index = int(rng.choice(len(self.store.pairs), p=self.weights))
        lo, hi = width_range(self.store.pairs[index], self.crop)
        width = math.exp(rng.uniform(math.log(lo), math.log(hi))) if hi > lo else float(lo)
        step = cfg.width_step
        width_q = int(min(hi, max(lo, round(width / step) * step)))
        views = [self.store.resized(index, v, width_q) for v in (0, 1)]
        packed = self.sgbm(index, width_q)
        h, w = views[0].shape
        y = int(rng.integers(0, h - cfg.crop_h + 1))
        x = int(rng.integers(0, w - cfg.crop_w + 1))
        window = (slice(y, y + cfg.crop_h), slice(x, x + cfg.crop_w))
        left, right = (v[window].astype(np.float32) / np.float32(255.0) for v in views)
        crop = packed[0][window]
        valid = crop >= 0
        label = cell_labels(
            crop.astype(np.float32) / np.float32(16.0), valid, cfg.min_valid, cfg.max_spread
        )
        confidence = packed[1][window].astype(np.float32) / np.float32(4096.0)
        weight = cell_weights(confidence, valid, label)
        clean = (left, right)
        left, right = nuisances(left, right, rng, cfg.augment)
        return Sample(left, right, label, synthetic=False, weight=weight, clean=clean)


LABEL_WEIGHTINGS = ("binary", "lr")

VALIDATION_SHARE = 8
"""One pair in this many of each dataset (at least 4 pairs) is held out of head training."""


def validation_pairs(data_dir: Path | None = None) -> list[Pair]:
    """Train-split pairs held out of head training to choose recipes (never the eval split):
    per dataset of at least 4 pairs, the last ceil(n / VALIDATION_SHARE) by pair id (a
    contiguous block, so a held-out video frame has few training neighbours), and the labeled
    pairs of `labeled.LABELED_HOLDOUT` (issue 40; from 2026-12-05 on, so the heads trained
    before then saw MiddEval3-Q's Playroom and Recycle as pseudo-labelled crops)."""
    train = training_pairs(data_dir)
    by_dataset: dict[str, list[Pair]] = {}
    for pair in train:
        by_dataset.setdefault(pair.dataset, []).append(pair)
    held = []
    for dataset in sorted(by_dataset):
        pairs = sorted(by_dataset[dataset], key=lambda p: p.pair_id)
        if len(pairs) >= 4:
            held.extend(pairs[-math.ceil(len(pairs) / VALIDATION_SHARE) :])
    chosen = {p.pair_id for p in held}
    held.extend(p for p in train if p.pair_id in LABELED_HOLDOUT and p.pair_id not in chosen)
    return held


def head_training_pairs(data_dir: Path | None = None) -> list[Pair]:
    """The train split without the validation pairs."""
    held = {p.pair_id for p in validation_pairs(data_dir)}
    return [p for p in training_pairs(data_dir) if p.pair_id not in held]


SYNTHETIC_KINDS = ("plane", "layered")


class HeadSampler:
    """Sample `i` of a run is a pure function of (seed, i): synthetic, from a labeled train
    pair's ground truth, or pseudo-labelled (one uniform draw picks, by the config's shares)."""

    def __init__(self, cfg: DataConfig, seed: int, data_dir: Path | None) -> None:
        self.cfg = cfg
        self.seed = seed
        if cfg.label_weighting not in LABEL_WEIGHTINGS:
            raise ValueError(f"label_weighting {cfg.label_weighting!r} not in {LABEL_WEIGHTINGS}")
        if cfg.synthetic_kind not in SYNTHETIC_KINDS:
            raise ValueError(f"synthetic_kind {cfg.synthetic_kind!r} not in {SYNTHETIC_KINDS}")
        shares = (cfg.synthetic_fraction, cfg.labeled_fraction)
        if min(shares) < 0.0 or sum(shares) > 1.0 + 1e-9:
            raise ValueError(
                f"synthetic_fraction {shares[0]} + labeled_fraction {shares[1]} must lie in [0, 1]"
            )
        pairs = head_training_pairs(data_dir) if sum(shares) < 1.0 or shares[1] > 0 else []
        self.labeled = None
        if cfg.labeled_fraction > 0.0:
            self.labeled = LabeledSource([p for p in pairs if p.gt is not None], cfg)
        pseudo = cfg.synthetic_fraction + cfg.labeled_fraction < 1.0
        self.real = PseudoLabelSource(pairs, cfg) if pseudo else None

    def synthetic(self, rng: np.random.Generator) -> Sample:
        if self.cfg.synthetic_kind == "layered":
            from .synth_train import layered_sample

            return layered_sample(rng, self.cfg)
        return synthetic_sample(rng, self.cfg)

    def sample(self, index: int) -> Sample:
        rng = np.random.default_rng([self.seed, index])
        if self.real is None and self.labeled is None:
            return self.synthetic(rng)
        draw = rng.random()
        if draw < self.cfg.synthetic_fraction:
            return self.synthetic(rng)
        if (
            self.labeled is not None
            and draw < self.cfg.synthetic_fraction + self.cfg.labeled_fraction
        ):
            return self.labeled.sample(rng)
        if self.real is None:  # rounding at the top of the labeled share
            return self.synthetic(rng)
        return self.real.sample(rng)

    def samples(self, indices: Sequence[int]) -> list[Sample]:
        return [self.sample(i) for i in indices]
