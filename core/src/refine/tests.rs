//! Tests of the pixel refinement: a plain pixel-by-pixel reference of the module docs' rules, known
//! shifts, the streaming path, extreme inputs and the Python fixture.

use super::*;
use crate::testutil::Rng;

const P: RefineParams = RefineParams::DEFAULT;

/// Largest test view (pixels) and grid (cells).
const MAX_PIXELS: usize = 24 * 48;
const MAX_CELLS: usize = 6 * 12;

fn noise(rng: &mut Rng, out: &mut [u8]) {
    out.iter_mut().for_each(|p| *p = rng.range(0, 255) as u8);
}

/// A textured `h x w` pair with `right(y, x) = left(y, x + shift)` (texture continued past
/// the right border), or the mean of `x + shift` and `x + shift + 1` when `half`.
fn shifted_pair(seed: u64, h: usize, w: usize, shift: usize, half: bool) -> ([u8; MAX_PIXELS], [u8; MAX_PIXELS]) {
    let mut rng = Rng::new(seed);
    let wide = w + shift + 1;
    let mut base = [0u8; 24 * 64];
    noise(&mut rng, &mut base[..h * wide]);
    let (mut left, mut right) = ([0u8; MAX_PIXELS], [0u8; MAX_PIXELS]);
    for y in 0..h {
        for x in 0..w {
            let at = |c: usize| base[y * wide + c] as u16;
            left[y * w + x] = at(x) as u8;
            right[y * w + x] = if half {
                (at(x + shift) + at(x + shift + 1)).div_ceil(2) as u8
            } else {
                at(x + shift) as u8
            };
        }
    }
    (left, right)
}

fn run_map(
    left: &[u8],
    right: &[u8],
    w: usize,
    tokens: &[u16],
    params: &RefineParams,
    out: &mut [u16],
) -> Result<(), Error> {
    let mut scratch = [0u32; 2 * 7 * 64];
    let n = scratch_len(w, params);
    refine_map(left, right, w, tokens, params, &mut scratch[..n], out)
}

// ---- a plain reference: the module docs' rules, pixel by pixel, on whole images ----

fn clamp(v: i64, n: usize) -> usize {
    v.clamp(0, n as i64 - 1) as usize
}

fn ref_census(img: &[u8], w: usize, h: usize, y: usize, x: usize, r: usize) -> u32 {
    let (r, c) = (r as i64, img[y * w + x]);
    let (mut code, mut bit) = (0u32, 0);
    for dy in -r..=r {
        for dx in -r..=r {
            if dy == 0 && dx == 0 {
                continue;
            }
            let n = img[clamp(y as i64 + dy, h) * w + clamp(x as i64 + dx, w)];
            code |= ((n < c) as u32) << bit;
            bit += 1;
        }
    }
    code
}

/// cv2's rule in eighths: source coordinate (2x - 3) / 8; below 0 or from the last cell on,
/// the edge cell alone.
fn ref_taps(x: usize, cells: usize) -> (usize, usize, i64) {
    let s8 = 2 * x as i64 - 3;
    let (floor, frac) = (s8.div_euclid(8), s8.rem_euclid(8));
    if floor < 0 {
        (0, 0, 0)
    } else if floor as usize >= cells - 1 {
        (cells - 1, cells - 1, 0)
    } else {
        (floor as usize, floor as usize + 1, frac)
    }
}

fn ref_d0(tokens: &[u16], w: usize, h: usize, y: usize, x: usize) -> i64 {
    let (rows, cells) = (h.div_ceil(4), w.div_ceil(4));
    let (ya, yb, fy) = ref_taps(y, rows);
    let (xa, xb, fx) = ref_taps(x, cells);
    let at = |r: usize, c: usize| 4 * tokens[r * cells + c] as i64;
    let sum = (8 - fy) * ((8 - fx) * at(ya, xa) + fx * at(ya, xb)) + fy * ((8 - fx) * at(yb, xa) + fx * at(yb, xb));
    (sum + 32) >> 6
}

