"""Synthetic training crops with exact disparity, generated at scale (issue 40).

`layered_sample(rng, cfg)` renders a crop_h x crop_w pair of several surfaces, far to near:
- a background plane, slanted in x and y, at any disparity of the candidate range;
- one to four nearer surfaces, each slanted too, shaped as rectangles, ellipses or thin
  structures (bars 1-5 px wide, tilted, alone or as a fence), so their edges make occlusion
  boundaries in both directions;
- surfaces textured with value noise at a random contrast, textureless (a flat grey with gentle
  shading and a grain: by default under a grey level, so only their edges can be matched, as the
  shipped heads were trained; `DataConfig.flat_grain_levels` gives them the fine grain real flat
  surfaces carry, `synth_folder.FLAT_GRAIN_LEVELS`) or repetitive (stripes
  of 4-16 px period, where a local match is ambiguous);
disparities over the whole range 0 .. 4 (max_disp - 1) px (60 px for 16 candidates: the w320
profile's range). The views then get the head's nuisances (head_data.HEAD_AUGMENT or the run's:
independent photometric changes and noise, one-view blur), which leave the geometry alone.

Geometry (sign convention of head_data: left(x, y) = right(x - d, y), d >= 0). A surface has the
planar left-view disparity d(x, y) = a + bx (x - cx) + by (y - cy) and a texture in right-view
coordinates shifted by `margin`: left pixel x shows T(x - d(x) + margin), right pixel x' shows
T(x' + margin) where the surface covers the left point x with x - d(x) = x', i.e.
x = (x' + a - bx cx + by (y - cy)) / (1 - bx). Shapes are drawn on a canvas `margin` px wider
than the view, so a surface that leaves the left view on the right still covers the right view
where it should. The ground truth is the left view's disparity at every pixel (occluded pixels
included, as Middlebury's), labels by head_data.cell_labels.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import cv2
import numpy as np
from numpy.typing import NDArray

from .augment import nuisances
from .synthetic import fine_grain, smooth_texture

if TYPE_CHECKING:
    from .head_data import DataConfig, Sample

Gray = NDArray[np.float32]
Mask = NDArray[np.bool_]

CELL = 4
MAX_SLANT = 0.06
"""Largest |bx| of a surface (px of disparity per px); |by| is up to twice that."""


def noise_texture(rng: np.random.Generator, h: int, w: int) -> Gray:
    """Value noise at a random contrast (down to weak texture), sometimes with hard blobs."""
    tex = smooth_texture(rng, h, w)
    if rng.random() < 0.4:
        for _ in range(int(rng.integers(2, 10))):
            y, x = int(rng.integers(0, h)), int(rng.integers(0, w))
            ry, rx = int(rng.integers(2, 12)), int(rng.integers(2, 24))
            tex[max(0, y - ry) : y + ry, max(0, x - rx) : x + rx] = rng.random()
    contrast = math.exp(rng.uniform(math.log(0.1), 0.0))
    return np.clip(0.5 + (tex - tex.mean()) * contrast * 1.6, 0.0, 1.0).astype(np.float32)


def flat_texture(rng: np.random.Generator, h: int, w: int, grain_levels: float = 0.0) -> Gray:
    """A flat grey with a gentle linear shading and a grain: `grain_levels` grey levels rms of
    fine grain (`synthetic.fine_grain`, what real flat surfaces carry), or with 0 a faint one
    under a grey level (the shipped heads' training data)."""
    level = rng.uniform(0.1, 0.9)
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    shade = rng.uniform(-0.1, 0.1) * xs / w + rng.uniform(-0.1, 0.1) * ys / h
    if grain_levels > 0.0:
        grain = fine_grain(rng, h, w) * np.float32(grain_levels / 255.0)
    else:
        grain = (smooth_texture(rng, h, w) - 0.5) * 0.004
    return np.clip(level + shade + grain, 0.0, 1.0).astype(np.float32)


def stripe_texture(rng: np.random.Generator, h: int, w: int) -> Gray:
    """Repetitive stripes (period 4-16 px, slightly tilted) over weak noise."""
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    period = rng.uniform(4.0, 16.0)
    tilt = rng.uniform(-0.3, 0.3)
    phase = rng.uniform(0.0, 2 * math.pi)
    wave = np.sin(2 * math.pi * (xs + tilt * ys) / period + phase)
    if rng.random() < 0.5:
        wave = np.sign(wave)
    amp = rng.uniform(0.1, 0.4)
    grain = (smooth_texture(rng, h, w) - 0.5) * 0.1
    level = rng.uniform(0.3, 0.7)
    return np.clip(level + amp * wave + grain, 0.0, 1.0).astype(np.float32)


def random_texture(
    rng: np.random.Generator, h: int, w: int, flat_share: float, grain_levels: float = 0.0
) -> Gray:
    draw = rng.random()
    if draw < flat_share:
        return flat_texture(rng, h, w, grain_levels)
    if draw < flat_share + 0.08:
        return stripe_texture(rng, h, w)
    return noise_texture(rng, h, w)


def shape_mask(rng: np.random.Generator, h: int, cw: int, w: int) -> Mask:
    """A shape on the (h, cw) canvas, mostly over the view's [0, w) columns: a rectangle, an
    ellipse, one thin bar or a fence of bars."""
    canvas = np.zeros((h, cw), np.uint8)
    kind = rng.random()
    if kind < 0.3:
        rh, rw = int(rng.integers(h // 4, h + 1)), int(rng.integers(w // 12, w // 2))
        y0, x0 = int(rng.integers(-h // 4, h - rh // 2)), int(rng.integers(-rw // 2, w))
        canvas[max(0, y0) : max(0, y0 + rh), max(0, x0) : max(0, x0 + rw)] = 1
    elif kind < 0.55:
        ry, rx = rng.uniform(h / 6, h / 1.5), rng.uniform(w / 20, w / 4)
        cy, cx = rng.uniform(0, h), rng.uniform(0, w)
        ys, xs = np.mgrid[0:h, 0:cw].astype(np.float32)
        canvas[((ys + 0.5 - cy) / ry) ** 2 + ((xs + 0.5 - cx) / rx) ** 2 <= 1.0] = 1
    else:
        bars = 1 if kind < 0.8 else int(rng.integers(2, 6))
        gap = rng.uniform(6.0, 24.0)
        x = rng.uniform(0, w)
        lean = rng.uniform(-0.5, 0.5)
        for b in range(bars):
            thick = int(rng.integers(1, 6))
            xb = x + b * gap
            top = (int(round(xb * 16)), int(round(rng.uniform(-h, h / 3) * 16)))
            bottom = (
                int(round((xb + lean * h) * 16)),
                int(round(rng.uniform(2 * h / 3, 2 * h) * 16)),
            )
            cv2.line(canvas, top, bottom, 1, thickness=thick, lineType=cv2.LINE_8, shift=4)
        if rng.random() < 0.3:  # a cross bar, as a chair rail or a fence's
            y = int(rng.integers(0, h))
            t = int(rng.integers(1, 6))
            x0 = int(max(0, x - 4))
            canvas[y : y + t, x0 : int(min(cw, x + (bars - 1) * gap + 4))] = 1
    return canvas.astype(bool)


def sample_x(texture: Gray, x: Gray) -> Gray:
    """texture[y, x[y, col]], bilinear along x; outside the texture: its border."""
    ys = np.broadcast_to(np.arange(x.shape[0], dtype=np.float32)[:, None], x.shape)
    out = cv2.remap(
        texture,
        np.ascontiguousarray(x, dtype=np.float32),
        np.ascontiguousarray(ys),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    return np.asarray(out, dtype=np.float32)


def plane(
    rng: np.random.Generator, h: int, w: int, lo: float, hi: float, slant: float
) -> tuple[float, float, float]:
    """(a, bx, by) of a plane whose disparity over the view stays within [lo, hi]."""
    bx = float(rng.uniform(-slant, slant)) if rng.random() < 0.7 else 0.0
    by = float(rng.uniform(-2 * slant, 2 * slant)) if rng.random() < 0.5 else 0.0
    spread = abs(bx) * w / 2 + abs(by) * h / 2
    if hi - lo < 2 * spread:  # too slanted for the room left: flatten
        shrink = (hi - lo) / (2 * spread) if spread > 0 else 0.0
        bx, by, spread = bx * shrink, by * shrink, spread * shrink
    a = float(rng.uniform(lo + spread, hi - spread)) if hi - spread > lo + spread else lo + spread
    return a, bx, by


def render_layers(
    layers: list[tuple[tuple[float, float, float], Mask, Gray]], h: int, w: int, margin: int
) -> tuple[Gray, Gray, Gray]:
    """(left, right, left disparity) of surfaces given far to near as ((a, bx, by), canvas mask
    (h, w + margin), texture (h, w + 2 margin))."""
    cx, cy = w / 2.0, h / 2.0
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32)
    left, right = np.zeros((h, w), np.float32), np.zeros((h, w), np.float32)
    disparity = np.zeros((h, w), np.float32)
    for (a, bx, by), mask, texture in layers:
        d = (a + bx * (xs - cx) + by * (ys - cy)).astype(np.float32)
        inside = mask[:, :w]
        left = np.where(inside, sample_x(texture, xs - d + margin), left)
        disparity = np.where(inside, d, disparity)
        # The left point that right pixel x' sees on this surface, and whether it is covered.
        x_left = (xs + a - bx * cx + by * (ys - cy)) / (1.0 - bx)
        covered = sample_x(mask.astype(np.float32), x_left) >= 0.5
        right = np.where(covered, sample_x(texture, xs + margin), right)
    return left, right, disparity


def layered_scene(
    rng: np.random.Generator, h: int, w: int, max_px: float, grain_levels: float = 0.0
) -> tuple[Gray, Gray, Gray]:
    """(left, right, left disparity px) of a random layered scene, disparities in [0, max_px];
    textureless surfaces with `grain_levels` of grain (`flat_texture`)."""
    margin = int(math.ceil(max_px)) + 4
    cw, tw = w + margin, w + 2 * margin
    # The background anywhere in the range; sometimes near the top (large disparities).
    top = max_px if rng.random() < 0.25 else rng.uniform(0.3, 1.0) * max_px
    background = plane(rng, h, w, 0.0, top, MAX_SLANT)
    flat_share = 0.35
    layers = [
        (background, np.ones((h, cw), bool), random_texture(rng, h, tw, flat_share, grain_levels))
    ]
    floor = background[0] + abs(background[1]) * w / 2 + abs(background[2]) * h / 2
    count = int(rng.integers(0, 5)) if floor < max_px - 3.0 else 0
    levels = sorted(rng.uniform(floor + 2.0, max_px, size=count)) if count else []
    for level in levels:
        geometry = plane(rng, h, w, level - 1.0, min(max_px, level + 3.0), MAX_SLANT / 2)
        mask = shape_mask(rng, h, cw, w)
        layers.append((geometry, mask, random_texture(rng, h, tw, flat_share, grain_levels)))
    left, right, disparity = render_layers(layers, h, w, margin)
    return left, right, np.clip(disparity, 0.0, max_px).astype(np.float32)


def layered_sample(rng: np.random.Generator, cfg: DataConfig) -> Sample:
    """A layered scene as a head training sample (labels in patch columns, NaN where a cell
    straddles a depth edge), with the config's nuisances."""
    from .head_data import Sample, cell_labels

    max_px = float(CELL * (cfg.max_disp - 1))
    left, right, disparity = layered_scene(
        rng, cfg.crop_h, cfg.crop_w, max_px, cfg.flat_grain_levels
    )
    valid = np.ones_like(disparity, dtype=bool)
    label = cell_labels(disparity, valid, cfg.min_valid, cfg.max_spread)
    clean = (left, right)
    left, right = nuisances(left, right, rng, cfg.augment)
    return Sample(left, right, label, synthetic=True, clean=clean)
