//! The no-linkage readout in integers, one descriptor row at a time: each left cell is compared
//! by cosine similarity with the right cells 0 .. `max_cols - 1` patch columns to its left, the
//! first maximum wins, and a parabola through its neighbours refines it to 1/256 column.
//!
//! Streaming: a row needs only its own left and right descriptors (int8 codes) and a scratch of
//! one inverse norm per right cell, so a pipeline can match each descriptor row as the encoder
//! emits it; the similarity volume is never stored. The left cell's norm is a common factor of
//! its candidates, so it changes neither the winner nor the parabola and is not computed.

use crate::config::DIM;
use crate::fixed::isqrt_u64;
use crate::Error;

/// The descriptor length as the loops see it: on Cortex-M55 (MVE) an opaque run-time value, so
/// LLVM emits one tail-predicated 16-lane `vmladav.s8` loop per dot product rather than
/// unrolling a constant 128 into 32-bit lanes (as in the attention kernel); the value is [`DIM`]
/// either way, which every bound below relies on.
#[inline(always)]
fn dim() -> usize {
    crate::kernels::dispatch::loop_len(DIM)
}

/// Most disparity candidates one cell may have.
pub const MAX_CANDIDATES: usize = 64;
/// Cosine similarity unit of the costs: `cost = COST_ONE * (1 - cos)`, in `0..=2 * COST_ONE`.
pub const COST_ONE: u16 = 4096;
/// The cost of a candidate outside the right view.
pub const COST_EXCLUDED: u16 = 2 * COST_ONE;
/// Fraction bits of the matched disparity (patch columns, Q8).
pub const DISPARITY_FRAC_BITS: u32 = 8;
/// `2^INV_NORM_BITS / |r|` is the fixed-point inverse norm of a right descriptor.
const INV_NORM_BITS: u32 = 30;

/// `round(2^30 / |d|)` for each [`DIM`]-code descriptor of `row` into `out` (0 for an all-zero
/// descriptor, whose similarities are then 0, as with `F.normalize`).
pub fn inverse_norms(row: &[i8], out: &mut [u32]) -> Result<(), Error> {
    let cells = check_row(row)?;
    Error::check_len("inverse norms", cells, out.len())?;
    for (d, o) in row.chunks_exact(dim()).zip(out.iter_mut()) {
        let sum_sq: u64 = d.iter().map(|&x| (x as i32 * x as i32) as u64).sum();
        // |d|^2 <= DIM * 2^14; the square root keeps 16 fraction bits via a 2^32 prescale.
        let norm_q16 = isqrt_u64(sum_sq << 32) as u64;
        let scaled = (1u64 << (INV_NORM_BITS + 16)) + norm_q16 / 2;
        *o = scaled.checked_div(norm_q16).map_or(0, |inv| inv as u32);
    }
    Ok(())
}

/// Matches one row: `left` and `right` are `cols x DIM` codes of the same token row,
/// `right_inv_norms` comes from [`inverse_norms`] of `right`; writes each left cell's
/// disparity in Q8 patch columns to `out` (`cols` entries).
///
/// No value overflows for any codes and norms: `|dot| <= DIM * 2^14 = 2^21`, so each
/// similarity is below `2^53` and the parabola's terms below `2^63`.
pub fn match_row(
    left: &[i8],
    right: &[i8],
    right_inv_norms: &[u32],
    max_cols: usize,
    out: &mut [u16],
) -> Result<(), Error> {
    let cells = check_pair(left, right, right_inv_norms, max_cols)?;
    Error::check_len("disparity row", cells, out.len())?;
    let mut sims = [0i64; MAX_CANDIDATES];
    let dim = dim();
    for (p, (l, o)) in left.chunks_exact(dim).zip(out.iter_mut()).enumerate() {
        let candidates = max_cols.min(p + 1);
        for (k, s) in sims.iter_mut().enumerate().take(candidates) {
            let q = p - k;
            let r = right.get(q * dim..(q + 1) * dim).unwrap_or_default();
            let dot: i32 = l.iter().zip(r).map(|(&a, &b)| a as i32 * b as i32).sum();
            *s = dot as i64 * right_inv_norms.get(q).copied().unwrap_or(0) as i64;
        }
        *o = refine(&sims[..candidates], max_cols);
    }
    Ok(())
}