/// Both views, `h x w`.
struct Pair<'a> {
    left: &'a [u8],
    right: &'a [u8],
    w: usize,
    h: usize,
}

fn ref_refine(pair: &Pair<'_>, tokens: &[u16], p: &RefineParams, y: usize, x: usize) -> u16 {
    let Pair { left, right, w, h } = *pair;
    let d0 = ref_d0(tokens, w, h, y, x);
    let base = (d0 + 128) >> 8;
    let (s, b) = (p.search as i64, p.box_radius as i64);
    let cost = |k: i64| -> Option<i64> {
        let d = base + k;
        if k.abs() > s || d < 0 || d > x as i64 {
            return None;
        }
        let mut a = 0i64;
        for i in -b..=b {
            for j in -b..=b {
                let (v, u) = (clamp(y as i64 + i, h), clamp(x as i64 + j, w));
                let ur = clamp(u as i64 - d, w);
                let cl = ref_census(left, w, h, v, u, p.census_radius);
                let cr = ref_census(right, w, h, v, ur, p.census_radius);
                a += (cl ^ cr).count_ones() as i64;
            }
        }
        Some(256 * a + p.lambda as i64 * (256 * d - d0).abs())
    };
    // Lowest cost, then smallest |k|, then smallest d.
    let best = (-s..=s).filter_map(|k| cost(k).map(|c| (c, k.abs(), k))).min();
    let Some((c0, _, k)) = best else {
        return d0.min(65535) as u16;
    };
    let step = match (cost(k - 1), cost(k + 1)) {
        (Some(lo), Some(hi)) if lo - 2 * c0 + hi > 0 => ((lo - hi) * 128 / (lo - 2 * c0 + hi)).clamp(-128, 128),
        _ => 0,
    };
    ((base + k) * 256 + step).clamp(0, 65535) as u16
}

fn assert_matches_reference(left: &[u8], right: &[u8], w: usize, h: usize, tokens: &[u16], p: &RefineParams) {
    let mut out = [0u16; MAX_PIXELS];
    run_map(left, right, w, tokens, p, &mut out[..w * h]).unwrap();
    for y in 0..h {
        for x in 0..w {
            let expected = ref_refine(&Pair { left, right, w, h }, tokens, p, y, x);
            assert_eq!(out[y * w + x], expected, "{w}x{h} {p:?}: pixel ({y}, {x})");
        }
    }
}

#[test]
fn agrees_with_the_plain_reference_at_every_pixel() {
    let mut rng = Rng::new(11);
    let params = [
        P,
        RefineParams {
            census_radius: 1,
            search: 3,
            lambda: 0,
            box_radius: 0,
        },
        RefineParams {
            census_radius: 2,
            search: MAX_SEARCH,
            lambda: MAX_LAMBDA,
            box_radius: MAX_BOX_RADIUS,
        },
    ];
    for (h, w) in [(16usize, 24usize), (13, 10), (5, 7), (1, 9), (9, 1)] {
        let (mut left, mut right) = ([0u8; MAX_PIXELS], [0u8; MAX_PIXELS]);
        noise(&mut rng, &mut left[..h * w]);
        noise(&mut rng, &mut right[..h * w]);
        let mut tokens = [0u16; MAX_CELLS];
        let cells = h.div_ceil(4) * w.div_ceil(4);
        tokens[..cells]
            .iter_mut()
            .for_each(|t| *t = rng.range(0, 6 * 256) as u16);
        for p in &params {
            assert_matches_reference(&left[..h * w], &right[..h * w], w, h, &tokens[..cells], p);
        }
    }
}

