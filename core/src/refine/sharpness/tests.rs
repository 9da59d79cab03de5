//! Tests of the sharpness equalisation: the box filter and the decision against whole-image
//! forms of the module docs' rules, the streaming window and refiner against the whole map,
//! and the Python fixture.

use super::*;
use crate::refine::scratch_len;
use crate::testutil::Rng;

/// `box(v, k)` of a whole image, straight from rule 1.
fn box_image(v: &[u8], w: usize, h: usize, k: usize) -> [u8; 24 * 20] {
    let mut out = [0u8; 24 * 20];
    let n = ((2 * k + 1) * (2 * k + 1)) as u32;
    for y in 0..h {
        for x in 0..w {
            let mut sum = 0u32;
            for dy in 0..=2 * k {
                for dx in 0..=2 * k {
                    let yy = (y + dy).saturating_sub(k).min(h - 1);
                    let xx = (x + dx).saturating_sub(k).min(w - 1);
                    sum += v[yy * w + xx] as u32;
                }
            }
            out[y * w + x] = ((sum + n / 2) / n) as u8;
        }
    }
    out
}

#[test]
fn box_rows_equal_the_window_mean_with_clamped_edges() {
    // Rows narrower than the window too (every column clamped at both ends).
    for w in [24, 1, 2, 3, 5] {
        let h = 20;
        let mut rng = Rng::new(5 + w as u64);
        let mut image = [0u8; 24 * 20];
        for p in image.iter_mut() {
            *p = (rng.next_u64() >> 24) as u8;
        }
        for k in 0..=MAX_RADIUS {
            let want = box_image(&image, w, h, k);
            for y in 0..h {
                let mut rows: [&[u8]; 2 * MAX_RADIUS + 1] = [&[]; 2 * MAX_RADIUS + 1];
                for (i, r) in rows.iter_mut().enumerate().take(2 * k + 1) {
                    let v = (y + i).saturating_sub(k).min(h - 1);
                    *r = &image[v * w..(v + 1) * w];
                }
                let mut out = [0u8; 24];
                box_row(&rows[..2 * k + 1], k, &mut out[..w]).unwrap();
                assert_eq!(out[..w], want[y * w..(y + 1) * w], "width {w}, radius {k}, row {y}");
            }
        }
    }
}

#[test]
fn the_window_division_by_a_multiply_is_exact_over_its_range() {
    for sum in 0..=9 * 255 {
        assert_eq!(div_rounded::<1>(sum) as u32, (sum + 4) / 9, "{sum}");
    }
    for sum in 0..=25 * 255 {
        assert_eq!(div_rounded::<2>(sum) as u32, (sum + 12) / 25, "{sum}");
    }
}

#[test]
fn box_row_refuses_bad_shapes() {
    let row = [1u8; 8];
    let mut out = [0u8; 8];
    assert!(matches!(box_row(&[&row], 3, &mut out), Err(Error::OutOfRange { .. })));
    assert!(matches!(box_row(&[&row], 1, &mut out), Err(Error::BufferSize { .. })));
    assert!(matches!(
        box_row(&[&row, &row[..7], &row], 1, &mut out),
        Err(Error::BufferSize { .. })
    ));
    assert!(matches!(box_row(&[&[]], 0, &mut []), Err(Error::EmptyImage)));
    let wide = [0u8; MAX_ROW + 1];
    let mut wide_out = [0u8; MAX_ROW + 1];
    assert!(matches!(
        box_row(&[&wide], 0, &mut wide_out),
        Err(Error::BufferSize { .. })
    ));
}

#[test]
fn gradient_sum_adds_absolute_steps() {
    assert_eq!(gradient_sum(&[0, 10, 4, 4, 255]), 10 + 6 + 251);
    assert_eq!(gradient_sum(&[7]), 0);
    assert_eq!(gradient_sum(&[]), 0);
}

#[test]
fn decide_blurs_the_sharper_view_to_the_closest_radius_beyond_the_margin() {
    // Equal: nothing. Left 20 % sharper: inside the 25 % margin.
    assert_eq!(decide(&[100, 60, 40], &[100, 60, 40], MARGIN_PCT, None), Decision::NONE);
    assert_eq!(decide(&[120, 70, 50], &[100, 60, 40], MARGIN_PCT, None).radius, 0);
    // Right twice as sharp: radius 1 brings it to 100 exactly.
    assert_eq!(
        decide(&[100, 60, 40], &[200, 100, 70], MARGIN_PCT, None),
        Decision { right: true, radius: 1 }
    );
    // Left three times as sharp: radius 2 (110) is closer to 100 than radius 1 (180).
    assert_eq!(
        decide(&[300, 180, 110], &[100, 60, 40], MARGIN_PCT, None),
        Decision {
            right: false,
            radius: 2
        }
    );
    // Ties go to the smaller radius; ties of the views to the left.
    assert_eq!(decide(&[200, 150, 50], &[100, 0, 0], 0, None).radius, 1);
    assert!(!decide(&[100, 0, 0], &[100, 0, 0], 0, None).right);
    // Saturating, never overflowing.
    assert_eq!(decide(&[u64::MAX, 1, 0], &[1, 0, 0], 0, None).radius, 1);
}

