"""EVAL.md resolution profiles: the image and ground-truth sizes every score is computed at.

Images: area resize to width P, height round(H * P / W) (half up), then the bottom rows are
dropped down to a multiple of 4. Ground truth: nearest-neighbour resize at pixel centres
(OpenCV `INTER_NEAREST_EXACT`: source index floor((dst + 0.5) * W / P)) to the same size,
disparity times P / W. Pixel-centre sampling is what reproduces the EVAL.md SGBM table
(0.869 / 5.67 / 10.39 / 78.7); OpenCV's plain `INTER_NEAREST` (floor(dst * W / P)) gives
0.866 / 5.66 / 10.36.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

PROFILES = {"w160": 160, "w320": 320}


def profile_width(profile: str) -> int:
    if profile not in PROFILES:
        raise ValueError(f"unknown profile {profile!r}; known: {sorted(PROFILES)}")
    return PROFILES[profile]


def resized_height(width: int, height: int, target_width: int) -> int:
    """round(H * P / W), half up (as Rust's f64::round for positive values)."""
    return int(math.floor(height * target_width / width + 0.5))


def profile_size(width: int, height: int, target_width: int) -> tuple[int, int]:
    """(width, height) at the profile, the height already cut to a multiple of 4."""
    h = resized_height(width, height, target_width)
    return target_width, h - h % 4


def to_u8(image: NDArray[np.float32]) -> NDArray[np.uint8]:
    """A [0, 1] view as the 8-bit image OpenCV's StereoSGBM and the Rust side read."""
    return np.clip(np.rint(image * 255.0), 0, 255).astype(np.uint8)


def resize_image(image: NDArray[np.float32], target_width: int) -> NDArray[np.float32]:
    """Area-resize a (H, W) image to the profile and drop the bottom rows to a multiple of 4."""
    h, w = image.shape[:2]
    out_w, out_h = profile_size(w, h, target_width)
    full_h = resized_height(w, h, target_width)
    resized = cv2.resize(image, (out_w, full_h), interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(resized[:out_h])


def resize_gt(
    disparity: NDArray[np.float32], valid: NDArray[np.bool_], target_width: int
) -> tuple[NDArray[np.float32], NDArray[np.bool_]]:
    """Nearest-neighbour resize of disparity and validity; disparity scaled by P / W."""
    h, w = disparity.shape
    out_w, out_h = profile_size(w, h, target_width)
    full_h = resized_height(w, h, target_width)
    size = (out_w, full_h)
    disp = cv2.resize(disparity, size, interpolation=cv2.INTER_NEAREST_EXACT)[:out_h]
    mask = cv2.resize(valid.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST_EXACT)[:out_h]
    scaled = disp.astype(np.float32) * np.float32(target_width / w)
    return np.ascontiguousarray(scaled), np.ascontiguousarray(mask.astype(bool))