/// A constant shift of 5 px, a grid off by up to 1.5 px per cell: every pixel whose box
/// sees the matched texture wins at the true disparity, the parabola moving it by less
/// than a quarter pixel (it is not 0: the random texture's costs at d -+ 1 differ).
#[test]
fn an_integer_shift_is_recovered_from_a_coarse_grid() {
    let (h, w, shift) = (24, 48, 5);
    let (left, right) = shifted_pair(3, h, w, shift, false);
    let mut rng = Rng::new(5);
    let mut tokens = [0u16; 6 * 12];
    // Q8 patch columns = Q8 px / 4: (5 + [-1.5, 1.5]) px.
    tokens
        .iter_mut()
        .for_each(|t| *t = ((shift as i64 * 256 + rng.range(-384, 384)) / 4) as u16);
    let mut out = [0u16; 24 * 48];
    run_map(&left, &right, w, &tokens, &P, &mut out).unwrap();
    let mut exact = 0;
    for y in 0..h {
        for x in shift + 2..w {
            let d = out[y * w + x] as i64;
            assert_eq!((d + 128) >> 8, shift as i64, "pixel ({y}, {x}): {d}");
            assert!((d - 256 * shift as i64).abs() < 64, "pixel ({y}, {x}): {d}");
            exact += (d == 256 * shift as i64) as usize;
        }
    }
    assert!(exact > 0, "some pixels have symmetric costs");
    assert_matches_reference(&left[..h * w], &right[..h * w], w, h, &tokens, &P);
}

/// Right view = mean of two neighbouring left pixels: a shift of 5.5 px, read within a
/// quarter pixel at nearly every pixel from a grid reading 5.5.
#[test]
fn a_half_pixel_shift_is_read_within_a_quarter_pixel() {
    let (h, w, shift) = (24, 48, 5);
    let (left, right) = shifted_pair(8, h, w, shift, true);
    let tokens = [((shift * 256 + 128) / 4) as u16; 6 * 12];
    let mut out = [0u16; 24 * 48];
    run_map(&left, &right, w, &tokens, &P, &mut out).unwrap();
    let truth = shift as i64 * 256 + 128;
    let (mut within, mut total, mut err_sum) = (0, 0, 0);
    for y in 0..h {
        for x in shift + 3..w {
            let err = (out[y * w + x] as i64 - truth).abs();
            assert!(err <= 128, "pixel ({y}, {x}): {}", out[y * w + x]);
            within += (err <= 64) as usize;
            err_sum += err;
            total += 1;
        }
    }
    assert!(within * 100 >= total * 95, "{within} of {total} within 0.25 px");
    assert!(err_sum < total as i64 * 32, "mean error {} Q8", err_sum / total as i64);
}

/// Grid reading 6 px: pixels 0..4 have no candidate (every d > x) and keep d0; pixel 4
/// has d = 4 alone (no parabola), pixel 5 has d = 4, 5.
#[test]
fn without_a_valid_candidate_a_pixel_keeps_d0() {
    let (h, w) = (8, 16);
    let mut rng = Rng::new(2);
    let (mut left, mut right) = ([0u8; 128], [0u8; 128]);
    noise(&mut rng, &mut left);
    noise(&mut rng, &mut right);
    let tokens = [6 * 64u16; 2 * 4];
    let mut out = [0u16; 128];
    run_map(&left, &right, w, &tokens, &P, &mut out).unwrap();
    for y in 0..h {
        assert_eq!(out[y * w..y * w + 4], [6 * 256; 4], "row {y}");
        assert_eq!(out[y * w + 4], 4 * 256, "row {y}: only d = 4 is valid");
    }
    // Beyond u16 (d0 = 4 * 65535 Q8): no candidate either, and the output saturates.
    run_map(&left, &right, w, &[u16::MAX; 8], &P, &mut out).unwrap();
    assert!(out.iter().all(|&d| d == u16::MAX));
}