#[test]
fn a_view_sharper_at_every_scale_alike_has_more_contrast_and_is_not_blurred() {
    let c = Some(CONTRAST_MARGIN_PCT);
    // Right twice the left at every scale (less contrast on the left): rule 4 alone blurs
    // the right, rule 4a keeps it (200 * 40 * 100 <= 100 * 80 * 115).
    let (left, flat) = ([100, 60, 40], [200, 120, 80]);
    assert_eq!(
        decide(&left, &flat, MARGIN_PCT, None),
        Decision { right: true, radius: 1 }
    );
    assert_eq!(decide(&left, &flat, MARGIN_PCT, c), Decision { right: true, radius: 0 });
    // Right sharper at the fine scale only (the left defocused): blurred as before.
    let fine = [200, 100, 45];
    assert_eq!(decide(&left, &fine, MARGIN_PCT, c), Decision { right: true, radius: 1 });
    // The margin: 200 * 40 * 100 against 100 * x * 115 decides at x = 69.56...
    assert_eq!(decide(&left, &[200, 100, 69], MARGIN_PCT, c).radius, 1);
    assert_eq!(decide(&left, &[200, 100, 70], MARGIN_PCT, c).radius, 0);
    // Saturating, never overflowing.
    assert_eq!(decide(&[u64::MAX; 3], &[1, 0, 0], 0, Some(u64::MAX)).radius, 0);
    assert_eq!(decide(&[u64::MAX, 1, 0], &[1, 0, u64::MAX], 0, c).radius, 1);
}

fn window_rows(view: &[u8], w: usize, h: usize, y: usize) -> [&[u8]; DECISION_ROWS] {
    core::array::from_fn(|e| {
        let v = window_row(y, e, DECISION_REACH, h);
        &view[v * w..(v + 1) * w]
    })
}

#[test]
fn the_streaming_window_decides_as_the_whole_map_in_any_row_order() {
    let (w, h) = (24usize, 20usize);
    let mut rng = Rng::new(9);
    let mut sharp = [0u8; 24 * 20];
    for p in sharp.iter_mut() {
        *p = (rng.next_u64() >> 24) as u8;
    }
    // The right view blurred (radius 2) in its lower half only: decisions change down the map.
    let blurred = box_image(&sharp, w, h, 2);
    let mut right = sharp;
    right[10 * w..].copy_from_slice(&blurred[10 * w..h * w]);
    let left = &sharp[..];
    let mut window = SharpnessWindow::new(w, h).unwrap();
    let order = (0..h).chain([5, 19, 0, 12, 12, 3]);
    let mut seen = [false; 2];
    for y in order {
        let (l, r) = (window_rows(left, w, h, y), window_rows(&right, w, h, y));
        let found = window.decide(y, &l, &r).unwrap();
        assert_eq!(found, decide_map_row(left, &right, w, h, y).unwrap(), "row {y}");
        seen[(found.radius > 0) as usize] = true;
    }
    assert_eq!(seen, [true, true], "rows with and without blur");
    assert!(matches!(window.decide(h, &[], &[]), Err(Error::OutOfRange { .. })));
    assert!(matches!(window.decide(0, &[], &[]), Err(Error::BufferSize { .. })));
    assert!(matches!(
        SharpnessWindow::new(MAX_ROW + 1, 4),
        Err(Error::TooWide { .. })
    ));
}

fn eq_window(view: &[u8], w: usize, h: usize, y: usize, wide: usize) -> [&[u8]; MAX_EQUALISED_ROWS] {
    core::array::from_fn(|e| {
        let v = window_row(y, e.min(2 * wide), wide, h);
        &view[v * w..(v + 1) * w]
    })
}

