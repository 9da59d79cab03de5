"""Pixel refinement of a token-grid disparity (issue 14): the float twin of `core/src/refine.rs`.

The token grid gives one disparity per 4x4 view cell. Refinement turns it into one disparity per
pixel, guided by both views:

1. d0: the grid upsampled bilinearly to pixels like cv2.resize INTER_LINEAR (half-pixel
   centres, source coordinate (x + 0.5) / 4 - 0.5, edge cells clamped), in pixels.
2. base = round(d0); a 5x5 census transform of each view (bit set where the neighbour is darker
   than the centre, coordinates clamped to the image).
3. Each candidate d = base + k, |k| <= search, with d >= 0 and x - d >= 0, costs the Hamming
   distance of the census codes summed over the box around the pixel (9x9 by default; every box
   pixel at the centre's d; box and matched columns clamped to the image) plus lam * |d - d0|.
4. The lowest cost wins (ties: smaller |k|, then smaller d); a parabola through its two
   neighbours (when both are valid and it opens upwards) moves it by at most half a pixel;
   without any valid candidate the pixel keeps d0.

`refine_float` is that algorithm in floating point; `refine_int` is a direct transcription of
the integer rules of the Rust module (Q8 pixels, costs scaled by 256, the bilinear step exact
in 1/64, the parabola step truncated), bit-exact with it. The fixture the Rust tests pin the
module to comes from `refine_int`:

    python -m bino_train.refine --fixture ../tests/fixtures/refine/cases.bin
"""

from __future__ import annotations

import argparse
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

CELL = 4
"""View pixels per token cell, in both directions."""

FIXTURE_MAGIC = b"BRF1"
"""First bytes of a refinement fixture file (format in `write_fixture`)."""

# Weight (in 1/8) of the second of the two cells a pixel reads, by pixel index mod 4: pixels
# 0 and 1 of a cell read (c - 1, c), pixels 2 and 3 read (c, c + 1).
_FRAC8 = np.array([5, 7, 1, 3], dtype=np.int64)
_POPCOUNT8 = np.array([bin(i).count("1") for i in range(256)], dtype=np.int64)


@dataclass(frozen=True)
class RefineParams:
    """The refinement's parameters; the defaults are the ones the prototype chose."""

    census_radius: int = 2
    """Census window radius (2: 5x5, 24 bits). 1 or 2."""
    search: int = 2
    """Candidates base - search ..= base + search, in pixels. 0 to 8."""
    lam: int = 50
    """Cost of one pixel away from d0, in summed-Hamming units (2 per mean Hamming of a 5x5
    box). 0 to 4096."""
    box_radius: int = 4
    """Aggregation box radius (4: 9x9; 2, 5x5, until session 34). 0 to 4."""

    def check(self) -> None:
        """Raises ValueError for a parameter outside the Rust module's range."""
        for name, value, lo, hi in (
            ("census radius", self.census_radius, 1, 2),
            ("search", self.search, 0, 8),
            ("lambda", self.lam, 0, 4096),
            ("box radius", self.box_radius, 0, 4),
        ):
            if not lo <= value <= hi:
                raise ValueError(f"{name} {value} is outside {lo}..={hi}")


