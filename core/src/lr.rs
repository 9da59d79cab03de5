//! The left-right consistency check, one row at a time.
//!
//! The right view's readout needs no second pass over the descriptors: its cost of right cell
//! `q` at disparity `k` is the left cost of cell `q + k` at `k`, so a left cost row reindexed
//! gives the right view's row, which feeds the same WTA or SGM. A left cell is kept when the
//! right cell it lands on reads (nearly) the same disparity; the kept fraction is the paper's
//! `LRkeep`.

use crate::matching::{check_candidates, DISPARITY_FRAC_BITS, MAX_CANDIDATES};
use crate::sgm::{refine_min, COST_EXCLUDED};
use crate::Error;

/// The right view's cost row from the left view's (`cols x candidates`, candidates fastest):
/// `right[q][k] = left[q + k][k]`, [`COST_EXCLUDED`] where `q + k` is outside the row.
pub fn right_view_costs(left: &[u16], candidates: usize, out: &mut [u16]) -> Result<(), Error> {
    let cols = check_costs(left, candidates)?;
    Error::check_len("right-view cost row", left.len(), out.len())?;
    for (q, costs) in out.chunks_exact_mut(candidates).enumerate() {
        for (k, c) in costs.iter_mut().enumerate() {
            *c = if q + k < cols {
                left.get((q + k) * candidates + k).copied().unwrap_or(COST_EXCLUDED)
            } else {
                COST_EXCLUDED
            };
        }
    }
    Ok(())
}

/// Winner-takes-all on a cost row: each cell's first minimum refined by a parabola, Q8
/// patch columns (the same refinement as the SGM readout).
pub fn wta_costs(costs: &[u16], candidates: usize, out: &mut [u16]) -> Result<(), Error> {
    let cols = check_costs(costs, candidates)?;
    Error::check_len("disparity row", cols, out.len())?;
    let mut wide = [0u32; MAX_CANDIDATES];
    for (c, o) in costs.chunks_exact(candidates).zip(out.iter_mut()) {
        wide.iter_mut().zip(c).for_each(|(w, &v)| *w = v as u32);
        *o = refine_min(&wide[..candidates]);
    }
    Ok(())
}

/// Marks each left cell 1 when the right cell its disparity lands on (`p - round(d)`) reads a
/// disparity within `max_diff_q8` of it, else 0; returns the number kept.
pub fn consistent_row(left: &[u16], right: &[u16], max_diff_q8: u16, out: &mut [u8]) -> Result<usize, Error> {
    if right.len() != left.len() {
        return Err(Error::PairMismatch);
    }
    Error::check_len("left-right mask row", left.len(), out.len())?;
    let half = 1usize << (DISPARITY_FRAC_BITS - 1);
    let mut kept = 0;
    for (p, (&d, o)) in left.iter().zip(out.iter_mut()).enumerate() {
        let shift = (d as usize + half) >> DISPARITY_FRAC_BITS;
        let ok = p
            .checked_sub(shift)
            .and_then(|q| right.get(q))
            .is_some_and(|&r| r.abs_diff(d) <= max_diff_q8);
        *o = ok as u8;
        kept += ok as usize;
    }
    Ok(kept)
}

/// How a `+lr` readout fills the cells its left-right check rejected, chosen per readout on the
/// held-out labeled pairs (`train/experiments.json`, `background_fill`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fill {
    /// The nearest kept cell to the left ([`fill_rejected`]): the heads' and the descriptor
    /// matchers' readouts, whose rejected cells are mostly their own mismatches.
    FromLeft,
    /// The lower of the kept cells around a rejected run ([`fill_background`]): the readouts
    /// with the census in them, whose rejected cells are mostly occlusions.
    Background,
}

impl Fill {
    /// Fills `row`'s rejected cells (`consistent` 0) in place by this rule.
    pub fn apply<T: Copy + Default + PartialOrd>(self, row: &mut [T], consistent: &[u8]) -> Result<(), Error> {
        match self {
            Fill::FromLeft => fill_rejected(row, consistent),
            Fill::Background => fill_background(row, consistent),
        }
    }
}

/// [`Fill::FromLeft`]: each cell the left-right check rejected (`consistent` 0) takes the
/// disparity of the nearest kept cell to its left; rejected cells before the first kept one take
/// that one's; a row with no kept cell is all 0. In place. Generic so the host's float readouts
/// fill with this same definition (a copy of kept values, exact in any precision).
pub fn fill_rejected<T: Copy + Default>(row: &mut [T], consistent: &[u8]) -> Result<(), Error> {
    Error::check_len("left-right mask row", row.len(), consistent.len())?;
    let Some(first) = consistent.iter().position(|&k| k != 0) else {
        row.fill(T::default());
        return Ok(());
    };
    let mut carried = row.get(first).copied().unwrap_or_default();
    for (value, &kept) in row.iter_mut().zip(consistent) {
        if kept != 0 {
            carried = *value;
        } else {
            *value = carried;
        }
    }
    Ok(())
}