#[test]
fn the_equalised_refiner_gives_the_reference_rows_in_any_order() {
    let (w, h) = (24usize, 20usize);
    let mut rng = Rng::new(12);
    let mut base = [0u8; 28 * 20];
    for p in base.iter_mut() {
        *p = (rng.next_u64() >> 24) as u8;
    }
    let mut left = [0u8; 24 * 20];
    let mut sharp_right = [0u8; 24 * 20];
    for y in 0..h {
        left[y * w..(y + 1) * w].copy_from_slice(&base[y * 28..y * 28 + w]);
        sharp_right[y * w..(y + 1) * w].copy_from_slice(&base[y * 28 + 3..y * 28 + 3 + w]);
    }
    // The right view defocused below row 8, the left one above row 4: every kind of row.
    let blurred_right = box_image(&sharp_right, w, h, 2);
    let blurred_left = box_image(&left, w, h, 1);
    let mut right = sharp_right;
    right[8 * w..].copy_from_slice(&blurred_right[8 * w..h * w]);
    left[..4 * w].copy_from_slice(&blurred_left[..4 * w]);
    let (grid_rows, cells) = (h.div_ceil(4), w.div_ceil(4));
    let mut grid = [0u16; 5 * 6];
    for g in grid.iter_mut() {
        *g = (3 * 64 + rng.range(0, 96)) as u16;
    }
    let params = RefineParams::DEFAULT;
    let mut want = [0u16; 24 * 20];
    let mut s_ref = [0u32; scratch_len(24, &RefineParams::DEFAULT)];
    let n = scratch_len(w, &params);
    refine_map_equalised(&left, &right, w, &grid, &params, &mut s_ref[..n], &mut want).unwrap();
    let wide = equalised_reach(&params);
    let (mut census, mut smoothed) = (
        [0u32; scratch_len(24, &RefineParams::DEFAULT)],
        [0u8; smoothed_len(24, &RefineParams::DEFAULT)],
    );
    let mut refiner = EqualisedRefiner::new(
        &mut census[..n],
        &mut smoothed[..smoothed_len(w, &params)],
        w,
        h,
        &params,
    )
    .unwrap();
    let mut kinds = [false; 3];
    for y in (0..h).chain([7, 3, 19, 0, 9, 9, 4]) {
        let (wl, wr) = (eq_window(&left, w, h, y, wide), eq_window(&right, w, h, y, wide));
        let rows = ViewRows {
            height: h,
            left: &wl[..2 * wide + 1],
            right: &wr[..2 * wide + 1],
        };
        let (a, b) = token_rows(y, grid_rows);
        let tokens = TokenRows {
            first: &grid[a * cells..(a + 1) * cells],
            second: &grid[b * cells..(b + 1) * cells],
        };
        let mut got = [0u16; 24];
        refiner.refine_row(y, &rows, &tokens, &mut got).unwrap();
        assert_eq!(got[..], want[y * w..(y + 1) * w], "row {y}");
        let d = decide_map_row(&left, &right, w, h, y).unwrap();
        kinds[if d.radius == 0 { 0 } else { 1 + d.right as usize }] = true;
    }
    assert_eq!(kinds, [true, true, true], "plain rows and rows blurring each view");
}

/// `train/bino_train/sharpness.py` (`refine_equalised`) wrote these cases:
/// `python -m bino_train.sharpness --fixture ../tests/fixtures/refine/equalised.bin`.
#[test]
fn matches_the_python_fixture_bit_for_bit() {
    const FIXTURE: &[u8] = include_bytes!("../../../../tests/fixtures/refine/equalised.bin");
    let mut blurred = [false; 2];
    let mut vetoed = false;
    let cases = crate::refine::fixture::for_each_case(FIXTURE, b"BRE1", |i, case| {
        let (w, h, n) = (case.width, case.height, case.width * case.height);
        assert!(n <= 16 * 24);
        for y in 0..h {
            let d = decide_map_row(case.left, case.right, w, h, y).unwrap();
            if d.radius > 0 {
                blurred[d.right as usize] = true;
            }
        }
        let mut tokens = [0u16; 4 * 6];
        let tokens = case.tokens(&mut tokens);
        let mut scratch = [0u32; scratch_len(24, &RefineParams::DEFAULT)];
        let scratch = &mut scratch[..crate::refine::scratch_len(w, &case.params)];
        let mut out = [0u16; 16 * 24];
        refine_map_equalised(case.left, case.right, w, tokens, &case.params, scratch, &mut out[..n]).unwrap();
        case.check(i, &out[..n]);
        vetoed |= (0..h).any(|y| {
            let [l, r] = map_window_sums(case.left, case.right, w, h, y).unwrap();
            decide(&l, &r, MARGIN_PCT, None).radius > 0
                && decide_map_row(case.left, case.right, w, h, y).unwrap().radius == 0
        });
    });
    assert!(cases >= 4);
    assert_eq!(blurred, [true, true], "the cases blur each view somewhere");
    assert!(vetoed, "a case where rule 4a keeps a blur rule 4 would make");
}
