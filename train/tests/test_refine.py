"""Pixel refinement (issue 14): the float twin, the integer transcription and their fixture."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from bino_train.refine import (
    RefineParams,
    census,
    grid_size,
    keep_rejected,
    refine_float,
    refine_int,
    upsample_float,
    upsample_int,
    write_fixture,
)

FIXTURE = Path(__file__).resolve().parents[2] / "tests" / "fixtures" / "refine" / "cases.bin"


def shifted_pair(
    seed: int, h: int, w: int, shift: int, half: bool = False
) -> tuple[np.ndarray, np.ndarray]:
    """Noise texture with right(x) = left(x + shift), or the mean of x + shift and
    x + shift + 1 (a shift of shift + 0.5 px) when `half`."""
    base = np.random.default_rng(seed).integers(0, 256, size=(h, w + shift + 1), dtype=np.int64)
    left = base[:, :w]
    right = base[:, shift : w + shift]
    if half:
        right = (right + base[:, shift + 1 : w + shift + 1] + 1) // 2
    return left.astype(np.uint8), right.astype(np.uint8)


def test_upsampling_is_cv2_linear_and_the_integer_one_its_rounding() -> None:
    rng = np.random.default_rng(0)
    tokens = rng.uniform(0, 12, size=(6, 10))
    expected = cv2.resize((tokens * 4).astype(np.float32), (40, 24), interpolation=cv2.INTER_LINEAR)
    np.testing.assert_allclose(upsample_float(tokens, 24, 40), expected, atol=1e-4)
    q8 = rng.integers(0, 65536, size=(6, 10))
    exact = upsample_float(q8 / 256, 24, 40)
    assert np.abs(upsample_int(q8, 24, 40) / 256 - exact).max() <= 1 / 512 + 1e-9
    # Where the four cells a pixel reads agree, the value is exact: 4 D.
    assert (upsample_int(np.full((2, 3), 777), 8, 12) == 4 * 777).all()


def test_census_bits_are_darker_neighbours_in_raster_order() -> None:
    view = np.array([[1, 2, 3], [4, 5, 6], [7, 8, 9]], dtype=np.uint8)
    codes = census(view, 1)
    # Neighbours of the centre in raster order: 1 2 3 4 (below 5) then 6 7 8 9.
    assert codes[1, 1] == 0b1111
    # Corner (0, 0) with edge replicate: every neighbour is >= 1.
    assert codes[0, 0] == 0
    assert census(np.zeros((3, 4), dtype=np.uint8), 2).max() == 0


@pytest.mark.parametrize("twin", ["float", "int"])
def test_an_integer_shift_is_recovered_from_a_coarse_grid(twin: str) -> None:
    h, w, shift = 24, 48, 5
    left, right = shifted_pair(3, h, w, shift)
    t, p = grid_size(h, w)
    tokens = (shift + np.random.default_rng(5).uniform(-1.5, 1.5, size=(t, p))) / 4
    if twin == "float":
        out = refine_float(left, right, tokens)
    else:
        out = refine_int(left, right, np.round(tokens * 256).astype(np.uint16)) / 256
    inner = out[:, shift + 2 :]
    assert (np.floor(inner + 0.5) == shift).all()
    assert np.abs(inner - shift).max() < 0.25


@pytest.mark.parametrize("twin", ["float", "int"])
def test_a_half_pixel_shift_is_read_within_a_quarter_pixel(twin: str) -> None:
    h, w, shift = 24, 48, 5
    left, right = shifted_pair(8, h, w, shift, half=True)
    t, p = grid_size(h, w)
    tokens = np.full((t, p), (shift + 0.5) / 4)
    if twin == "float":
        out = refine_float(left, right, tokens)
    else:
        out = refine_int(left, right, np.round(tokens * 256).astype(np.uint16)) / 256
    err = np.abs(out[:, shift + 3 :] - (shift + 0.5))
    assert err.max() <= 0.5
    assert (err <= 0.25).mean() >= 0.95
    assert err.mean() < 0.125


def test_without_a_valid_candidate_a_pixel_keeps_d0() -> None:
    left, right = shifted_pair(2, 8, 16, 0)
    out_int = refine_int(left, right, np.full((2, 4), 6 * 64, dtype=np.uint16))
    out_float = refine_float(left, right, np.full((2, 4), 1.5))
    assert (out_int[:, :4] == 6 * 256).all() and (out_float[:, :4] == 6.0).all()
    assert (out_int[:, 4] == 4 * 256).all() and (out_float[:, 4] == 4.0).all()
    saturated = refine_int(left, right, np.full((2, 4), 65535, dtype=np.uint16))
    assert (saturated == 65535).all()


def test_the_float_twin_agrees_with_the_integer_rules() -> None:
    """The twins differ only by the integer rounding of d0 (1/512 px) and of the parabola step
    (1/256 px), which can flip a near-tie now and then."""
    rng = np.random.default_rng(1)
    h, w = 32, 64
    left, right = shifted_pair(4, h, w, 6, half=True)
    noise_l = rng.integers(0, 256, size=(h, w), dtype=np.uint8)
    noise_r = rng.integers(0, 256, size=(h, w), dtype=np.uint8)
    t, p = grid_size(h, w)
    for pair in ((left, right), (noise_l, noise_r)):
        q8 = rng.integers(0, 10 * 256, size=(t, p)).astype(np.uint16)
        for params in (RefineParams(), RefineParams(census_radius=1, search=4, lam=9)):
            f = refine_float(*pair, q8 / 256, params)
            i = refine_int(*pair, q8, params) / 256
            diff = np.abs(f - i)
            assert (diff <= 1 / 64).mean() >= 0.98, params
            assert np.median(diff) <= 1 / 256


@pytest.mark.parametrize("h", range(1, 9))
def test_tiny_and_extreme_views_run(h: int) -> None:
    for w in range(1, 9):
        t, p = grid_size(h, w)
        for value in (0, 255):
            view = np.full((h, w), value, dtype=np.uint8)
            for tokens in (np.zeros((t, p)), np.full((t, p), 65535)):
                q8 = tokens.astype(np.uint16)
                assert refine_int(view, view, q8).shape == (h, w)
                assert np.isfinite(refine_float(view, view, tokens / 256)).all()
            assert (refine_int(view, view, np.full((t, p), 65535, dtype=np.uint16)) == 65535).all()


def test_bad_parameters_and_shapes_are_refused() -> None:
    view = np.zeros((8, 8), dtype=np.uint8)
    tokens = np.zeros((2, 2), dtype=np.uint16)
    for params in (
        RefineParams(census_radius=3),
        RefineParams(census_radius=0),
        RefineParams(search=9),
        RefineParams(lam=4097),
        RefineParams(box_radius=5),
    ):
        with pytest.raises(ValueError, match="outside"):
            refine_int(view, view, tokens, params)
    with pytest.raises(ValueError, match="do not cover"):
        refine_float(view, view, np.zeros((2, 3)))
    with pytest.raises(ValueError, match="equal"):
        refine_int(view, view[:4], tokens)


def test_the_committed_fixture_is_current(tmp_path: Path) -> None:
    """The Rust tests pin core/src/refine.rs to this file; rewrite it with
    `python -m bino_train.refine --fixture ../tests/fixtures/refine/cases.bin`."""
    fresh = tmp_path / "cases.bin"
    size = write_fixture(fresh)
    assert size < 20_000
    assert fresh.read_bytes() == FIXTURE.read_bytes()


def test_rejected_cells_keep_the_bilinear_step() -> None:
    """`keep_rejected` (the `+lr+ref` rule, `bino_core::refine::keep_rejected_map`): pixels of
    rejected cells take d0 of the filled grid, the others keep the refined value."""
    left, right = shifted_pair(5, 16, 24, 3)
    rng = np.random.default_rng(9)
    tokens = rng.integers(0, 4 * 256, size=(4, 6))
    kept = rng.random((4, 6)) > 0.3
    kept[0, 0] = False
    refined = refine_int(left, right, tokens)
    out = keep_rejected(refined, tokens, kept)
    d0 = upsample_int(tokens, 16, 24)
    for y in range(16):
        for x in range(24):
            want = d0[y, x] if not kept[y // 4, x // 4] else refined[y, x]
            assert out[y, x] == want, (y, x)
    assert (out != refined).any(), "some rejected pixel differs from its refined value"
    assert np.array_equal(keep_rejected(refined, tokens, np.ones((4, 6), bool)), refined)