/// [`Fill::Background`]: each run of cells the left-right check rejected (`consistent` 0) takes
/// the lower of the two kept disparities around it, the nearest to its left and to its right (an
/// occlusion hides the farther surface beside a nearer one), or the one that exists at a row's
/// ends; a row with no kept cell is all 0. In place, generic as [`fill_rejected`].
pub fn fill_background<T: Copy + Default + PartialOrd>(row: &mut [T], consistent: &[u8]) -> Result<(), Error> {
    Error::check_len("left-right mask row", row.len(), consistent.len())?;
    // The nearest kept value left of the current run, and where the run starts.
    let mut before: Option<T> = None;
    let mut run = 0;
    for at in 0..=row.len() {
        let after = row.get(at).copied();
        if after.is_some() && consistent.get(at).is_some_and(|&k| k == 0) {
            continue;
        }
        let fill = match (before, after) {
            (Some(b), Some(a)) if a < b => a,
            (Some(v), _) | (None, Some(v)) => v,
            (None, None) => T::default(),
        };
        if let Some(cells) = row.get_mut(run..at) {
            cells.fill(fill);
        }
        before = after;
        run = at + 1;
    }
    Ok(())
}

/// The head's share, in 256ths, of a fused cell where both the head and SGM pass their checks
/// ([`fuse_row`]), for views `width` px wide: 160 (0.625) up to
/// [`FUSE_HEAD_HEAVY_MAX_WIDTH`], 128 (the midpoint) above. Chosen on the held-out labeled
/// pairs and the synthetic folders (`train/experiments.json`, `fused_weight`): at 160 px 0.625
/// beats the midpoint on all three sets, at 320 px the midpoint beats 0.625 and 0.75 on two of
/// three. The pipeline and the host both take it from here.
pub const fn fuse_head_weight(width: usize) -> u8 {
    if width <= FUSE_HEAD_HEAVY_MAX_WIDTH {
        160
    } else {
        128
    }
}

/// Widest view (px) whose fused readout leans on the head ([`fuse_head_weight`]).
pub const FUSE_HEAD_HEAVY_MAX_WIDTH: usize = 160;

/// One method's row as [`fuse_row`] reads it: Q8 disparities and their left-right mask (1 =
/// kept).
#[derive(Debug, Clone, Copy)]
pub struct CheckedRow<'r> {
    /// Disparity per cell, Q8 patch columns.
    pub disparity_q8: &'r [u16],
    /// 1 where the method's own left-right check keeps the cell, else 0.
    pub kept: &'r [u8],
}

/// How far the head's confidence moves its share in [`fuse_row`]: a quarter of (confidence -
/// 1/2), i.e. the share in 1024ths is `4 * head_weight + confidence_q8 - 128`. Chosen on the
/// held-out labeled pairs and the synthetic folders (`train/experiments.json`,
/// `fused_confidence`): slopes 1/8 to 1/2 tried, 1/4 the steepest better than the fixed share on
/// all six sets.
pub const FUSE_CONFIDENCE_SLOPE_INV: u32 = 4;

/// The fused readout's row (`fuse+lr`): where both the head and SGM pass their own left-right
/// checks, their weighted mean in Q8 (rounded half up), the head's share `head_weight / 256`
/// moved by its confidence (`head_confidence`, Q8 largest candidate probability, the head row's
/// `confidence_q8`: see [`FUSE_CONFIDENCE_SLOPE_INV`]; a head sure of its answer weighs more);
/// where one passes, its disparity; where neither does, the head's, marked rejected (0) for
/// [`fill_rejected`]. Masks are 1 = kept. Returns the number of cells kept. The two methods fail
/// in different places (SGM on slanted and thin structures, the head where its reach or the
/// texture runs out), so their checked mean is better than either on every validation set.
pub fn fuse_row(
    head: CheckedRow<'_>,
    head_confidence: &[u16],
    sgm: CheckedRow<'_>,
    head_weight: u8,
    out: &mut [u16],
    out_kept: &mut [u8],
) -> Result<usize, Error> {
    let cols = head.disparity_q8.len();
    if sgm.disparity_q8.len() != cols {
        return Err(Error::PairMismatch);
    }
    Error::check_len("head mask row", cols, head.kept.len())?;
    Error::check_len("head confidence row", cols, head_confidence.len())?;
    Error::check_len("SGM mask row", cols, sgm.kept.len())?;
    Error::check_len("fused disparity row", cols, out.len())?;
    Error::check_len("fused mask row", cols, out_kept.len())?;
    const FULL: u32 = 1024;
    let base = FUSE_CONFIDENCE_SLOPE_INV * head_weight as u32;
    let mut kept = 0;
    let cells = head.disparity_q8.iter().zip(head.kept).zip(head_confidence);
    let cells = cells.zip(sgm.disparity_q8.iter().zip(sgm.kept));
    for ((((&h, &hk), &c), (&s, &sk)), (o, ok)) in cells.zip(out.iter_mut().zip(out_kept.iter_mut())) {
        *o = match (hk != 0, sk != 0) {
            (true, true) => {
                // The head's share in 1024ths, kept inside [0, 1024]; at most 65535 * 1024 + 512
                // before the shift: u32, and the result fits a u16.
                let w = (base + c as u32).saturating_sub(128).min(FULL);
                ((h as u32 * w + s as u32 * (FULL - w) + FULL / 2) >> 10) as u16
            }
            (false, true) => s,
            _ => h,
        };
        *ok = u8::from(hk != 0 || sk != 0);
        kept += usize::from(*ok);
    }
    Ok(kept)
}