/// A streaming caller: a ring of `window_rows` rows of each view, filled as rows arrive,
/// and two token rows, give the same rows as the whole-map call.
#[test]
fn row_by_row_equals_the_whole_map() {
    let mut rng = Rng::new(21);
    for (h, w, p) in [
        (24, 48, P),
        (13, 10, P),
        (7, 5, RefineParams { box_radius: 3, ..P }),
        (3, 3, P),
    ] {
        let (mut left, mut right) = ([0u8; MAX_PIXELS], [0u8; MAX_PIXELS]);
        noise(&mut rng, &mut left[..h * w]);
        noise(&mut rng, &mut right[..h * w]);
        let (rows, cells) = (h.div_ceil(4), w.div_ceil(4));
        let mut tokens = [0u16; MAX_CELLS];
        tokens[..rows * cells]
            .iter_mut()
            .for_each(|t| *t = rng.range(0, 2048) as u16);
        let mut whole = [0u16; MAX_PIXELS];
        run_map(
            &left[..h * w],
            &right[..h * w],
            w,
            &tokens[..rows * cells],
            &p,
            &mut whole[..h * w],
        )
        .unwrap();

        // Ring slot of image row v: v mod window.
        let (reach, window) = (p.reach(), p.window_rows());
        let mut ring_l = [[0u8; 48]; MAX_WINDOW_ROWS];
        let mut ring_r = [[0u8; 48]; MAX_WINDOW_ROWS];
        let mut scratch = [0u32; 2 * (2 * MAX_BOX_RADIUS + 1) * 48];
        let mut pushed = 0;
        for y in 0..h {
            while pushed < h.min(y + reach + 1) {
                let slot = pushed % window;
                ring_l[slot][..w].copy_from_slice(&left[pushed * w..(pushed + 1) * w]);
                ring_r[slot][..w].copy_from_slice(&right[pushed * w..(pushed + 1) * w]);
                pushed += 1;
            }
            let mut wl: [&[u8]; MAX_WINDOW_ROWS] = [&[]; MAX_WINDOW_ROWS];
            let mut wr: [&[u8]; MAX_WINDOW_ROWS] = [&[]; MAX_WINDOW_ROWS];
            for e in 0..window {
                let slot = window_row(y, e, reach, h) % window;
                wl[e] = &ring_l[slot][..w];
                wr[e] = &ring_r[slot][..w];
            }
            let (first, second) = token_rows(y, rows);
            let grid = TokenRows {
                first: &tokens[first * cells..(first + 1) * cells],
                second: &tokens[second * cells..(second + 1) * cells],
            };
            let view = ViewRows {
                height: h,
                left: &wl[..window],
                right: &wr[..window],
            };
            let mut row = [0u16; 48];
            let n = scratch_len(w, &p);
            refine_row(y, &view, &grid, &p, &mut scratch[..n], &mut row[..w]).unwrap();
            assert_eq!(row[..w], whole[y * w..(y + 1) * w], "{h}x{w}: row {y}");
        }
    }
}

#[test]
fn extreme_inputs_run_through() {
    let mut rng = Rng::new(99);
    let params = [
        P,
        RefineParams {
            census_radius: 1,
            search: 0,
            lambda: 0,
            box_radius: 0,
        },
        RefineParams {
            census_radius: MAX_CENSUS_RADIUS,
            search: MAX_SEARCH,
            lambda: MAX_LAMBDA,
            box_radius: MAX_BOX_RADIUS,
        },
    ];
    let mut out = [0u16; 64];
    for h in 1..=8usize {
        for w in 1..=8usize {
            let n = h * w;
            let cells = h.div_ceil(4) * w.div_ceil(4);
            let mut random = [0u8; 64];
            noise(&mut rng, &mut random);
            for (left, right) in [
                ([255u8; 64], [255u8; 64]),
                ([0; 64], [0; 64]),
                ([0; 64], [255; 64]),
                (random, [7; 64]),
            ] {
                for tokens in [[u16::MAX; 4], [0; 4], [u16::MAX, 0, 1, 32768]] {
                    for p in &params {
                        run_map(&left[..n], &right[..n], w, &tokens[..cells], p, &mut out[..n]).unwrap();
                        if tokens[0] == u16::MAX && cells == 1 {
                            assert!(out[..n].iter().all(|&d| d == u16::MAX), "{h}x{w}");
                        }
                        if tokens == [0; 4] {
                            // d = 0 wins for views without texture, and at x = 0 always.
                            assert_eq!(out[0], 0, "{h}x{w}");
                        }
                    }
                }
            }
        }
    }
    // Flat views (census cost 0 everywhere) and d0 = 7 px: the penalty decides among the
    // valid candidates (d <= x), with no step where a neighbour is invalid; x < 5 keeps d0.
    run_map(&[9; 64], &[9; 64], 8, &[7 * 64; 4], &P, &mut out).unwrap();
    let row = [1792, 1792, 1792, 1792, 1792, 5 * 256, 6 * 256, 7 * 256];
    assert!(out.chunks_exact(8).all(|r| r == row), "{out:?}");
}

