"""Self-supervised stereo terms: the right view warped by the predicted disparity.

The standard way to learn stereo without ground truth (Monodepth / Godard et al. 2017): the
token-grid disparity is upsampled to pixels exactly as EVAL.md does (bilinear, half-pixel
centres, x 4 px per patch column), the right crop is sampled at x - d, and the left crop is
compared with it by 0.85 SSIM (3 x 3) + 0.15 L1, over pixels whose source lies inside the
right crop. An edge-aware smoothness term (disparity gradients damped where the left image has
edges, on the mean-normalised disparity) fills textureless regions.

Both terms compare the clean crops (before the view-specific nuisances the head sees).
"""

from __future__ import annotations

from typing import NamedTuple

import torch
import torch.nn.functional as F
from torch import Tensor

CELL = 4
SSIM_SHARE = 0.85


def pixel_disparity(cols: Tensor) -> Tensor:
    """(B, T, P) patch columns -> (B, 4T, 4P) px, bilinear like cv2.resize INTER_LINEAR."""
    up = F.interpolate(
        cols[:, None] * CELL, scale_factor=CELL, mode="bilinear", align_corners=False
    )
    return up[:, 0]


def warp_right(right: Tensor, disparity: Tensor) -> tuple[Tensor, Tensor]:
    """right(y, x - d(y, x)) by bilinear sampling, and where x - d lies inside the crop.
    right, disparity: (B, H, W) (px)."""
    b, h, w = right.shape
    xs = torch.arange(w, device=right.device, dtype=right.dtype).view(1, 1, w) - disparity
    ys = torch.arange(h, device=right.device, dtype=right.dtype).view(1, h, 1).expand(b, h, w)
    grid = torch.stack([(2.0 * xs + 1.0) / w - 1.0, (2.0 * ys + 1.0) / h - 1.0], dim=-1)
    warped = F.grid_sample(
        right[:, None], grid, mode="bilinear", padding_mode="border", align_corners=False
    )
    return warped[:, 0], xs >= 0


def ssim_distance(x: Tensor, y: Tensor) -> Tensor:
    """(1 - SSIM) / 2 per pixel over 3 x 3 windows (reflection padded), in [0, 1]."""
    c1, c2 = 0.01**2, 0.03**2
    x, y = x[:, None], y[:, None]
    pad = (1, 1, 1, 1)

    def mean(t: Tensor) -> Tensor:
        return F.avg_pool2d(F.pad(t, pad, mode="reflect"), 3, 1)

    mx, my = mean(x), mean(y)
    sx = mean(x * x) - mx * mx
    sy = mean(y * y) - my * my
    sxy = mean(x * y) - mx * my
    num = (2 * mx * my + c1) * (2 * sxy + c2)
    den = (mx * mx + my * my + c1) * (sx + sy + c2)
    return ((1 - num / den) / 2).clamp(0, 1)[:, 0]


def edge_aware_smoothness(disparity: Tensor, image: Tensor) -> Tensor:
    """Mean |grad d| exp(-|grad I|) on the mean-normalised disparity (B, H, W)."""
    d = disparity / (disparity.mean(dim=(1, 2), keepdim=True) + 1e-3)
    dx = (d[:, :, 1:] - d[:, :, :-1]).abs() * torch.exp(-(image[:, :, 1:] - image[:, :, :-1]).abs())
    dy = (d[:, 1:] - d[:, :-1]).abs() * torch.exp(-(image[:, 1:] - image[:, :-1]).abs())
    return dx.mean() + dy.mean()


class PhotometricParts(NamedTuple):
    reconstruction: Tensor
    smoothness: Tensor


def photometric_terms(cols: Tensor, images: Tensor) -> PhotometricParts:
    """cols: (B, T, P) predicted disparity (patch columns); images: (B, 2, 4T, 4P) clean
    (left, right) crops in [0, 1]."""
    left, right = images[:, 0], images[:, 1]
    disparity = pixel_disparity(cols)
    warped, inside = warp_right(right, disparity)
    error = SSIM_SHARE * ssim_distance(left, warped) + (1 - SSIM_SHARE) * (left - warped).abs()
    mask = inside.float()
    reconstruction = (error * mask).sum() / mask.sum().clamp_min(1.0)
    return PhotometricParts(reconstruction, edge_aware_smoothness(disparity, left))
