"""Pair index, split guard, grayscale rule, ground truth and EVAL.md profiles."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from bino_train.pairs import (
    DEFAULT_DATA_DIR,
    SplitError,
    check_training_pairs,
    load_gray,
    load_gt,
    load_pairs,
    training_pairs,
)
from bino_train.profile import profile_size, resize_gt, resize_image


def test_default_data_dir_is_shared_data_beside_the_repository() -> None:
    repo_root = Path(__file__).resolve().parents[2]
    assert DEFAULT_DATA_DIR == repo_root.parent / "shared" / "data"


def test_load_pairs_resolves_paths_and_filters_splits(data_dir: Path) -> None:
    everything = load_pairs(data_dir)
    assert [p.pair_id for p in everything] == ["t0", "t1", "t2", "t3", "e0", "e1"]
    evals = load_pairs(data_dir, "eval")
    assert [p.pair_id for p in evals] == ["e0", "e1"]
    assert evals[0].left.is_file() and evals[0].gt is not None and evals[0].gt.is_file()
    assert evals[0].gt_scale == 4.0 and evals[0].gt_invalid == 0
    assert all(p.gt is None for p in load_pairs(data_dir, "train"))


def test_training_code_can_only_get_train_pairs(data_dir: Path) -> None:
    assert {p.split for p in training_pairs(data_dir)} == {"train"}
    with pytest.raises(SplitError):
        load_pairs(data_dir, "eval", for_training=True)
    with pytest.raises(SplitError):
        load_pairs(data_dir, None, for_training=True)
    with pytest.raises(SplitError):
        check_training_pairs(load_pairs(data_dir))


def test_colour_images_become_gray_by_opencv_bgr2gray_on_uint8(data_dir: Path) -> None:
    pair = load_pairs(data_dir, "eval")[0]
    bgr = cv2.imread(str(pair.left), cv2.IMREAD_COLOR)
    expected = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY).astype(np.float32) / 255.0
    gray = load_gray(pair.left)
    assert gray.dtype == np.float32 and gray.shape == (pair.height, pair.width)
    assert np.array_equal(gray, expected)


def test_ground_truth_is_scaled_and_invalid_values_masked(data_dir: Path) -> None:
    pair = load_pairs(data_dir, "eval")[1]
    stored = cv2.imread(str(pair.gt), cv2.IMREAD_UNCHANGED)
    disparity, valid = load_gt(pair)
    assert np.array_equal(valid, stored != 0)
    assert np.allclose(disparity, stored / 4.0)


def test_profile_size_rounds_height_then_cuts_to_multiple_of_four() -> None:
    assert profile_size(450, 375, 160) == (160, 132)  # 133.33 -> 133 -> 132
    assert profile_size(284, 216, 160) == (160, 120)  # 121.69 -> 122 -> 120
    assert profile_size(1344, 372, 320) == (320, 88)  # 88.57 -> 89 -> 88
    assert profile_size(320, 2, 160) == (160, 0)


def test_profile_resizes_image_and_ground_truth_consistently() -> None:
    image = np.random.default_rng(0).random((375, 450), dtype=np.float32)
    out = resize_image(image, 160)
    assert out.shape == (132, 160)
    # Area averaging keeps the mean of a smooth field.
    assert abs(float(out.mean()) - float(image[: 132 * 375 // 133].mean())) < 0.01
    disparity = np.tile(np.arange(450, dtype=np.float32), (375, 1))
    valid = disparity % 2 == 0
    gt, gt_valid = resize_gt(disparity, valid, 160)
    assert gt.shape == gt_valid.shape == (132, 160)
    # Nearest neighbour at pixel centres: source column floor((x + 0.5) * 450 / 160).
    src = np.floor((np.arange(160) + 0.5) * 450 / 160).astype(int)
    assert np.allclose(gt[5], src * 160 / 450)
    assert np.array_equal(gt_valid[5], src % 2 == 0)