#[test]
fn bilinear_step_is_cv2_linear_and_exact_where_cells_agree() {
    let mut rng = Rng::new(7);
    for (h, w) in [(24usize, 48usize), (13, 10), (4, 4), (1, 1), (6, 1)] {
        let (rows, cells) = (h.div_ceil(4), w.div_ceil(4));
        let mut tokens = [0u16; MAX_CELLS];
        // Random values with long runs, so many pixels read four equal cells.
        let mut value = 0u16;
        for t in tokens[..rows * cells].iter_mut() {
            if rng.range(0, 3) == 0 {
                value = rng.range(0, u16::MAX as i64) as u16;
            }
            *t = value;
        }
        let (mut agreeing, mut total) = (0, 0);
        for y in 0..h {
            let (first, second) = token_rows(y, rows);
            let grid = TokenRows {
                first: &tokens[first * cells..(first + 1) * cells],
                second: &tokens[second * cells..(second + 1) * cells],
            };
            let (ya, yb, _) = ref_taps(y, rows);
            for x in 0..w {
                let d0 = bilinear(x, y, &grid, cells);
                assert_eq!(d0 as i64, ref_d0(&tokens, w, h, y, x), "{h}x{w}: pixel ({y}, {x})");
                let (xa, xb, _) = ref_taps(x, cells);
                let four = [ya * cells + xa, ya * cells + xb, yb * cells + xa, yb * cells + xb].map(|i| tokens[i]);
                if four.iter().all(|&t| t == four[0]) {
                    assert_eq!(d0, 4 * four[0] as u32, "{h}x{w}: pixel ({y}, {x})");
                    agreeing += 1;
                }
                total += 1;
            }
        }
        assert!(
            agreeing > 0 && (agreeing < total || rows * cells == 1),
            "{h}x{w}: {agreeing} of {total}"
        );
    }
    // The weights by pixel mod 4: 5/8, 7/8 of cell c (with c - 1), then 1/8, 3/8 of c + 1.
    let grid = TokenRows {
        first: &[0, 64, 0],
        second: &[0, 64, 0],
    };
    let row: [u32; 12] = core::array::from_fn(|x| bilinear(x, 0, &grid, 3));
    assert_eq!(row, [0, 0, 32, 96, 160, 224, 224, 160, 96, 32, 0, 0]);
}