/// One row of SGM costs (`cols x max_cols`, candidates fastest): `COST_ONE * (1 - cos)` of
/// each left cell against the right cell `k` columns to its left, `COST_EXCLUDED` where that
/// is outside the view. Both rows' inverse norms come from [`inverse_norms`]; any `u32` norms
/// are safe (`|dot| <= 2^21`, so the products below stay under `2^62`).
pub fn cost_row(
    left: &[i8],
    right: &[i8],
    left_inv_norms: &[u32],
    right_inv_norms: &[u32],
    max_cols: usize,
    out: &mut [u16],
) -> Result<(), Error> {
    let cells = check_pair(left, right, right_inv_norms, max_cols)?;
    Error::check_len("left inverse norms", cells, left_inv_norms.len())?;
    Error::check_len("cost row", cells.saturating_mul(max_cols), out.len())?;
    let dim = dim();
    for (p, (l, costs)) in left.chunks_exact(dim).zip(out.chunks_exact_mut(max_cols)).enumerate() {
        let inv_l = left_inv_norms.get(p).copied().unwrap_or(0) as i64;
        for (k, c) in costs.iter_mut().enumerate() {
            let Some(q) = p.checked_sub(k) else {
                *c = COST_EXCLUDED;
                continue;
            };
            let r = right.get(q * dim..(q + 1) * dim).unwrap_or_default();
            let dot: i32 = l.iter().zip(r).map(|(&a, &b)| a as i32 * b as i32).sum();
            let inv_r = right_inv_norms.get(q).copied().unwrap_or(0) as i64;
            // dot * 2^60 / (|l| |r|) taken down to Q12 in two steps that stay below 2^52.
            let cos_q12 = (((dot as i64 * inv_l) >> 24) * inv_r) >> 24;
            *c = (COST_ONE as i64 - cos_q12).clamp(0, COST_EXCLUDED as i64) as u16;
        }
    }
    Ok(())
}

/// First maximum plus the parabola step (clamped to half a column), taken only when both
/// neighbours are inside the candidate range and the parabola opens downwards; Q8.
fn refine(sims: &[i64], max_cols: usize) -> u16 {
    let mut best = 0;
    for (k, &s) in sims.iter().enumerate() {
        if s > sims[best] {
            best = k;
        }
    }
    let base = (best as i64) << DISPARITY_FRAC_BITS;
    let step = match (best.checked_sub(1).and_then(|k| sims.get(k)), sims.get(best + 1)) {
        // The float readout's candidate range is max_cols wide even where fewer exist: a
        // winner at its last slot has no right neighbour there either.
        (Some(&l), Some(&r)) if best + 1 < max_cols => {
            let at = sims[best];
            let denom = l - 2 * at + r;
            if denom < 0 {
                let half = 1i64 << (DISPARITY_FRAC_BITS - 1);
                // (l - r) / (2 denom) in Q8, rounded to nearest.
                let num = (l - r) << DISPARITY_FRAC_BITS;
                let den = 2 * denom;
                let half_den = den.abs() / 2;
                let q = if num >= 0 { num + half_den } else { num - half_den } / den;
                q.clamp(-half, half)
            } else {
                0
            }
        }
        _ => 0,
    };
    (base + step).clamp(0, u16::MAX as i64) as u16
}

/// What [`match_row`] and [`cost_row`] both need: a well-formed left row, a right row of the
/// same length with its inverse norms, and a supported candidate count; returns the cells.
fn check_pair(left: &[i8], right: &[i8], right_inv_norms: &[u32], max_cols: usize) -> Result<usize, Error> {
    let cells = check_row(left)?;
    if right.len() != left.len() {
        return Err(Error::PairMismatch);
    }
    Error::check_len("right inverse norms", cells, right_inv_norms.len())?;
    check_candidates(max_cols)?;
    Ok(cells)
}

/// `1..=MAX_CANDIDATES` disparity candidates.
pub(crate) fn check_candidates(candidates: usize) -> Result<(), Error> {
    if (1..=MAX_CANDIDATES).contains(&candidates) {
        Ok(())
    } else {
        Err(Error::Candidates {
            requested: candidates,
            max: MAX_CANDIDATES,
        })
    }
}

