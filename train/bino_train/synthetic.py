"""Procedural stereo pairs with known disparity, for fixtures and tests (no data files needed)."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray


def smooth_texture(rng: np.random.Generator, height: int, width: int) -> NDArray[np.float32]:
    """Multi-scale value noise in [0, 1]: enough structure at every scale for matching."""
    out = np.zeros((height, width), dtype=np.float64)
    for cell, weight in ((16, 0.45), (6, 0.3), (2, 0.25)):
        gh, gw = height // cell + 2, width // cell + 2
        grid = rng.random((gh, gw))
        ys = np.arange(height) / cell
        xs = np.arange(width) / cell
        y0, x0 = ys.astype(int), xs.astype(int)
        fy, fx = (ys - y0)[:, None], (xs - x0)[None, :]
        g00 = grid[y0][:, x0]
        g01 = grid[y0][:, x0 + 1]
        g10 = grid[y0 + 1][:, x0]
        g11 = grid[y0 + 1][:, x0 + 1]
        top = g00 * (1 - fx) + g01 * fx
        bottom = g10 * (1 - fx) + g11 * fx
        out += weight * (top * (1 - fy) + bottom * fy)
    return out.astype(np.float32)


def high_pass(image: NDArray[np.float32]) -> NDArray[np.float32]:
    """The image minus its Gaussian blur of 1.5 px: the micro-texture `flat_texture` measures."""
    return np.asarray(image - cv2.GaussianBlur(image, (0, 0), 1.5), dtype=np.float32)


def fine_grain(rng: np.random.Generator, h: int, w: int) -> NDArray[np.float32]:
    """Gaussian noise softened by a 0.7 px blur (a lens), scaled to unit rms of its high-pass."""
    noise = rng.normal(size=(h, w)).astype(np.float32)
    raw = np.asarray(cv2.GaussianBlur(noise, (0, 0), 0.7), dtype=np.float32)
    return np.asarray(raw / max(float(np.sqrt(np.mean(high_pass(raw) ** 2))), 1e-6), np.float32)


def shifted_pair(
    seed: int, height: int, width: int, disparity: int
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """A grayscale pair (H, W) with left(x, y) == right(x - disparity, y) everywhere."""
    rng = np.random.default_rng(seed)
    wide = smooth_texture(rng, height, width + disparity)
    # right(x) = wide(x + d) and left(x) = wide(x), so left(x) == right(x - d).
    left = wide[:, :width]
    right = wide[:, disparity:]
    return np.ascontiguousarray(left), np.ascontiguousarray(right)


def to_view_tensor(gray: NDArray[np.float32]) -> NDArray[np.float32]:
    """(H, W) grayscale -> (1, 3, H, W), the channel replicated as the model expects."""
    return np.ascontiguousarray(np.broadcast_to(gray, (1, 3, *gray.shape)), dtype=np.float32)