#[test]
fn ties_and_the_parabola_follow_the_rules() {
    // Ties: k = 0 first, then -1 before +1.
    assert_eq!(winner(&[5, 3, 3, 3, 5], &[true; 5], 2), Some(2));
    assert_eq!(winner(&[5, 3, 4, 3, 5], &[true; 5], 2), Some(1));
    assert_eq!(winner(&[1, 3, 4, 3, 1], &[true; 5], 2), Some(0));
    assert_eq!(winner(&[1, 3, 4, 3, 1], &[false, true, true, true, true], 2), Some(4));
    assert_eq!(winner(&[1, 3, 4, 3, 1], &[false; 5], 2), None);
    assert_eq!(winner(&[9], &[true], 0), Some(0));
    // Symmetric neighbours: no step; truncation toward zero; the edge of the range and an
    // invalid neighbour give no step; a flat parabola none either.
    assert_eq!(subpixel_step(&[10, 4, 10], &[true; 3], 1), 0);
    assert_eq!(subpixel_step(&[10, 4, 7], &[true; 3], 1), 42); // 384 / 9 = 42.67
    assert_eq!(subpixel_step(&[7, 4, 10], &[true; 3], 1), -42);
    assert_eq!(subpixel_step(&[4, 4, 10], &[true; 3], 1), -128);
    assert_eq!(subpixel_step(&[10, 4, 7], &[true; 3], 0), 0);
    assert_eq!(subpixel_step(&[10, 4, 7], &[true; 3], 2), 0);
    assert_eq!(subpixel_step(&[10, 4, 7], &[false, true, true], 1), 0);
    assert_eq!(subpixel_step(&[4, 4, 4], &[true; 3], 1), 0);
    assert_eq!(subpixel_step(&[u32::MAX - 1, 0, 0], &[true; 3], 1), 128);
    // The i32 division (costs below 2^24) gives the rule's i64 quotient: random costs on both
    // sides of 2^24, and the extremes just below it.
    let rule = |c: [u32; 3]| {
        let (lo, mid, hi) = (c[0] as i64, c[1] as i64, c[2] as i64);
        let denom = lo - 2 * mid + hi;
        if denom <= 0 {
            0
        } else {
            (((lo - hi) * 128) / denom).clamp(-128, 128)
        }
    };
    let mut rng = Rng::new(5);
    let top = (1i64 << 24) - 1;
    for i in 0..20_000 {
        let max = if i % 2 == 0 { top } else { 1 << 26 };
        let c = [0; 3].map(|_: u32| rng.range(0, max) as u32);
        assert_eq!(subpixel_step(&c, &[true; 3], 1), rule(c), "{c:?}");
    }
    for c in [
        [top as u32, 0, 1],
        [0, 0, top as u32],
        [top as u32, 1, 0],
        [top as u32, 0, top as u32],
    ] {
        assert_eq!(subpixel_step(&c, &[true; 3], 1), rule(c), "{c:?}");
    }
}

