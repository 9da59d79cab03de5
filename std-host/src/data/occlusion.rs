//! `bino eval --occlude 10,20,30,40`: the paper's one-view occlusion benchmark (section 3.6,
//! table "one-view occlusion"), adapted to the eval split. At test time the RIGHT view is covered
//! by token-aligned rectangles (edges on the 4x4 token grid) of mid-grey until exactly the given
//! share of its token cells is covered (the share rounded up to whole cells); the left view and
//! the ground truth are untouched, and every method sees the same images.
//!
//! One seeded sequence of rectangles per pair (SplitMix64 from the seed and the pair id) serves
//! every severity: the 20 % blocks contain the 10 % ones, so the curve over severities measures
//! more occlusion, not other occlusion. Summary per readout: clean, `Occ40` (at the largest
//! severity), `OccAUC` (mean over the non-zero severities) and `Δ40` (largest minus clean).
//!
//! ```
//! use bino_host::data::occlusion::occlude_right;
//! let right = vec![7u8; 64 * 32];
//! let out = occlude_right(&right, 64, 32, 25, 0, "pair").unwrap();
//! // 25 % of the 16 x 8 token cells, 4x4 pixels each, are mid-grey.
//! assert_eq!(out.iter().filter(|&&v| v == 128).count(), 32 * 16);
//! ```

use anyhow::{ensure, Result};

use crate::data::nuisance::OCCLUDE_FILL;
use crate::data::profile::View;
use crate::data::rng::{fnv1a, SplitMix64};
use crate::eval::EvalItem;
use crate::int8::to_u8;

/// Pixels per token cell side (`PATCH_H` rows, `CELL_W` columns).
const CELL: usize = bino_core::config::PATCH_H;
const _: () = assert!(bino_core::config::CELL_W == CELL, "square token cells");

/// Largest severity, in percent of the view's area.
pub const MAX_PERCENT: u32 = 90;

/// Each rectangle spans at most this fraction (1/n) of the token grid's width and height.
const MAX_SIDE_DIVISOR: usize = 5;

/// Checks severities: each in `1..=`[`MAX_PERCENT`], rising, none twice.
pub fn check_severities(percents: &[u32]) -> Result<()> {
    for (i, &p) in percents.iter().enumerate() {
        ensure!(
            (1..=MAX_PERCENT).contains(&p),
            "--occlude {p}: a severity is a percentage of the view's area from 1 to {MAX_PERCENT}"
        );
        ensure!(
            i == 0 || percents[i - 1] < p,
            "--occlude {}: severities must rise ({} then {p})",
            percents.iter().map(u32::to_string).collect::<Vec<_>>().join(","),
            percents[i - 1]
        );
    }
    Ok(())
}

/// The token cells covered at `percent`, in the order the pair's rectangles cover them:
/// `ceil(percent * cells / 100)` distinct cell indices (row-major on the `rows x cols` grid).
fn covered_cells(rows: usize, cols: usize, percent: u32, seed: u64, pair_id: &str) -> Vec<usize> {
    let cells = rows * cols;
    let target = (percent as usize * cells).div_ceil(100).min(cells);
    let mut rng = SplitMix64::new(fnv1a(pair_id.as_bytes()) ^ seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ 0x0cc1_0de5);
    let (max_w, max_h) = ((cols / MAX_SIDE_DIVISOR).max(1), (rows / MAX_SIDE_DIVISOR).max(1));
    let mut covered = vec![false; cells];
    let mut order = Vec::with_capacity(target);
    // Each rectangle covers at least one new cell with positive probability until the target
    // is reached; after many rectangles the rest is taken in raster order, so this ends.
    let mut rectangles = 0usize;
    while order.len() < target && rectangles < 64 * cells {
        rectangles += 1;
        let (w, h) = (1 + rng.below(max_w), 1 + rng.below(max_h));
        let (c0, r0) = (rng.below(cols - w + 1), rng.below(rows - h + 1));
        for r in r0..r0 + h {
            for c in c0..c0 + w {
                let i = r * cols + c;
                if !covered[i] && order.len() < target {
                    covered[i] = true;
                    order.push(i);
                }
            }
        }
    }
    for (i, done) in covered.iter_mut().enumerate() {
        if order.len() >= target {
            break;
        }
        if !*done {
            *done = true;
            order.push(i);
        }
    }
    order
}

