"""Sharpness equalisation of the two views before the pixel refinement (issue 14), in integers.

The refinement's census compares the views pixel by pixel. When one view is defocused (one-view
blur, the nuisance every readout loses most to), the census codes of the sharp view no longer
match the blurred one and the refinement's gain vanishes: on the 22 held-out validation pairs
at 160 px the refined head+lr readout goes from 0.491 epe clean to 0.892 under a 5x5 box blur of
the right view, no better than the unrefined 0.889. Blurring the sharper view to the other's
sharpness before the census restores most of it, and leaves a clean pair as it was (both views
are about equally sharp, so nothing is blurred).

The rules, per output row `y` of the refinement, so that a streaming refinement can apply them
from the view rows around `y` alone:

1. `box(v, k)`: the mean of the `(2k + 1)^2` window around each pixel, coordinates clamped to
   the image (edge replicate), rounded half up: `(sum + n // 2) // n`, `n = (2k + 1)^2`;
   `box(v, 0) = v`.
2. `g(v, k, row)`: the sum over the row of `|s(x + 1) - s(x)|`, `s = box(box(v, k), 1)` (the
   3x3 mean keeps sensor noise from reading as sharpness).
3. `S(v, k)`: `g(v, k, row)` summed over the rows `y - WINDOW ..= y + WINDOW`, clamped to the
   image (a clamped row counts each time it is named).
4. The sharper view is the left when `S(left, 0) >= S(right, 0)`, else the right; `own` is its
   `S(., 0)`, `target` the other's. When `100 own <= (100 + MARGIN_PCT) target` nothing is
   blurred. Otherwise, of `k` in `0..=MAX_RADIUS` the lowest `|S(sharper, k) - target|` wins,
   ties to the smaller `k`.
4a. A contrast check: a view with less contrast (exposure gain, a tone curve) has smaller
   gradients at every scale, a defocused one loses its fine gradients more than its coarse
   ones. So a blur chosen by rule 4 stands only when the sharper view is also sharper relative
   to its own coarse gradients: `100 S(s, 0) S(o, MAX_RADIUS) > (100 + CONTRAST_MARGIN_PCT)
   S(o, 0) S(s, MAX_RADIUS)` (`s` the sharper view, `o` the other); else nothing is blurred.
5. Row `y` is refined with the census of `box(sharper, k)` in place of the sharper view (the
   other view as it is).

The fixture that pins `bino_core::refine::sharpness::refine_map_equalised` to
`refine_equalised`:

    python -m bino_train.sharpness --fixture ../tests/fixtures/refine/equalised.bin

Chosen on the validation pairs (`python -m bino_train.refine_val --nuisance none blur noise
gain gamma occlude --equalise`), never on the eval split; per-48-row blocks did as well under blur
but cost more clean. Without rule 4a an exposure gain of 0.7 read as defocus and blurred the
other view in 96 % of the rows (160 px gain: 0.736 epe against 0.490 unequalised).
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

WINDOW = 3
"""Rows above and below the output row whose sharpness decides it."""

MARGIN_PCT = 25
"""How much sharper (%) the sharper view must be before it is blurred."""

MAX_RADIUS = 2
"""Largest box radius tried (5x5)."""

CONTRAST_MARGIN_PCT = 15
"""How much sharper (%) relative to its coarse gradients the sharper view must be (rule 4a)."""


class Decision(NamedTuple):
    """One output row's choice: the view blurred (0 left, 1 right) and the box radius (0: none)."""

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
    """Per row, the sum of `|s(y, x + 1) - s(y, x)|` with `s = box(view, 1)` (rule 2, `k = 0`)."""
    smooth = box(view, 1).astype(np.int64)
    return np.abs(np.diff(smooth, axis=1)).sum(axis=1)