#[test]
fn bad_parameters_and_shapes_are_errors() {
    let bad = [
        RefineParams { census_radius: 0, ..P },
        RefineParams { census_radius: 3, ..P },
        RefineParams {
            search: MAX_SEARCH + 1,
            ..P
        },
        RefineParams {
            lambda: MAX_LAMBDA + 1,
            ..P
        },
        RefineParams {
            box_radius: MAX_BOX_RADIUS + 1,
            ..P
        },
    ];
    let mut out = [0u16; 64];
    let mut scratch = [0u32; scratch_len(8, &P)];
    for p in bad {
        assert!(matches!(p.check(), Err(Error::OutOfRange { .. })), "{p:?}");
        let r = refine_map(&[0; 64], &[0; 64], 8, &[0; 4], &p, &mut scratch, &mut out);
        assert!(matches!(r, Err(Error::OutOfRange { .. })), "{p:?}");
    }
    assert_eq!(RefineParams::default().check(), Ok(()));
    let map = |l: &[u8], r: &[u8], w, t: &[u16], s: &mut [u32], o: &mut [u16]| refine_map(l, r, w, t, &P, s, o);
    assert_eq!(
        map(&[0; 64], &[0; 64], 0, &[0; 4], &mut scratch, &mut out),
        Err(Error::EmptyImage)
    );
    assert_eq!(
        map(&[], &[], 8, &[0; 4], &mut scratch, &mut out),
        Err(Error::EmptyImage)
    );
    assert!(matches!(
        map(&[0; 63], &[0; 63], 8, &[0; 4], &mut scratch, &mut out),
        Err(Error::BufferSize { .. })
    ));
    assert_eq!(
        map(&[0; 64], &[0; 56], 8, &[0; 4], &mut scratch, &mut out),
        Err(Error::PairMismatch)
    );
    assert!(matches!(
        map(&[0; 64], &[0; 64], 8, &[0; 3], &mut scratch, &mut out),
        Err(Error::BufferSize { .. })
    ));
    assert!(matches!(
        map(
            &[0; 64],
            &[0; 64],
            8,
            &[0; 4],
            &mut scratch[..scratch_len(8, &P) - 1],
            &mut out
        ),
        Err(Error::BufferSize { .. })
    ));
    assert!(matches!(
        map(&[0; 64], &[0; 64], 8, &[0; 4], &mut scratch, &mut out[..63]),
        Err(Error::BufferSize { .. })
    ));

    let row = [0u8; 8];
    let window = [&row[..]; P.window_rows()];
    let tokens = TokenRows {
        first: &[0; 2],
        second: &[0; 2],
    };
    let good = ViewRows {
        height: 8,
        left: &window,
        right: &window,
    };
    let mut line = [0u16; 8];
    assert_eq!(refine_row(7, &good, &tokens, &P, &mut scratch, &mut line), Ok(()));
    assert!(matches!(
        refine_row(8, &good, &tokens, &P, &mut scratch, &mut line),
        Err(Error::OutOfRange { .. })
    ));
    let short = ViewRows {
        left: &window[..8],
        ..good
    };
    assert!(matches!(
        refine_row(0, &short, &tokens, &P, &mut scratch, &mut line),
        Err(Error::BufferSize { .. })
    ));
    let narrow = [&row[..7]; P.window_rows()];
    let narrow = ViewRows { right: &narrow, ..good };
    assert!(matches!(
        refine_row(0, &narrow, &tokens, &P, &mut scratch, &mut line),
        Err(Error::BufferSize { .. })
    ));
    let bad_tokens = TokenRows {
        second: &[0; 3],
        ..tokens
    };
    assert!(matches!(
        refine_row(0, &good, &bad_tokens, &P, &mut scratch, &mut line),
        Err(Error::BufferSize { .. })
    ));
    let empty = ViewRows { height: 0, ..good };
    assert_eq!(
        refine_row(0, &empty, &tokens, &P, &mut scratch, &mut line),
        Err(Error::EmptyImage)
    );
    assert_eq!(
        refine_row(0, &good, &tokens, &P, &mut scratch, &mut []),
        Err(Error::EmptyImage)
    );
    let tall = ViewRows {
        height: MAX_HEIGHT + 1,
        ..good
    };
    assert!(matches!(
        refine_row(0, &tall, &tokens, &P, &mut scratch, &mut line),
        Err(Error::TooTall { .. })
    ));
}

#[test]
fn sizes_for_the_budget() {
    assert_eq!((P.reach(), P.window_rows()), (6, 13));
    assert_eq!(scratch_len(160, &P), 2 * 9 * 160);
    assert_eq!(stream_bytes(160, &P), 2 * 13 * 160 + 2 * 2 * 40 + 4 * 2 * 9 * 160);
    assert_eq!(stream_bytes(160, &P), 15840);
    assert_eq!(stream_bytes(usize::MAX, &P), usize::MAX, "saturates");
    // The clamped window rows of the first and last output rows.
    assert_eq!(
        core::array::from_fn::<_, 13, _>(|e| window_row(0, e, 6, 6)),
        [0, 0, 0, 0, 0, 0, 0, 1, 2, 3, 4, 5, 5]
    );
    assert_eq!(
        core::array::from_fn::<_, 13, _>(|e| window_row(5, e, 6, 6)),
        [0, 0, 1, 2, 3, 4, 5, 5, 5, 5, 5, 5, 5]
    );
    assert_eq!(
        [0, 1, 2, 3, 4, 5, 8, 9].map(|y| token_rows(y, 3)),
        [(0, 0), (0, 0), (0, 1), (0, 1), (0, 1), (0, 1), (1, 2), (1, 2)]
    );
    assert_eq!(token_rows(10, 3), (2, 2));
    assert_eq!(token_rows(5, 0), (0, 0));
}

