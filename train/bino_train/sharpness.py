"""Sharpness equalisation of the two views before the pixel refinement (issue 14), in integers.

The refinement's census compares the views pixel by pixel. When one view is defocused (one-view
blur, the nuisance every readout loses most to), the census codes of the sharp view no longer
match the blurred one and the refinement's gain vanishes: on the 22 held-out validation pairs
at 160 px the refined head+lr readout goes from 0.491 epe clean to 0.892 under a 5x5 box blur of
the right view, no better than the unrefined 0.889. Blurring the sharper view to the other's
sharpness before the census restores most of it, and leaves a clean pair untouched (both views
are equally sharp, so nothing is blurred).

The rules, per block of `BAND_ROWS` view rows (the last block may be shorter), so that a
streaming pipeline can decide each band when its rows have arrived:

1. `box(v, k)`: the mean of the `(2k + 1)^2` window around each pixel, coordinates clamped to
   the image (edge replicate), rounded half up: `(sum + n // 2) // n`, `n = (2k + 1)^2`;
   `box(v, 0) = v`.
2. `sharpness(v, rows)`: the sum over those rows of `|s(y, x + 1) - s(y, x)|`, `s = box(v, 1)`
   (the 3x3 mean first keeps sensor noise from reading as sharpness).
3. With `SL`, `SR` the two views' sharpness over the block: the sharper view is the left when
   `SL >= SR`, else the right; the other's sharpness is the target. For `k` in
   `0..=MAX_RADIUS` the candidate is `box(sharper, k)`, scored `|sharpness(candidate) -
   target|`; the lowest wins, ties to the smaller `k`.
4. The block's rows of the sharper view become those of `box(sharper, k)` (its vertical window
   reads the original rows above and below the block); the other view is unchanged.

    python -m bino_train.refine_val ... --nuisance blur --equalise
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

BAND_ROWS = 48
"""Rows decided together: the pipeline's band height."""

MAX_RADIUS = 2
"""Largest box radius tried (5x5)."""


class Decision(NamedTuple):
    """One block's choice: its first row, which view is blurred (0 left, 1 right), the radius."""

    row: int
    view: int
    radius: int


def box(view: NDArray[np.uint8], radius: int) -> NDArray[np.uint8]:
    """The `(2 radius + 1)^2` mean, edge replicate, rounded half up (rule 1)."""
    if radius == 0:
        return view.copy()
    padded = np.pad(view.astype(np.int64), radius, mode="edge")
    h, w = view.shape
    total = np.zeros((h, w), dtype=np.int64)
    for dy in range(2 * radius + 1):
        for dx in range(2 * radius + 1):
            total += padded[dy : dy + h, dx : dx + w]
    n = (2 * radius + 1) ** 2
    return ((total + n // 2) // n).astype(np.uint8)


def sharpness_rows(view: NDArray[np.uint8]) -> NDArray[np.int64]:
    """Per row, the sum of `|s(y, x + 1) - s(y, x)|` with `s = box(view, 1)` (rule 2)."""
    smooth = box(view, 1).astype(np.int64)
    return np.abs(np.diff(smooth, axis=1)).sum(axis=1)


def decide(left: NDArray[np.uint8], right: NDArray[np.uint8]) -> list[Decision]:
    """Each block's sharper view and radius (rule 3)."""
    if left.shape != right.shape or left.ndim != 2:
        raise ValueError(f"views must be equal 2-D arrays, got {left.shape} and {right.shape}")
    rows_l, rows_r = sharpness_rows(left), sharpness_rows(right)
    blurred = {
        (v, k): sharpness_rows(box(view, k))
        for v, view in enumerate((left, right))
        for k in range(1, MAX_RADIUS + 1)
    }
    decisions = []
    for y0 in range(0, left.shape[0], BAND_ROWS):
        rows = slice(y0, y0 + BAND_ROWS)
        sl, sr = int(rows_l[rows].sum()), int(rows_r[rows].sum())
        view, own, target = (0, sl, sr) if sl >= sr else (1, sr, sl)
        scores = [abs(own - target)]
        scores += [
            abs(int(blurred[view, k][rows].sum()) - target) for k in range(1, MAX_RADIUS + 1)
        ]
        decisions.append(Decision(y0, view, int(np.argmin(scores))))
    return decisions


def equalise(
    left: NDArray[np.uint8], right: NDArray[np.uint8]
) -> tuple[NDArray[np.uint8], NDArray[np.uint8], list[Decision]]:
    """The two views with each block's sharper view blurred to the other's sharpness (rule 4)."""
    out = [left.copy(), right.copy()]
    decisions = decide(left, right)
    for d in decisions:
        if d.radius > 0:
            source = (left, right)[d.view]
            out[d.view][d.row : d.row + BAND_ROWS] = box(source, d.radius)[
                d.row : d.row + BAND_ROWS
            ]
    return out[0], out[1], decisions
