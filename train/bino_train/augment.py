"""Training crops from the train split, and the stereo-aware nuisances of paper section 3.5.

A crop: pick a pair, a resize width (log-uniform in a range, quantised so resized images can be
cached), then the same 48 x 160 window in both views, which keeps the rectified geometry
left(x, y) = right(x - d, y), d >= 0. Nuisances act on each view independently: photometric
(contrast, brightness, gamma), gaussian noise, an occluding rectangle in one view, and (when
`blur_prob` is set) defocus blur of one view.
A horizontal flip is only ever applied together with a swap of the views: mirroring turns the
left view into a right view, and swapping restores d >= 0.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from typing import Any

import cv2
import numpy as np
import torch
from numpy.typing import NDArray
from torch import Tensor

from .pairs import Pair, check_training_pairs, load_gray_u8

Gray = NDArray[np.float32]


@dataclass(frozen=True)
class AugmentConfig:
    crop_h: int = 48
    crop_w: int = 160
    min_width: int = 160
    """Smallest resized image width (raised per image so that the crop fits)."""
    max_width: int = 672
    """Largest resized image width (never above the original width: no upsampling)."""
    width_step: int = 8
    """Resize widths are multiples of this, so a few resized copies per image get reused."""
    balance_datasets: bool = False
    """Pick datasets uniformly instead of pairs (the driving sequence dominates the pair count)."""
    flip_prob: float = 0.5
    independent: bool = True
    """Photometric and noise parameters drawn per view (the paper's strongest recipe)."""
    photometric_prob: float = 0.8
    brightness: float = 0.1
    contrast: float = 0.2
    gamma: float = 0.25
    noise_prob: float = 0.5
    noise_std: float = 0.03
    occlusion_prob: float = 0.5
    occlusion_h: tuple[int, int] = (8, 32)
    occlusion_w: tuple[int, int] = (8, 48)
    blur_prob: float = 0.0
    """Chance of a gaussian defocus blur of one view (issue 14: one-view blur was never seen in
    training, and the readouts lose most under it). 0 draws nothing: older runs resume exactly."""
    blur_sigma: tuple[float, float] = (0.5, 1.5)
    """Range of the blur's standard deviation in pixels of the crop (a 5x5 box filter is 1.41)."""
    cache_mb: int = 384
    teacher_clean: bool = False
    """Teacher sees the pair before the appearance nuisances, the student after: the
    slot-wise target then asks the student's tokens to be invariant to them."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @staticmethod
    def from_dict(d: dict[str, Any]) -> AugmentConfig:
        fixed = dict(d)
        for key in ("occlusion_h", "occlusion_w", "blur_sigma"):
            if key in fixed:
                fixed[key] = tuple(fixed[key])
        return AugmentConfig(**fixed)


CLEAN = AugmentConfig(photometric_prob=0.0, noise_prob=0.0, occlusion_prob=0.0, flip_prob=0.0)


class ImageStore:
    """Grayscale train images, each decoded once, with an LRU cache of area-resized copies."""

    def __init__(self, pairs: list[Pair], cache_mb: int) -> None:
        check_training_pairs(pairs)
        self.pairs = pairs
        self._originals: dict[tuple[int, int], NDArray[np.uint8]] = {}
        self._resized: OrderedDict[tuple[int, int, int], NDArray[np.uint8]] = OrderedDict()
        self._budget = cache_mb * 1024 * 1024
        self._bytes = 0

    def original(self, index: int, view: int) -> NDArray[np.uint8]:
        key = (index, view)
        if key not in self._originals:
            pair = self.pairs[index]
            image = load_gray_u8(pair.left if view == 0 else pair.right)
            if image.shape != (pair.height, pair.width):
                raise ValueError(f"{pair.pair_id}: size {image.shape} differs from PAIRS.tsv")
            self._originals[key] = image
        return self._originals[key]

    def resized(self, index: int, view: int, width: int) -> NDArray[np.uint8]:
        key = (index, view, width)
        hit = self._resized.get(key)
        if hit is not None:
            self._resized.move_to_end(key)
            return hit
        image = self.original(index, view)
        h, w = image.shape
        if width == w:
            return image
        height = int(math.floor(h * width / w + 0.5))
        resized = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
        out = np.asarray(resized, dtype=np.uint8)
        self._resized[key] = out
        self._bytes += out.nbytes
        while self._bytes > self._budget and len(self._resized) > 1:
            _, old = self._resized.popitem(last=False)
            self._bytes -= old.nbytes
        return out


def width_range(pair: Pair, cfg: AugmentConfig) -> tuple[int, int]:
    """Quantised resize widths for which a crop fits, smallest and largest."""
    step = cfg.width_step
    need = max(cfg.min_width, cfg.crop_w, math.ceil(cfg.crop_h * pair.width / pair.height))
    if need > pair.width:
        raise ValueError(f"{pair.pair_id} ({pair.width}x{pair.height}) is too small for a crop")
    lo = min(math.ceil(need / step) * step, pair.width)
    hi = max(lo, (min(cfg.max_width, pair.width) // step) * step)
    return lo, hi


def sample_window(
    store: ImageStore, rng: np.random.Generator, cfg: AugmentConfig, weights: NDArray[np.float64]
) -> tuple[Gray, Gray]:
    """A clean crop (crop_h, crop_w) of both views of a random pair at a random scale."""
    index = int(rng.choice(len(store.pairs), p=weights))
    lo, hi = width_range(store.pairs[index], cfg)
    width = math.exp(rng.uniform(math.log(lo), math.log(hi))) if hi > lo else float(lo)
    width_q = int(min(hi, max(lo, round(width / cfg.width_step) * cfg.width_step)))
    views = [store.resized(index, v, width_q) for v in (0, 1)]
    h, w = views[0].shape
    y = int(rng.integers(0, h - cfg.crop_h + 1))
    x = int(rng.integers(0, w - cfg.crop_w + 1))
    left, right = (
        v[y : y + cfg.crop_h, x : x + cfg.crop_w].astype(np.float32) / np.float32(255.0)
        for v in views
    )
    return left, right


def flip_swap(left: Gray, right: Gray) -> tuple[Gray, Gray]:
    """Mirror both views and swap them: left(x) = right(x - d) with d >= 0 still holds."""
    return np.ascontiguousarray(right[:, ::-1]), np.ascontiguousarray(left[:, ::-1])


def photometric(image: Gray, params: tuple[float, float, float]) -> Gray:
    """Contrast about the mean, brightness offset, then gamma; values stay in [0, 1]."""
    contrast, brightness, gamma = params
    mean = float(image.mean())
    out = np.clip((image - mean) * contrast + mean + brightness, 0.0, 1.0)
    return np.power(out, gamma, dtype=np.float32)


def draw_photometric(rng: np.random.Generator, cfg: AugmentConfig) -> tuple[float, float, float]:
    contrast = rng.uniform(1.0 - cfg.contrast, 1.0 + cfg.contrast)
    brightness = rng.uniform(-cfg.brightness, cfg.brightness)
    gamma = math.exp(rng.uniform(-math.log1p(cfg.gamma), math.log1p(cfg.gamma)))
    return float(contrast), float(brightness), float(gamma)


def blur(image: Gray, sigma: float) -> Gray:
    """Gaussian defocus blur, edges replicated (same size and dtype)."""
    out = cv2.GaussianBlur(image, (0, 0), sigmaX=sigma, borderType=cv2.BORDER_REPLICATE)
    return np.asarray(out, dtype=np.float32)


def occlude(image: Gray, rng: np.random.Generator, cfg: AugmentConfig) -> Gray:
    """Replace a random rectangle by a flat patch or by noise (something the other view lacks)."""
    h, w = image.shape
    rh = int(rng.integers(cfg.occlusion_h[0], min(cfg.occlusion_h[1], h) + 1))
    rw = int(rng.integers(cfg.occlusion_w[0], min(cfg.occlusion_w[1], w) + 1))
    y = int(rng.integers(0, h - rh + 1))
    x = int(rng.integers(0, w - rw + 1))
    out = image.copy()
    level = rng.uniform(0.0, 1.0)
    if rng.random() < 0.5:
        out[y : y + rh, x : x + rw] = level
    else:
        patch = level + rng.normal(0.0, rng.uniform(0.05, 0.3), size=(rh, rw))
        out[y : y + rh, x : x + rw] = np.clip(patch, 0.0, 1.0)
    return out


def nuisances(
    left: Gray, right: Gray, rng: np.random.Generator, cfg: AugmentConfig
) -> tuple[Gray, Gray]:
    """Flip+swap, photometric, noise and one-view occlusion, each with its probability."""
    left, right = maybe_flip(left, right, rng, cfg)
    return appearance(left, right, rng, cfg)


def maybe_flip(
    left: Gray, right: Gray, rng: np.random.Generator, cfg: AugmentConfig
) -> tuple[Gray, Gray]:
    """Horizontal flip, always together with the view swap (keeps d >= 0)."""
    if rng.random() < cfg.flip_prob:
        return flip_swap(left, right)
    return left, right


def appearance(
    left: Gray, right: Gray, rng: np.random.Generator, cfg: AugmentConfig
) -> tuple[Gray, Gray]:
    """One-view blur, photometric change, noise and one-view occlusion (the geometry is left
    alone). Blur comes first: defocus happens in the optics, before the sensor's noise."""
    views = [left, right]
    if cfg.blur_prob > 0.0 and rng.random() < cfg.blur_prob:
        v = int(rng.integers(0, 2))
        views[v] = blur(views[v], float(rng.uniform(*cfg.blur_sigma)))
    if rng.random() < cfg.photometric_prob:
        shared = draw_photometric(rng, cfg)
        for v in range(2):
            views[v] = photometric(
                views[v], draw_photometric(rng, cfg) if cfg.independent else shared
            )
    if rng.random() < cfg.noise_prob:
        shared_std = rng.uniform(0.0, cfg.noise_std)
        for v in range(2):
            std = rng.uniform(0.0, cfg.noise_std) if cfg.independent else shared_std
            noisy = views[v] + rng.normal(0.0, std, size=views[v].shape)
            views[v] = np.clip(noisy, 0.0, 1.0).astype(np.float32)
    if rng.random() < cfg.occlusion_prob:
        v = int(rng.integers(0, 2))
        views[v] = occlude(views[v], rng, cfg)
    return views[0].astype(np.float32), views[1].astype(np.float32)


def dataset_weights(pairs: list[Pair], balance: bool) -> NDArray[np.float64]:
    if not balance:
        return np.full(len(pairs), 1.0 / len(pairs))
    counts: dict[str, int] = {}
    for p in pairs:
        counts[p.dataset] = counts.get(p.dataset, 0) + 1
    w = np.array([1.0 / counts[p.dataset] for p in pairs])
    return w / w.sum()


class CropSampler:
    """Endless augmented training batches; its state (RNG + count) makes resume exact."""

    def __init__(self, pairs: list[Pair], cfg: AugmentConfig, seed: int) -> None:
        self.cfg = cfg
        self.store = ImageStore(pairs, cfg.cache_mb)
        self.weights = dataset_weights(pairs, cfg.balance_datasets)
        self.rng = np.random.default_rng(seed)
        self.batches = 0

    def next_batch(self, batch: int) -> tuple[Tensor, Tensor]:
        """(left, right), each (B, 1, crop_h, crop_w) float32 in [0, 1], with nuisances."""
        _, _, left, right = self.next_batch_with_clean(batch)
        return left, right

    def next_batch_with_clean(self, batch: int) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """(clean left, clean right, left, right): the same flipped crops before and after
        the appearance nuisances, each (B, 1, crop_h, crop_w) float32 in [0, 1]."""
        views: list[list[Gray]] = [[], [], [], []]
        for _ in range(batch):
            left, right = sample_window(self.store, self.rng, self.cfg, self.weights)
            left, right = maybe_flip(left, right, self.rng, self.cfg)
            changed = appearance(left, right, self.rng, self.cfg)
            for slot, view in zip(views, (left, right, *changed), strict=True):
                slot.append(view.astype(np.float32))
        self.batches += 1
        stacked = [torch.from_numpy(np.stack(v)[:, None]) for v in views]
        return stacked[0], stacked[1], stacked[2], stacked[3]

    def state_dict(self) -> dict[str, Any]:
        return {"rng": self.rng.bit_generator.state, "batches": self.batches}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.rng.bit_generator.state = state["rng"]
        self.batches = int(state["batches"])

    def reseed(self, seed: int | list[int]) -> None:
        """A new crop stream (an inexact continuation: --init-from; a loader worker's own)."""
        self.rng = np.random.default_rng(seed)


class _WorkerStream(torch.utils.data.IterableDataset[tuple[Tensor, Tensor, Tensor, Tensor]]):
    """One endless batch stream per loader worker, each with its own seeded sampler."""

    def __init__(
        self, pairs: list[Pair], cfg: AugmentConfig, seed: int, start: int, batch: int
    ) -> None:
        self.pairs, self.cfg, self.seed, self.start, self.batch = pairs, cfg, seed, start, batch

    def __iter__(self) -> Iterator[tuple[Tensor, Tensor, Tensor, Tensor]]:
        info = torch.utils.data.get_worker_info()
        worker = 0 if info is None else info.id
        cv2.setNumThreads(1)  # one core per worker; the workers are the parallelism
        sampler = CropSampler(self.pairs, self.cfg, seed=0)
        sampler.reseed([self.seed, self.start, worker])
        while True:
            yield sampler.next_batch_with_clean(self.batch)


class ParallelCropSampler:
    """CropSampler's batches from `workers` processes (a GPU leg, where one core cannot cut
    crops as fast as the GPU trains on them). Deterministic for a given worker count, but a
    different stream from CropSampler's; its state is only the batch count, and a restored
    sampler re-seeds from it (not an exact resume, like --init-from)."""

    def __init__(
        self, pairs: list[Pair], cfg: AugmentConfig, seed: int, batch: int, workers: int
    ) -> None:
        if workers < 1:
            raise ValueError(f"data workers {workers} < 1")
        self.pairs, self.cfg, self.seed = pairs, cfg, seed
        self.batch, self.workers = batch, workers
        self.batches = 0
        self._iter: Iterator[tuple[Tensor, Tensor, Tensor, Tensor]] | None = None

    def next_batch_with_clean(self, batch: int) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        if batch != self.batch:
            raise ValueError(f"this sampler cuts batches of {self.batch}, asked for {batch}")
        if self._iter is None:
            stream = _WorkerStream(self.pairs, self.cfg, self.seed, self.batches, self.batch)
            # Spawned, not forked: a fork of a process whose torch / OpenCV thread pools already
            # ran can deadlock in the child (seen in the full test suite).
            loader = torch.utils.data.DataLoader(
                stream,
                batch_size=None,
                num_workers=self.workers,
                prefetch_factor=4,
                multiprocessing_context="spawn",
            )
            self._iter = iter(loader)
        self.batches += 1
        return next(self._iter)

    def state_dict(self) -> dict[str, Any]:
        return {"batches": self.batches, "workers": self.workers}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.batches = int(state["batches"])
        self._iter = None

    def reseed(self, seed: int) -> None:
        self.seed = seed
        self._iter = None


def to_three_channels(view: Tensor) -> Tensor:
    """(B, 1, H, W) -> (B, 3, H, W): grayscale replicated, as the encoder expects."""
    return view.expand(-1, 3, -1, -1)