def grid_size(height: int, width: int) -> tuple[int, int]:
    """Token grid (rows, columns) of a view: ceil(H / 4) x ceil(W / 4)."""
    return -(-height // CELL), -(-width // CELL)


def _taps(n: int, cells: int) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """For pixels 0..n: first cell, second cell (clamped to the grid) and the second's weight
    in 1/8."""
    x = np.arange(n)
    c = x // CELL
    m = x % CELL
    first = np.where(m < 2, c - 1, c)
    second = first + 1
    return (
        np.clip(first, 0, cells - 1),
        np.clip(second, 0, cells - 1),
        _FRAC8[m],
    )


def _check_shapes(left: NDArray[np.uint8], right: NDArray[np.uint8], tokens: NDArray[Any]) -> None:
    if left.ndim != 2 or left.shape != right.shape or left.size == 0:
        raise ValueError(f"views must be equal non-empty 2-D arrays: {left.shape}, {right.shape}")
    if tokens.shape != grid_size(*left.shape):
        raise ValueError(f"tokens {tokens.shape} do not cover a {left.shape} view")


def upsample_float(tokens: NDArray[Any], height: int, width: int) -> NDArray[np.float64]:
    """(T, P) patch columns -> (height, width) pixels, bilinear with half-pixel centres."""
    ry, sy, fy = _taps(height, tokens.shape[0])
    rx, sx, fx = _taps(width, tokens.shape[1])
    grid = np.asarray(tokens, dtype=np.float64) * CELL
    wx = fx / 8.0
    wy = (fy / 8.0)[:, None]
    rows_a = grid[ry][:, rx] * (1 - wx) + grid[ry][:, sx] * wx
    rows_b = grid[sy][:, rx] * (1 - wx) + grid[sy][:, sx] * wx
    return np.asarray(rows_a * (1 - wy) + rows_b * wy)


def upsample_int(tokens_q8: NDArray[Any], height: int, width: int) -> NDArray[np.int64]:
    """(T, P) Q8 patch columns -> (height, width) Q8 pixels, exact in 1/64 then rounded:
    (sum of w_y w_x (4 D) + 32) >> 6 with weights in 1/8."""
    ry, sy, fy = _taps(height, tokens_q8.shape[0])
    rx, sx, fx = _taps(width, tokens_q8.shape[1])
    grid: NDArray[np.int64] = np.asarray(tokens_q8, dtype=np.int64)
    rows_a: NDArray[np.int64] = grid[ry][:, rx] * (8 - fx) + grid[ry][:, sx] * fx
    rows_b: NDArray[np.int64] = grid[sy][:, rx] * (8 - fx) + grid[sy][:, sx] * fx
    wy = fy[:, None]
    total: NDArray[np.int64] = (rows_a * (8 - wy) + rows_b * wy) * CELL + 32
    return np.asarray(total >> 6)


def census(view: NDArray[np.uint8], radius: int) -> NDArray[np.int64]:
    """Census codes: bit b set where neighbour b is below the centre. Neighbours in raster
    order (rows top to bottom, columns left to right, the centre skipped), bit 0 first;
    coordinates clamped to the image."""
    h, w = view.shape
    img = np.asarray(view, dtype=np.int64)
    ys = np.arange(h)[:, None]
    xs = np.arange(w)[None, :]
    codes = np.zeros((h, w), dtype=np.int64)
    bit = 0
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            if dy == 0 and dx == 0:
                continue
            neighbour = img[np.clip(ys + dy, 0, h - 1), np.clip(xs + dx, 0, w - 1)]
            codes |= (neighbour < img).astype(np.int64) << bit
            bit += 1
    return codes


def _popcount(x: NDArray[np.int64]) -> NDArray[np.int64]:
    return np.asarray(
        _POPCOUNT8[x & 255]
        + _POPCOUNT8[(x >> 8) & 255]
        + _POPCOUNT8[(x >> 16) & 255]
        + _POPCOUNT8[(x >> 24) & 255]
    )


def aggregated_costs(
    left: NDArray[np.uint8], right: NDArray[np.uint8], base: NDArray[np.int64], p: RefineParams
) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """(2S + 1, H, W) summed census Hamming distances of candidates base + k, k = -S..=S, and
    their validity (d >= 0 and x - d >= 0). Every box pixel (v, u) is compared with the right
    view at (v, u - d), d the centre's; v, u and u - d are clamped to the image."""
    h, w = left.shape
    cl = census(left, p.census_radius)
    cr = census(right, p.census_radius)
    ys = np.arange(h)[:, None]
    xs = np.arange(w)[None, :]
    b = p.box_radius
    costs = []
    valid = []
    for k in range(-p.search, p.search + 1):
        d = base + k
        valid.append((d >= 0) & (d <= xs))
        total = np.zeros((h, w), dtype=np.int64)
        for i in range(-b, b + 1):
            v = np.clip(ys + i, 0, h - 1)
            for j in range(-b, b + 1):
                u = np.clip(xs + j, 0, w - 1)
                ur = np.clip(u - d, 0, w - 1)
                total += _popcount(cl[v, u] ^ cr[v, ur])
        costs.append(total)
    return np.stack(costs), np.stack(valid)


def _winner(costs: NDArray[Any], valid: NDArray[np.bool_], search: int) -> NDArray[np.int64]:
    """Index (0..2S) of the lowest valid cost per pixel, visiting k = 0, -1, +1, -2, +2, ...
    and keeping the first strict minimum; -1 where no candidate is valid."""
    best = np.full(costs.shape[1:], -1, dtype=np.int64)
    best_cost = np.full(costs.shape[1:], np.inf)
    order = [0] + [s * k for k in range(1, search + 1) for s in (-1, 1)]
    for k in order:
        idx = k + search
        take = valid[idx] & (costs[idx] < best_cost)
        best = np.where(take, idx, best)
        best_cost = np.where(take, costs[idx], best_cost)
    return best


def _neighbours(
    costs: NDArray[Any], valid: NDArray[np.bool_], best: NDArray[np.int64]
) -> tuple[NDArray[Any], NDArray[Any], NDArray[Any], NDArray[np.bool_]]:
    """Costs at best - 1, best, best + 1 and whether the parabola step applies (both
    neighbours exist and are valid)."""
    n = costs.shape[0]

    def at(a: NDArray[Any], idx: NDArray[np.int64]) -> NDArray[Any]:
        return np.take_along_axis(a, np.clip(idx, 0, n - 1)[None], 0)[0]

    c_lo, c_at, c_hi = at(costs, best - 1), at(costs, best), at(costs, best + 1)
    v_lo, v_hi = at(valid, best - 1), at(valid, best + 1)
    both = (best >= 1) & (best <= n - 2) & v_lo & v_hi
    return c_lo, c_at, c_hi, both


def refine_float(
    left: NDArray[np.uint8],
    right: NDArray[np.uint8],
    tokens: NDArray[Any],
    params: RefineParams | None = None,
) -> NDArray[np.float64]:
    """(H, W) refined disparity in pixels from (T, P) token disparities in patch columns."""
    p = params or RefineParams()
    p.check()
    _check_shapes(left, right, tokens)
    h, w = left.shape
    d0 = upsample_float(tokens, h, w)
    base = np.floor(d0 + 0.5).astype(np.int64)
    hamming, valid = aggregated_costs(left, right, base, p)
    ks = np.arange(-p.search, p.search + 1)[:, None, None]
    d = base[None] + ks
    costs = hamming.astype(np.float64) + p.lam * np.abs(d - d0[None])
    best = _winner(costs, valid, p.search)
    c_lo, c_at, c_hi, both = _neighbours(costs, valid, best)
    denom = c_lo - 2 * c_at + c_hi
    step = both & (denom > 0)
    offset = np.where(step, (c_lo - c_hi) / (2 * np.where(step, denom, 1.0)), 0.0)
    refined = np.maximum(base + best - p.search + np.clip(offset, -0.5, 0.5), 0.0)
    return np.asarray(np.where(best >= 0, refined, d0))


def refine_int(
    left: NDArray[np.uint8],
    right: NDArray[np.uint8],
    tokens_q8: NDArray[Any],
    params: RefineParams | None = None,
) -> NDArray[np.uint16]:
    """(H, W) refined disparity in Q8 pixels from (T, P) Q8 patch columns: the integer rules
    of `core/src/refine.rs`, transcribed."""
    p = params or RefineParams()
    p.check()
    _check_shapes(left, right, tokens_q8)
    h, w = left.shape
    d0 = upsample_int(np.asarray(tokens_q8, dtype=np.int64), h, w)
    base = (d0 + 128) >> 8
    hamming, valid = aggregated_costs(left, right, base, p)
    ks = np.arange(-p.search, p.search + 1)[:, None, None]
    d = base[None] + ks
    costs = hamming * 256 + p.lam * np.abs(d * 256 - d0[None])
    best = _winner(costs, valid, p.search)
    c_lo, c_at, c_hi, both = _neighbours(costs, valid, best)
    denom = c_lo - 2 * c_at + c_hi
    step = both & (denom > 0)
    num = (c_lo - c_hi) * 128
    safe = np.where(step, denom, 1)
    offset = np.where(step, np.sign(num) * (np.abs(num) // safe), 0)  # truncated toward zero
    refined = np.maximum((base + best - p.search) * 256 + np.clip(offset, -128, 128), 0)
    out = np.where(best >= 0, refined, d0)
    return np.minimum(out, 65535).astype(np.uint16)


def keep_rejected(
    refined_q8: NDArray[Any], tokens_q8: NDArray[Any], kept: NDArray[Any]
) -> NDArray[np.uint16]:
    """The `+lr+ref` rule for the cells a left-right check rejected (`kept` False, (T, P)): their
    pixels take the bilinear step d0 of the filled grid `tokens_q8` instead of the refined value
    (`bino_core::refine::keep_rejected_map`). (H, W) Q8 pixels."""
    h, w = refined_q8.shape
    d0 = upsample_int(np.asarray(tokens_q8, dtype=np.int64), h, w)
    rows = np.minimum(np.arange(h) // CELL, kept.shape[0] - 1)
    cols = np.minimum(np.arange(w) // CELL, kept.shape[1] - 1)
    rejected = ~np.asarray(kept, dtype=bool)[rows][:, cols]
    out = np.where(rejected, np.minimum(d0, 65535), refined_q8)
    return np.asarray(out, dtype=np.uint16)


def fixture_cases() -> list[
    tuple[NDArray[np.uint8], NDArray[np.uint8], NDArray[Any], RefineParams]
]:
    """The fixture's cases: 16x24 textured pairs (a shift of 3 px with a coarse grid off by
    up to 1.5 px, a half-pixel shift, raw noise with random tokens, a left border case) under
    the default and a few other parameter sets."""
    rng = np.random.default_rng(14)
    h, w = 16, 24
    t, pc = grid_size(h, w)
    cases: list[tuple[NDArray[np.uint8], NDArray[np.uint8], NDArray[Any], RefineParams]] = []
    base = rng.integers(0, 256, size=(h, w + 8), dtype=np.int64)
    left = base[:, :w].astype(np.uint8)
    right = base[:, 3 : w + 3].astype(np.uint8)
    tokens = np.clip(np.round((3 + rng.uniform(-1.5, 1.5, size=(t, pc))) * 64), 0, None)
    cases.append((left, right, tokens.astype(np.uint16), RefineParams()))
    half = ((base[:, 2 : w + 2] + base[:, 3 : w + 3] + 1) // 2).astype(np.uint8)
    cases.append((left, half, np.full((t, pc), 160, dtype=np.uint16), RefineParams()))
    noise_l = rng.integers(0, 256, size=(h, w), dtype=np.uint8)
    noise_r = rng.integers(0, 256, size=(h, w), dtype=np.uint8)
    random_tokens = rng.integers(0, 6 * 256, size=(t, pc)).astype(np.uint16)
    for p in (
        RefineParams(),
        RefineParams(census_radius=1, search=3, lam=0, box_radius=0),
        RefineParams(census_radius=2, search=8, lam=4096, box_radius=3),
        RefineParams(census_radius=1, search=0, lam=7, box_radius=1),
    ):
        cases.append((noise_l, noise_r, random_tokens, p))
    edge = np.full((t, pc), 65535, dtype=np.uint16)
    edge[:, 1:] = 2 * 256
    cases.append((left, right, edge, RefineParams()))
    return cases


def write_fixture(
    path: Path,
    cases: list[tuple[NDArray[np.uint8], NDArray[np.uint8], NDArray[Any], RefineParams]]
    | None = None,
    refine: Any = None,
    magic: bytes = FIXTURE_MAGIC,
) -> int:
    """Writes the fixture: `magic` (`BRF1`), u16 case count, then per case u16 height, width,
    census radius, search, lambda, box radius, the left and right views (u8, row-major),
    the tokens (u16, ceil(H/4) x ceil(W/4)) and the expected output of `refine` (default
    `refine_int`; u16, H x W), all little-endian. Returns the bytes written."""
    out = bytearray(magic)
    cases = fixture_cases() if cases is None else cases
    refine = refine_int if refine is None else refine
    out += struct.pack("<H", len(cases))
    for left, right, tokens, p in cases:
        h, w = left.shape
        out += struct.pack("<6H", h, w, p.census_radius, p.search, p.lam, p.box_radius)
        out += left.astype(np.uint8).tobytes() + right.astype(np.uint8).tobytes()
        out += tokens.astype("<u2").tobytes()
        out += refine(left, right, tokens, p).astype("<u2").tobytes()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(bytes(out))
    return len(out)


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