/// A row of whole [`DIM`]-code descriptors (the model's length: the bounds above rely on it).
fn check_row(row: &[i8]) -> Result<usize, Error> {
    if row.is_empty() {
        return Err(Error::EmptyImage);
    }
    if !row.len().is_multiple_of(DIM) {
        return Err(Error::BufferSize {
            what: "descriptor row",
            expected: row.len() / DIM * DIM,
            found: row.len(),
        });
    }
    Ok(row.len() / DIM)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::Rng;

    /// Right row = left row shifted by `shift` cells (new cells random): matches find it.
    #[test]
    fn recovers_a_known_shift_exactly() {
        let mut rng = Rng::new(4);
        let cols = 20;
        let mut right = [0i8; 20 * DIM];
        rng.fill_i8(&mut right);
        let shift = 3;
        let mut left = [0i8; 20 * DIM];
        rng.fill_i8(&mut left);
        for p in shift..cols {
            left[p * DIM..(p + 1) * DIM].copy_from_slice(&right[(p - shift) * DIM..(p - shift + 1) * DIM]);
        }
        let mut norms = [0u32; 20];
        inverse_norms(&right, &mut norms).unwrap();
        let mut out = [0u16; 20];
        match_row(&left, &right, &norms, 8, &mut out).unwrap();
        for (p, &d) in out.iter().enumerate().skip(shift) {
            // The winner is exact; random neighbours may pull the parabola a little.
            assert_eq!((d as i64 + 128) >> 8, shift as i64, "cell {p}: {d}");
        }
    }

    #[test]
    fn parabola_step_matches_the_float_formula() {
        // sims around the winner k = 2: l = 70, at = 100, r = 90 -> step (70 - 90) / (2 * -40) = 0.25.
        let sims = [10, 70, 100, 90, 20];
        assert_eq!(refine(&sims, 5), 2 * 256 + 64);
        // Winner at the edge of the range: no step.
        assert_eq!(refine(&[5, 9], 2), 256);
        // (1 - 3) / (2 * (1 - 10 + 3)) = 0.1667 -> 43/256, rounded to nearest.
        assert_eq!(refine(&[1, 5, 3], 3), 256 + 43);
        // Near the left border fewer candidates exist: a winner without a right neighbour
        // takes no step.
        assert_eq!(refine(&[1, 5], 3), 256);
        // A tie goes to the first maximum, whose parabola step is then exactly half a column.
        assert_eq!(refine(&[0, 100, 100], 3), 256 + 128);
        assert_eq!(refine(&[0, 100, 99], 3), 256 + 125);
    }

    #[test]
    fn costs_are_one_minus_cosine() {
        let mut rng = Rng::new(8);
        let mut left = [0i8; 3 * DIM];
        rng.fill_i8(&mut left);
        let mut right = left;
        right[DIM..2 * DIM].iter_mut().for_each(|x| *x = x.saturating_neg()); // cell 1 opposite
        let (mut nl, mut nr) = ([0u32; 3], [0u32; 3]);
        inverse_norms(&left, &mut nl).unwrap();
        inverse_norms(&right, &mut nr).unwrap();
        let mut cost = [0u16; 3 * 2];
        cost_row(&left, &right, &nl, &nr, 2, &mut cost).unwrap();
        assert!(cost[0] <= 2, "identical cells cost ~0: {cost:?}");
        assert_eq!(cost[1], COST_EXCLUDED, "cell 0 has no candidate 1");
        assert!(cost[2] >= 2 * COST_ONE - 2, "opposite cells cost ~2: {cost:?}");
        assert!(cost[4] <= 2);
    }

    #[test]
    fn zero_descriptors_have_zero_similarity() {
        let right = [0i8; 2 * DIM];
        let mut norms = [7u32; 2];
        inverse_norms(&right, &mut norms).unwrap();
        assert_eq!(norms, [0, 0]);
    }

    #[test]
    fn bad_shapes_are_errors() {
        let row = [1i8; 4 * DIM];
        let mut norms = [0u32; 4];
        let mut out = [0u16; 4];
        assert!(matches!(
            inverse_norms(&row[..DIM + 1], &mut norms),
            Err(Error::BufferSize { .. })
        ));
        assert!(matches!(
            inverse_norms(&row, &mut norms[..3]),
            Err(Error::BufferSize { .. })
        ));
        assert!(matches!(inverse_norms(&[], &mut norms), Err(Error::EmptyImage)));
        assert!(matches!(
            match_row(&row, &row[..2 * DIM], &norms, 4, &mut out),
            Err(Error::PairMismatch)
        ));
        assert!(matches!(
            match_row(&row, &row, &norms, 0, &mut out),
            Err(Error::Candidates { .. })
        ));
        assert!(matches!(
            match_row(&row, &row, &norms, MAX_CANDIDATES + 1, &mut out),
            Err(Error::Candidates { .. })
        ));
        assert!(matches!(
            match_row(&row, &row, &norms, 4, &mut out[..2]),
            Err(Error::BufferSize { .. })
        ));
    }

    /// Regression (fuzzing, issue 12): with a caller-chosen descriptor length the i32 dot
    /// product overflowed at 2^17 codes, and `cost_row` / the parabola overflowed for inverse
    /// norms `inverse_norms` never makes. The length is now the model's, and the extremes of
    /// codes and norms run through.
    #[test]
    fn extreme_codes_and_norms_do_not_overflow() {
        let mut left = [-128i8; 3 * DIM];
        let right = [-128i8; 3 * DIM];
        left[DIM..2 * DIM].fill(127);
        let norms = [u32::MAX; 3];
        let mut out = [0u16; 3];
        assert_eq!(match_row(&left, &right, &norms, 3, &mut out), Ok(()));
        let mut cost = [0u16; 3 * 3];
        assert_eq!(cost_row(&left, &right, &norms, &norms, 3, &mut cost), Ok(()));
        // Cell 0 is identical to right cell 0: any cosine above 1 saturates to cost 0.
        assert_eq!(cost[0], 0);
        assert!(cost.iter().all(|&c| c <= COST_EXCLUDED));
        // Parabola through the largest similarities these inputs can make.
        let big = (1i64 << 21) * u32::MAX as i64;
        assert!(refine(&[-big, big, -big], 3) <= 256 + 128);
        // Rows off the model's descriptor length are errors.
        let mut short_norms = [0u32; 1];
        assert!(matches!(
            inverse_norms(&left[..DIM / 2], &mut short_norms),
            Err(Error::BufferSize { .. })
        ));
    }
}