/// `train/bino_train/refine.py` (`refine_int`, its integer transcription) wrote these
/// cases: `python -m bino_train.refine --fixture ../tests/fixtures/refine/cases.bin`.
#[test]
fn matches_the_python_fixture_bit_for_bit() {
    const FIXTURE: &[u8] = include_bytes!("../../../tests/fixtures/refine/cases.bin");
    let cases = super::fixture::for_each_case(FIXTURE, b"BRF1", |i, case| {
        let mut tokens = [0u16; MAX_CELLS];
        let mut out = [0u16; MAX_PIXELS];
        let n = case.height * case.width;
        let tokens = case.tokens(&mut tokens);
        run_map(case.left, case.right, case.width, tokens, &case.params, &mut out[..n]).unwrap();
        case.check(i, &out[..n]);
    });
    assert!(cases >= 4);
}

#[test]
fn the_search_radius_follows_the_view_width() {
    // 160 px (the presets' and the firmware's width) keeps the shipped default.
    assert_eq!(RefineParams::for_width(160), RefineParams::DEFAULT);
    let search = |w| RefineParams::for_width(w).search;
    assert_eq!(
        [search(0), search(200), search(240), search(320), search(640)],
        [2, 3, 3, 4, 8]
    );
    assert_eq!(search(usize::MAX), MAX_SEARCH);
    for w in (0..2000).step_by(8) {
        let p = RefineParams::for_width(w);
        assert!(p.check().is_ok(), "width {w}: {p:?}");
        assert_eq!(RefineParams { search: 2, ..p }, RefineParams::DEFAULT);
    }
}

/// `+lr+ref`: the pixels of rejected cells (the mask of their own grid row `y / 4`) take `d0`,
/// the others keep the refined value, at sizes that are and are not multiples of the cell.
#[test]
fn rejected_cells_keep_d0_and_kept_cells_their_refined_value() {
    let mut rng = Rng::new(31);
    for (w, h) in [(16usize, 8usize), (13, 10), (48, 24), (1, 1)] {
        let (rows, cells) = (h.div_ceil(4), w.div_ceil(4));
        let mut tokens = [0u16; MAX_CELLS];
        let mut kept = [0u8; MAX_CELLS];
        for (t, k) in tokens.iter_mut().zip(kept.iter_mut()).take(rows * cells) {
            (*t, *k) = (rng.range(0, 12 * 256) as u16, (rng.range(0, 3) > 0) as u8);
        }
        kept[0] = 0;
        let refined: [u16; MAX_PIXELS] = core::array::from_fn(|i| 60_000 - i as u16);
        let mut out = refined;
        keep_rejected_map(w, &tokens[..rows * cells], &kept[..rows * cells], &mut out[..w * h]).unwrap();
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let expected = if kept[(y / 4) * cells + x / 4] == 0 {
                    ref_d0(&tokens[..rows * cells], w, h, y, x) as u16
                } else {
                    refined[i]
                };
                assert_eq!(out[i], expected, "{w}x{h} at ({y}, {x})");
            }
        }
        assert_eq!(out[w * h..], refined[w * h..], "past the map: untouched");
    }
}

#[test]
fn keeping_rejected_cells_checks_its_sizes() {
    let mut out = [0u16; 32];
    assert_eq!(keep_rejected_map(0, &[], &[], &mut out), Err(Error::EmptyImage));
    assert!(matches!(
        keep_rejected_map(5, &[0; 4], &[0; 4], &mut out[..32]),
        Err(Error::BufferSize { .. })
    ));
    assert!(matches!(
        keep_rejected_map(8, &[0; 4], &[0; 3], &mut out[..32]),
        Err(Error::BufferSize { .. })
    ));
    assert!(matches!(
        keep_rejected_map(8, &[0; 3], &[0; 4], &mut out[..32]),
        Err(Error::BufferSize { .. })
    ));
    let tokens = TokenRows {
        first: &[0; 2],
        second: &[0; 2],
    };
    assert!(matches!(
        keep_rejected_row(0, &tokens, &[0; 3], &mut out[..8]),
        Err(Error::BufferSize { .. })
    ));
    assert_eq!(keep_rejected_row(0, &tokens, &[1; 2], &mut out[..8]), Ok(()));
}