/// `right` (`width x height` grey levels, sides multiples of 4) with `percent` of its token
/// cells filled mid-grey, from `seed` and `pair_id`.
pub fn occlude_right(
    right: &[u8],
    width: usize,
    height: usize,
    percent: u32,
    seed: u64,
    pair_id: &str,
) -> Result<Vec<u8>> {
    check_severities(&[percent])?;
    ensure!(
        right.len() == width * height
            && width.is_multiple_of(CELL)
            && height.is_multiple_of(CELL)
            && width > 0
            && height > 0,
        "a {width}x{height} view ({} pixels given) is not a grid of {CELL}x{CELL} token cells",
        right.len()
    );
    let (rows, cols) = (height / CELL, width / CELL);
    let mut out = right.to_vec();
    for cell in covered_cells(rows, cols, percent, seed, pair_id) {
        let (r, c) = (cell / cols, cell % cols);
        for y in r * CELL..(r + 1) * CELL {
            out[y * width + c * CELL..y * width + (c + 1) * CELL].fill(OCCLUDE_FILL);
        }
    }
    Ok(out)
}

/// `item` with its right view occluded at `percent` (the left view and the ground truth
/// untouched); the occluded view holds 8-bit levels (`k / 255`), as the pipeline's input does.
pub fn occlude_item(item: &EvalItem, percent: u32, seed: u64) -> Result<EvalItem> {
    let right = &item.right;
    let pixels = occlude_right(
        &to_u8(&right.pixels),
        right.width,
        right.height,
        percent,
        seed,
        &item.pair_id,
    )?;
    Ok(EvalItem {
        right: View {
            width: right.width,
            height: right.height,
            pixels: pixels.iter().map(|&v| v as f32 / 255.0).collect(),
        },
        ..item.clone()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn covered(out: &[u8]) -> Vec<bool> {
        out.iter().map(|&v| v == OCCLUDE_FILL).collect()
    }

    #[test]
    fn each_severity_covers_exactly_its_share_in_whole_token_cells() {
        for (w, h) in [(160, 96), (320, 192), (40, 24), (4, 4)] {
            let img = vec![7u8; w * h];
            let cells = (w / 4) * (h / 4);
            for p in [1, 10, 20, 30, 40, 90] {
                let out = occlude_right(&img, w, h, p, 3, "a").unwrap();
                let n = out.iter().filter(|&&v| v == OCCLUDE_FILL).count();
                assert_eq!(n, 16 * (p as usize * cells).div_ceil(100), "{w}x{h} at {p} %");
                // Token-aligned: every 4x4 cell is all covered or all clear.
                for r in 0..h / 4 {
                    for c in 0..w / 4 {
                        let first = out[r * 4 * w + c * 4];
                        for y in 0..4 {
                            let row = &out[(r * 4 + y) * w + c * 4..(r * 4 + y) * w + c * 4 + 4];
                            assert!(row.iter().all(|&v| v == first), "{w}x{h} {p} % cell ({r}, {c})");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn milder_severities_are_inside_harsher_ones_and_pairs_differ() {
        let (w, h) = (160, 96);
        let img = vec![7u8; w * h];
        let masks: Vec<Vec<bool>> = [10, 20, 30, 40]
            .iter()
            .map(|&p| covered(&occlude_right(&img, w, h, p, 0, "a").unwrap()))
            .collect();
        for pair in masks.windows(2) {
            assert!(pair[0].iter().zip(&pair[1]).all(|(&a, &b)| !a || b), "nested");
        }
        let a = occlude_right(&img, w, h, 20, 0, "a").unwrap();
        assert_eq!(a, occlude_right(&img, w, h, 20, 0, "a").unwrap(), "deterministic");
        assert_ne!(a, occlude_right(&img, w, h, 20, 0, "b").unwrap(), "pair ids differ");
        assert_ne!(a, occlude_right(&img, w, h, 20, 1, "a").unwrap(), "seeds differ");
    }

    #[test]
    fn bad_severities_and_views_are_errors() {
        assert!(check_severities(&[10, 20, 30, 40]).is_ok());
        for bad in [&[0][..], &[95], &[20, 10], &[10, 10]] {
            assert!(check_severities(bad).is_err(), "{bad:?}");
        }
        let err = occlude_right(&[0; 30], 6, 5, 10, 0, "p").unwrap_err().to_string();
        assert!(err.contains("6x5"), "{err}");
    }
}