def decide_rows(
    left: NDArray[np.uint8],
    right: NDArray[np.uint8],
    window: int = WINDOW,
    margin_pct: int = MARGIN_PCT,
    contrast_margin_pct: int | None = CONTRAST_MARGIN_PCT,
) -> list[Decision]:
    """Each output row's blurred view and radius (rules 2-4a; `contrast_margin_pct` None: without
    rule 4a)."""
    if left.shape != right.shape or left.ndim != 2:
        raise ValueError(f"views must be equal 2-D arrays, got {left.shape} and {right.shape}")
    h = left.shape[0]
    g = {
        (v, k): sharpness_rows(box(view, k))
        for v, view in enumerate((left, right))
        for k in range(MAX_RADIUS + 1)
    }
    decisions = []
    for y in range(h):
        rows = np.clip(np.arange(y - window, y + window + 1), 0, h - 1)
        sl, sr = int(g[0, 0][rows].sum()), int(g[1, 0][rows].sum())
        view, own, target = (0, sl, sr) if sl >= sr else (1, sr, sl)
        if own * 100 <= target * (100 + margin_pct):
            decisions.append(Decision(view, 0))
            continue
        sums = [int(g[view, k][rows].sum()) for k in range(MAX_RADIUS + 1)]
        radius = int(np.argmin([abs(s - target) for s in sums]))
        if contrast_margin_pct is not None:
            coarse_own, coarse_other = sums[MAX_RADIUS], int(g[1 - view, MAX_RADIUS][rows].sum())
            if own * coarse_other * 100 <= target * coarse_own * (100 + contrast_margin_pct):
                radius = 0
        decisions.append(Decision(view, radius))
    return decisions


def refine_equalised(
    left: NDArray[np.uint8],
    right: NDArray[np.uint8],
    tokens_q8: NDArray[Any],
    params: Any = None,
    window: int = WINDOW,
    margin_pct: int = MARGIN_PCT,
) -> NDArray[np.uint16]:
    """`refine.refine_int` with each output row's census on the views its decision smooths
    (rule 5): a row of the refinement depends only on the views, so each row is taken from the
    whole-image refinement of its decision's views."""
    from .refine import refine_int

    refined: dict[Decision, NDArray[np.uint16]] = {}
    out = np.zeros(left.shape, dtype=np.uint16)
    for y, decision in enumerate(decide_rows(left, right, window, margin_pct)):
        key = decision if decision.radius else Decision(0, 0)
        if key not in refined:
            views = [left, right]
            views[key.view] = box(views[key.view], key.radius)
            refined[key] = refine_int(views[0], views[1], tokens_q8, params)
        out[y] = refined[key][y]
    return out


FIXTURE_MAGIC = b"BRE1"
"""First bytes of the equalised refinement's fixture (`refine.write_fixture`'s format)."""


def fixture_cases() -> list[tuple[NDArray[np.uint8], NDArray[np.uint8], NDArray[Any], Any]]:
    """16x24 textured pairs shifted by 3 px: the right view blurred (radius 1 and 2), the left
    view blurred, both sharp, the right view with noise, and with less contrast (gain 0.7, rule
    4a), sharp and blurred; default refinement parameters."""
    from .refine import RefineParams, grid_size

    rng = np.random.default_rng(29)
    h, w = 16, 24
    t, pc = grid_size(h, w)
    smooth = box(rng.integers(0, 256, size=(h, w + 8), dtype=np.int64).astype(np.uint8), 1)
    base = np.clip(smooth.astype(np.int64) * 3 - 256, 0, 255).astype(np.uint8)
    left, right = base[:, :w].copy(), base[:, 3 : w + 3].copy()
    tokens = np.clip(np.round((3 + rng.uniform(-1.0, 1.0, size=(t, pc))) * 64), 0, None)
    tokens = tokens.astype(np.uint16)
    noisy = np.clip(right.astype(np.int64) + rng.integers(-20, 21, size=right.shape), 0, 255)
    dim = (right.astype(np.int64) * 7 // 10 + 20).astype(np.uint8)
    p = RefineParams()
    return [
        (left, box(right, 2), tokens, p),
        (left, box(right, 1), tokens, p),
        (box(left, 2), right, tokens, p),
        (left, right, tokens, p),
        (left, noisy.astype(np.uint8), tokens, p),
        (left, dim, tokens, p),
        (left, box(dim, 2), tokens, p),
    ]


def write_fixture(path: Path) -> int:
    """Writes the fixture (`refine.write_fixture`'s format, magic `BRE1`, `refine_equalised`'s
    output); returns the bytes written."""
    from .refine import write_fixture as write_refine_fixture

    return write_refine_fixture(path, fixture_cases(), refine_equalised, FIXTURE_MAGIC)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--fixture", type=Path, required=True, help="fixture file to write")
    args = parser.parse_args(argv)
    size = write_fixture(args.fixture)
    print(f"wrote {args.fixture} ({size} bytes)")


if __name__ == "__main__":
    main()
