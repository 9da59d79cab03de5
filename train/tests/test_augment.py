"""Crops, nuisances, flip+swap, and the training loader's split discipline."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from bino_train import augment
from bino_train.augment import (
    CLEAN,
    AugmentConfig,
    CropSampler,
    ImageStore,
    ParallelCropSampler,
    flip_swap,
    nuisances,
    width_range,
)
from bino_train.pairs import SplitError, load_pairs, training_pairs
from bino_train.synthetic import smooth_texture


def shifted_pair(
    seed: int, height: int, width: int, disparity: int
) -> tuple[np.ndarray, np.ndarray]:
    """left(x) = right(x - d): the right view sees the scene d pixels further right.

    (Written here because synthetic.shifted_pair builds the opposite sign.)"""
    wide = smooth_texture(np.random.default_rng(seed), height, width + disparity)
    return wide[:, :width].copy(), wide[:, disparity : disparity + width].copy()


def _holds_convention(left: np.ndarray, right: np.ndarray, d: int) -> bool:
    """left(x) == right(x - d) wherever x - d is inside the image."""
    return bool(np.array_equal(left[:, d:], right[:, : right.shape[1] - d]))


def test_flip_with_swap_preserves_left_right_disparity_convention() -> None:
    left, right = shifted_pair(seed=3, height=48, width=160, disparity=8)
    assert _holds_convention(left, right, 8)
    flipped_left, flipped_right = flip_swap(left, right)
    assert _holds_convention(flipped_left, flipped_right, 8)
    # A flip without the swap would turn the disparity negative: the check must notice.
    assert not _holds_convention(left[:, ::-1], right[:, ::-1], 8)


def test_nuisance_pipeline_flip_keeps_convention() -> None:
    left, right = shifted_pair(seed=4, height=48, width=160, disparity=12)
    cfg = AugmentConfig(flip_prob=1.0, photometric_prob=0.0, noise_prob=0.0, occlusion_prob=0.0)
    out_left, out_right = nuisances(left, right, np.random.default_rng(0), cfg)
    assert not np.array_equal(out_left, left)
    assert _holds_convention(out_left, out_right, 12)


def test_nuisances_are_independent_per_view_and_stay_in_range() -> None:
    left, right = shifted_pair(seed=5, height=48, width=160, disparity=0)
    assert np.array_equal(left, right)
    cfg = AugmentConfig(flip_prob=0.0, photometric_prob=1.0, noise_prob=0.0, occlusion_prob=0.0)
    out_left, out_right = nuisances(left, right, np.random.default_rng(1), cfg)
    assert not np.allclose(out_left, out_right)  # independent photometric draws
    for view in (out_left, out_right):
        assert view.dtype == np.float32 and 0.0 <= view.min() and view.max() <= 1.0


def test_occlusion_hits_exactly_one_view() -> None:
    left, right = shifted_pair(seed=6, height=48, width=160, disparity=0)
    cfg = AugmentConfig(flip_prob=0.0, photometric_prob=0.0, noise_prob=0.0, occlusion_prob=1.0)
    for seed in range(10):
        out_left, out_right = nuisances(left, right, np.random.default_rng(seed), cfg)
        changed = [not np.array_equal(out_left, left), not np.array_equal(out_right, right)]
        assert sum(changed) == 1


def test_blur_softens_exactly_one_view() -> None:
    left, right = shifted_pair(seed=7, height=48, width=160, disparity=0)
    cfg = AugmentConfig(
        flip_prob=0.0, photometric_prob=0.0, noise_prob=0.0, occlusion_prob=0.0, blur_prob=1.0
    )
    for seed in range(10):
        out = nuisances(left, right, np.random.default_rng(seed), cfg)
        changed = [not np.array_equal(o, v) for o, v in zip(out, (left, right), strict=True)]
        assert sum(changed) == 1
        blurred, original = (out[0], left) if changed[0] else (out[1], right)
        # Defocus lowers the local contrast: horizontal gradients shrink, the mean stays.
        assert np.abs(np.diff(blurred, axis=1)).mean() < np.abs(np.diff(original, axis=1)).mean()
        assert blurred.dtype == np.float32 and abs(blurred.mean() - original.mean()) < 0.01


def test_blur_off_draws_nothing_so_older_runs_resume_exactly() -> None:
    """Without blur the nuisances consume the random stream as they did before blur existed:
    the values below were computed with augment.py as of commit 7bc173f (no blur option)."""
    texture = smooth_texture(np.random.default_rng(8), 48, 160)
    rng = np.random.default_rng(9)
    left, right = nuisances(texture.copy(), texture.copy(), rng, AugmentConfig())
    assert (float(left.sum()), float(right.sum())) == (3805.318359375, 3630.0244140625)
    assert rng.random() == 0.0054420114812837594
    legacy = {k: v for k, v in AugmentConfig().to_dict().items() if not k.startswith("blur")}
    assert AugmentConfig.from_dict(legacy) == AugmentConfig()
    restored = AugmentConfig.from_dict(AugmentConfig(blur_sigma=(1.0, 2.0)).to_dict())
    assert restored.blur_sigma == (1.0, 2.0)


def test_width_range_fits_the_crop_and_never_upsamples(data_dir: Path) -> None:
    cfg = AugmentConfig()
    for pair in training_pairs(data_dir):
        lo, hi = width_range(pair, cfg)
        assert cfg.crop_w <= lo <= hi <= pair.width
        assert round(pair.height * lo / pair.width) >= cfg.crop_h


def test_sampler_batches_shape_range_and_exact_state_restore(data_dir: Path) -> None:
    sampler = CropSampler(training_pairs(data_dir), AugmentConfig(), seed=0)
    left, right = sampler.next_batch(3)
    assert left.shape == right.shape == (3, 1, 48, 160)
    assert left.dtype == torch.float32 and 0.0 <= float(left.min()) and float(left.max()) <= 1.0
    state = sampler.state_dict()
    expected = sampler.next_batch(2)
    other = CropSampler(training_pairs(data_dir), AugmentConfig(), seed=99)
    other.load_state_dict(state)
    again = other.next_batch(2)
    assert torch.equal(expected[0], again[0]) and torch.equal(expected[1], again[1])
    assert other.batches == 2


def test_parallel_sampler_is_deterministic_per_worker_count_and_reseeds(data_dir: Path) -> None:
    pairs, cfg = training_pairs(data_dir), AugmentConfig()

    def first_batches(sampler: ParallelCropSampler, n: int) -> list[torch.Tensor]:
        return [sampler.next_batch_with_clean(4)[2] for _ in range(n)]

    one = first_batches(ParallelCropSampler(pairs, cfg, seed=0, batch=4, workers=2), 3)
    two = first_batches(ParallelCropSampler(pairs, cfg, seed=0, batch=4, workers=2), 3)
    assert all(a.shape == (4, 1, 48, 160) for a in one)
    assert all(torch.equal(a, b) for a, b in zip(one, two, strict=True))
    # The two workers cut different crops, and a new seed gives a new stream.
    assert not torch.equal(one[0], one[1])
    reseeded = ParallelCropSampler(pairs, cfg, seed=0, batch=4, workers=2)
    reseeded.reseed(7)
    assert not torch.equal(first_batches(reseeded, 1)[0], one[0])
    with pytest.raises(ValueError, match="batches of 4"):
        ParallelCropSampler(pairs, cfg, seed=0, batch=4, workers=1).next_batch_with_clean(5)
    with pytest.raises(ValueError, match="workers 0"):
        ParallelCropSampler(pairs, cfg, seed=0, batch=4, workers=0)


def test_training_loader_never_reads_eval_images(
    data_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    read: list[Path] = []
    original = augment.load_gray_u8

    def spy(path: Path) -> np.ndarray:
        read.append(path)
        return original(path)

    monkeypatch.setattr(augment, "load_gray_u8", spy)
    sampler = CropSampler(training_pairs(data_dir), AugmentConfig(), seed=0)
    for _ in range(20):
        sampler.next_batch(4)
    train_files = {p for pair in training_pairs(data_dir) for p in (pair.left, pair.right)}
    eval_files = {p for pair in load_pairs(data_dir, "eval") for p in (pair.left, pair.right)}
    assert read and set(read) <= train_files
    assert not set(read) & eval_files
    assert len(set(read)) == len(train_files)  # every train image gets used


def test_loader_refuses_eval_pairs(data_dir: Path) -> None:
    with pytest.raises(SplitError):
        CropSampler(load_pairs(data_dir), CLEAN, seed=0)
    with pytest.raises(SplitError):
        ImageStore(load_pairs(data_dir, "eval"), cache_mb=1)


def test_image_cache_respects_its_budget(data_dir: Path) -> None:
    store = ImageStore(training_pairs(data_dir), cache_mb=0)
    a = store.resized(0, 0, 160)
    b = store.resized(1, 0, 168)
    assert len(store._resized) == 1  # only the newest survives a zero budget
    assert np.array_equal(store.resized(0, 0, 160), a) and b.shape[1] == 168
