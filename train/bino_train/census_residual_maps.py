"""Per-pixel inputs of the census residual net (census_residual.py), at the profile width.

`census_maps` runs the census SGM of one view pair exactly as `census_selector` does (the core's
penalties and uniqueness, `census_selector_cells.census_cells`; rejected cells filled from the
left; the pixel refinement `census_companion.refined`) and stacks, per pixel:
- the census disparity before the refinement (`up`: the filled cell grid, bilinear) and after it
  (`ref`: census+lr+ref, the baseline), over the census's pixel range, and their difference;
- around the ANCHOR (the map the net adds its residual to: `ref` or `up`), at the integer
  disparities round(anchor) + k, k = -`WINDOW` .. `WINDOW`: the raw census Hamming distance of
  the pixel (/ 24), the refinement's 9x9 box sums of it (/ 81 x 24) and the cell's aggregated SGM
  cost (minus the cell's lowest, over the cell's mean minus its lowest); the anchor's fraction;
- the census's flags per cell (kept, left-right, unique), its uniqueness margin and its
  runner-up (its best candidate more than one column from the winner, `CensusCells.runner_up`:
  `census_rerank`'s oracle found much of what the winner misses there) minus the anchor;
- the left view, the right view warped by the anchor (`photometric.warp_right`) and their
  absolute difference;
- with the native head's logits (the encoder variant): its softmax over its candidates and its
  soft-argmin disparity minus the anchor (px / 8), bilinear to pixels, and its left-right check.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from numpy.typing import NDArray

from .census_companion import box_sums, cell_costs, pixel_hamming, refine_search, refined
from .census_selector_cells import CENSUS_PENALTIES, CensusCells, Pixels, census_cells
from .head_eval import consistent, diagonal_right, fill_rejected
from .photometric import warp_right
from .readout_variants import sgm_aggregate
from .refine import CELL, RefineParams, upsample_float

Features = NDArray[np.float32]

WINDOW = 2
"""Cost samples at round(anchor) - WINDOW ..= round(anchor) + WINDOW."""
OFFSETS = tuple(range(-WINDOW, WINDOW + 1))
MAX_HAMMING = 24.0
"""5x5 census: 24 bits."""
ANCHORS = ("ref", "up")
HEAD_DELTA_PX = 8.0
"""The head's and the runner-up's disparity minus the anchor are fed in units of this many px,
clipped to +-4."""


def channel_names(anchor: str, head_candidates: int = 0) -> list[str]:
    """The feature channels `census_maps` stacks, in order."""
    names = ["anchor/n", "ref/n", "(ref-up)/4", "frac"]
    for kind in ("ham", "box", "agg"):
        names += [f"{kind}{k:+d}" for k in OFFSETS]
    names += ["kept", "lr", "unique", "margin", "(runner-anchor)/8"]
    names += ["left", "warped", "|left-warped|"]
    if head_candidates:
        names += [f"head_p{i}" for i in range(head_candidates)]
        names += ["(head-anchor)/8", "head_kept"]
    return names


@dataclass(frozen=True)
class CensusMaps:
    """What the net reads of one pair and what its output is added to."""

    features: Features
    """(C, H, W) in `channel_names` order."""
    anchor: Pixels
    """The map the residual is added to (px)."""
    refined: Pixels
    """census+lr+ref (px): the baseline."""
    census: CensusCells


def cells_to_pixels(cells: NDArray[np.generic], h: int, w: int) -> NDArray[np.generic]:
    """Nearest (each 4x4 cell's value on its pixels)."""
    rows = np.minimum(np.arange(h) // CELL, cells.shape[0] - 1)
    cols = np.minimum(np.arange(w) // CELL, cells.shape[1] - 1)
    return cells[rows][:, cols]


def sample_volume(volume: NDArray[np.float64], index: NDArray[np.int64]) -> NDArray[np.float64]:
    """volume[y, x, index[y, x]] of an (H, W, N) volume, the index clamped to [0, N)."""
    n = volume.shape[-1]
    return np.take_along_axis(volume, np.clip(index, 0, n - 1)[..., None], -1)[..., 0]


def aggregate_pixels(aggregate: NDArray[np.float64], h: int, w: int) -> NDArray[np.float64]:
    """The (T, P, N) SGM aggregate normalised per cell ((cost - lowest) / (mean - lowest)) on
    each pixel of its cell: (H, W, N)."""
    low = aggregate.min(axis=-1, keepdims=True)
    spread = np.maximum(aggregate.mean(axis=-1, keepdims=True) - low, 1.0)
    return np.asarray(cells_to_pixels((aggregate - low) / spread, h, w))


def head_channels(logits: NDArray[np.float64], anchor: Pixels) -> list[NDArray[np.float32]]:
    """The head's softmax (D channels), its disparity minus the anchor and its left-right check,
    on pixels."""
    h, w = anchor.shape
    z = torch.from_numpy(logits).float()[None]
    prob = torch.softmax(z, dim=1)
    up = F.interpolate(prob, size=(h, w), mode="bilinear", align_corners=False)[0].numpy()
    cands = np.arange(logits.shape[0], dtype=np.float64)[:, None, None]
    p = prob[0].double().numpy()
    disparity = (p * cands).sum(axis=0)
    kept = consistent(disparity, diagonal_right(logits))
    delta = (upsample_float(disparity, h, w) - anchor) / HEAD_DELTA_PX
    return [
        *up.astype(np.float32),
        np.clip(delta, -4.0, 4.0).astype(np.float32),
        np.asarray(cells_to_pixels(kept, h, w), dtype=np.float32),
    ]


def census_maps(
    left: NDArray[np.uint8],
    right: NDArray[np.uint8],
    disparities: int,
    anchor: str = "ref",
    logits: NDArray[np.float64] | None = None,
) -> CensusMaps:
    """The census readout of a (H, W) view pair (H, W multiples of 4) searching `disparities`
    pixel disparities, and the residual net's input channels around `anchor` ("ref" or "up")."""
    if anchor not in ANCHORS:
        raise ValueError(f"unknown anchor {anchor!r}; known: {ANCHORS}")
    h, w = left.shape
    if h % CELL or w % CELL:
        raise ValueError(f"view size {left.shape} is not a multiple of {CELL}")
    rows, cols = h // CELL, w // CELL
    hamming = pixel_hamming(left, right, disparities, False)
    cc = census_cells(hamming, rows, cols)
    aggregate = sgm_aggregate(cell_costs(hamming, rows, cols), *CENSUS_PENALTIES)
    clamped = pixel_hamming(left, right, disparities + 8, True)
    radius = RefineParams().box_radius
    boxed = box_sums(clamped, radius)
    grid = fill_rejected(cc.disparity, cc.kept)
    up = upsample_float(grid, h, w)
    ref = refined(boxed, grid, cc.kept, refine_search(w)).astype(np.float64)
    base = ref if anchor == "ref" else up
    centre = np.floor(base + 0.5).astype(np.int64)
    agg = aggregate_pixels(aggregate, h, w)
    box_norm = (2 * radius + 1) ** 2 * MAX_HAMMING
    chans: list[NDArray[np.float64] | NDArray[np.float32]] = [
        base / disparities,
        ref / disparities,
        (ref - up) / CELL,
        base - centre,
    ]
    chans += [sample_volume(clamped, centre + k) / MAX_HAMMING for k in OFFSETS]
    chans += [sample_volume(boxed, centre + k) / box_norm for k in OFFSETS]
    chans += [np.minimum(sample_volume(agg, centre + k), 4.0) for k in OFFSETS]
    for cell_map in (cc.kept, cc.lr, cc.unique, cc.margin):
        chans.append(np.asarray(cells_to_pixels(cell_map, h, w), dtype=np.float64))
    runner = np.asarray(cells_to_pixels(cc.runner_up * CELL, h, w), dtype=np.float64)
    chans.append(np.clip((runner - base) / HEAD_DELTA_PX, -4.0, 4.0))
    lf = left.astype(np.float32) / np.float32(255.0)
    rf = right.astype(np.float32) / np.float32(255.0)
    warped, _ = warp_right(torch.from_numpy(rf)[None], torch.from_numpy(base).float()[None])
    wf = warped[0].numpy()
    chans += [lf, wf, np.abs(lf - wf)]
    if logits is not None:
        chans += head_channels(logits, base.astype(np.float32))
    features = np.stack([np.asarray(c, dtype=np.float32) for c in chans])
    return CensusMaps(features, base.astype(np.float32), ref.astype(np.float32), cc)