fn check_costs(costs: &[u16], candidates: usize) -> Result<usize, Error> {
    check_candidates(candidates)?;
    if costs.is_empty() {
        return Err(Error::EmptyImage);
    }
    if !costs.len().is_multiple_of(candidates) {
        return Err(Error::BufferSize {
            what: "cost row",
            expected: costs.len() / candidates * candidates,
            found: costs.len(),
        });
    }
    Ok(costs.len() / candidates)
}

#[cfg(test)]
mod tests {
    use super::*;

    const X: u16 = COST_EXCLUDED;

    #[test]
    fn right_costs_are_the_left_costs_reindexed() {
        // 3 cells, 2 candidates: left[p][k].
        let left = [10, X, 20, 21, 30, 31];
        let mut right = [0u16; 6];
        right_view_costs(&left, 2, &mut right).unwrap();
        // right[q][0] = left[q][0]; right[q][1] = left[q + 1][1].
        assert_eq!(right, [10, 21, 20, 31, 30, X]);
    }

    #[test]
    fn a_consistent_shift_is_kept_and_a_lone_outlier_is_not() {
        // Left cells 2..4 read disparity 2 (Q8 512) and land on right cells 0..2, which agree.
        // Cells 0 and 1 (disparities 0 and 1) land on right cell 0 too, which reads 2.
        let left = [0, 256, 512, 512, 512];
        let right = [512, 512, 512, 0, 0];
        let mut mask = [9u8; 5];
        let kept = consistent_row(&left, &right, 128, &mut mask).unwrap();
        assert_eq!(mask, [0, 0, 1, 1, 1]);
        assert_eq!(kept, 3);
        // A wider tolerance admits cell 1 (one column off).
        assert_eq!(consistent_row(&left, &right, 256, &mut mask), Ok(4));
        // A disparity pointing outside the view is never kept.
        assert_eq!(consistent_row(&[768], &[768], 128, &mut mask[..1]), Ok(0));
    }

    #[test]
    fn rejected_cells_take_the_nearest_kept_value_to_their_left() {
        let mut row = [10, 20, 30, 40, 50];
        fill_rejected(&mut row, &[0, 1, 0, 0, 1]).unwrap();
        assert_eq!(row, [20, 20, 20, 20, 50]);
        let mut none = [7, 8];
        fill_rejected(&mut none, &[0, 0]).unwrap();
        assert_eq!(none, [0, 0]);
        assert!(matches!(fill_rejected(&mut none, &[1]), Err(Error::BufferSize { .. })));
    }

    #[test]
    fn background_fill_takes_the_lower_of_a_runs_kept_neighbours() {
        let mut row = [10, 50, 30, 40, 20, 60];
        Fill::Background.apply(&mut row, &[1, 1, 0, 0, 1, 0]).unwrap();
        assert_eq!(
            row,
            [10, 50, 20, 20, 20, 20],
            "the right one is lower; a row's end takes its only one"
        );
        let mut row = [10, 50, 30, 40, 20, 60];
        Fill::FromLeft.apply(&mut row, &[1, 1, 0, 0, 1, 0]).unwrap();
        assert_eq!(row, [10, 50, 50, 50, 20, 20]);
        let mut row = [9, 30, 9, 9, 20];
        fill_background(&mut row, &[0, 1, 0, 0, 1]).unwrap();
        assert_eq!(row, [30, 30, 20, 20, 20], "leading cells take the first kept one");
        let mut none = [7, 8];
        fill_background(&mut none, &[0, 0]).unwrap();
        assert_eq!(none, [0, 0]);
        assert!(matches!(
            fill_background(&mut none, &[1]),
            Err(Error::BufferSize { .. })
        ));
    }

    #[test]
    fn wta_on_costs_takes_the_first_minimum() {
        let costs = [5, 1, 5, 3, 3, 9];
        let mut out = [0u16; 2];
        wta_costs(&costs, 3, &mut out).unwrap();
        assert_eq!(out[0], 256, "symmetric neighbours: no parabola step");
        assert_eq!(out[1] >> 8, 0, "tie goes to the first candidate");
    }

    #[test]
    fn bad_shapes_are_errors() {
        let mut out = [0u16; 4];
        assert!(matches!(
            right_view_costs(&[0; 5], 2, &mut out),
            Err(Error::BufferSize { .. })
        ));
        assert!(matches!(wta_costs(&[0; 4], 0, &mut out), Err(Error::Candidates { .. })));
        assert!(matches!(wta_costs(&[], 2, &mut out), Err(Error::EmptyImage)));
        let mut mask = [0u8; 3];
        assert_eq!(consistent_row(&[0; 3], &[0; 2], 0, &mut mask), Err(Error::PairMismatch));
        assert!(matches!(
            consistent_row(&[0; 2], &[0; 2], 0, &mut mask),
            Err(Error::BufferSize { .. })
        ));
    }

    #[test]
    fn the_fused_readout_leans_on_the_head_at_160_px_only() {
        assert_eq!(fuse_head_weight(160), 160);
        assert_eq!(fuse_head_weight(96), 160);
        assert_eq!(fuse_head_weight(161), 128);
        assert_eq!(fuse_head_weight(320), 128);
    }

    fn row<'r>(disparity_q8: &'r [u16], kept: &'r [u8]) -> CheckedRow<'r> {
        CheckedRow { disparity_q8, kept }
    }

    #[test]
    fn fusion_averages_where_both_pass_and_keeps_the_one_that_passes() {
        let head = [256, 512, 300, 700, 65535];
        let sgm = [257, 1024, 900, 100, 65535];
        let (head_kept, sgm_kept) = ([1, 1, 0, 0, 1], [1, 0, 1, 0, 1]);
        // Confidence 1/2 leaves the share as it is.
        let half = [128u16; 5];
        let (mut out, mut kept) = ([0u16; 5], [9u8; 5]);
        let (h, s) = (row(&head, &head_kept), row(&sgm, &sgm_kept));
        assert_eq!(fuse_row(h, &half, s, 128, &mut out, &mut kept), Ok(4));
        assert_eq!(
            out,
            [257, 512, 900, 700, 65535],
            "half up; one; the other; head; no overflow"
        );
        assert_eq!(kept, [1, 1, 1, 0, 1]);
        // 160 / 256 of the head: 0.625 * 256 + 0.375 * 1280 = 640.
        let (mut weighted, mut kept) = ([0u16; 1], [0u8; 1]);
        let fuse = |h: u16, c: u16, s: u16, w: u8, out: &mut [u16; 1], kept: &mut [u8; 1]| {
            fuse_row(row(&[h], &[1]), &[c], row(&[s], &[1]), w, out, kept)
        };
        assert_eq!(fuse(256, 128, 1280, 160, &mut weighted, &mut kept), Ok(1));
        assert_eq!(weighted, [640]);
        // A sure head weighs more, an unsure one less: (0.5 +- 0.125) of the head's 0 px.
        fuse(0, 255, 1024, 128, &mut weighted, &mut kept).unwrap();
        assert_eq!(weighted, [385], "share 639/1024");
        fuse(0, 0, 1024, 128, &mut weighted, &mut kept).unwrap();
        assert_eq!(weighted, [640], "share 384/1024");
        // The share stays inside [0, 1]: all head, all SGM, no overflow.
        fuse(65535, 255, 0, 255, &mut weighted, &mut kept).unwrap();
        assert_eq!(weighted, [65535]);
        fuse(65535, 0, 7, 0, &mut weighted, &mut kept).unwrap();
        assert_eq!(weighted, [7]);
        let h = row(&head, &head_kept);
        assert_eq!(
            fuse_row(h, &half, row(&sgm[..4], &sgm_kept[..4]), 128, &mut out, &mut [0u8; 5]),
            Err(Error::PairMismatch)
        );
        let s = row(&sgm, &sgm_kept);
        assert!(fuse_row(row(&head, &head_kept[..4]), &half, s, 128, &mut out, &mut [0u8; 5]).is_err());
        assert!(fuse_row(h, &half[..4], s, 128, &mut out, &mut [0u8; 5]).is_err());
        assert!(fuse_row(h, &half, s, 128, &mut out[..4], &mut [0u8; 5]).is_err());
    }
}
