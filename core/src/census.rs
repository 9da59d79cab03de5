//! A classical second opinion beside the heads: census matching with SGM, needing no encoder.
//!
//! Per token row: the 5x5 census codes of both views' pixel rows, the Hamming distance of every
//! left pixel `x` and right pixel `x - d` at every pixel disparity `d`, summed over each 4x4
//! cell, give the left view's cost row; the same distances summed over the right view's cells
//! (right pixel `x` at `d` is left pixel `x + d` at `d`) give the right view's. Each feeds a
//! streaming SGM ([`crate::sgm::SgmStream`], its four paths), whose winner is divided by the
//! cell width into Q8 patch columns, and the two maps check each other
//! ([`crate::lr::consistent_row`]); cells whose aggregate has no clear winner are rejected too
//! ([`DEFAULT_UNIQUENESS`]). The native pathway has no descriptors, so no `sgm` of its own;
//! this is the second opinion its head is fused with (`fuse-census`). Memory: one token row's
//! codes and costs and the two SGM states, never a cost volume.

use crate::config::{CELL_W, PATCH_H};
use crate::lr::consistent_row;
use crate::matching::check_candidates;
use crate::refine::census_codes;
use crate::refine::ring::hamming;
use crate::sgm::{self, Penalties, SgmStream};
use crate::Error;

/// Census window radius (5x5 codes, 24 bits: the pixel refinement's).
pub const CENSUS_RADIUS: usize = 2;
/// Pixel rows one token row's costs read: its `PATCH_H` rows and the census reach around them.
pub const WINDOW_ROWS: usize = PATCH_H + 2 * CENSUS_RADIUS;
/// Distance charged to a pixel whose match lies outside the other view (every census bit).
pub const OUTSIDE_COST: u16 = 24;
/// SGM penalties in cell-summed Hamming units (a cell sums 16 pixels of 0..=24), chosen on the
/// validation sets off the eval split (`train/experiments.json`, `census_companion`).
pub const DEFAULT_PENALTIES: Penalties = Penalties {
    p1: 32,
    p2: 128,
    edge: 0,
};

/// The view row `j` (`0..WINDOW_ROWS`) of token row `token_row`'s window in an image of
/// `height` rows: `4 t + j - 2`, clamped to the image.
pub const fn window_row(token_row: usize, j: usize, height: usize) -> usize {
    let v = (PATCH_H * token_row + j).saturating_sub(CENSUS_RADIUS);
    let last = height.saturating_sub(1);
    if v < last {
        v
    } else {
        last
    }
}

/// StereoSGBM's uniqueness ratio, in percent, that the check applies besides the left-right
/// test ([`CensusSgm::with_uniqueness`]): a cell is kept only if no candidate more than one
/// away from its winner costs less than `100 / 90` of it. Where the census is blind (flat
/// texture) its aggregate has no clear winner, and a fused readout takes the head there.
/// Chosen on the validation sets (`train/experiments.json`, `census_companion`): 10 % beat 0 on
/// the synthetic scenes at both widths and, in the three-way fusion, won all eight sets.
pub const DEFAULT_UNIQUENESS: u8 = 10;

/// The head's share, in 256ths, of a fused cell where the head's and the census's checks both
/// pass (then moved by the head's confidence, [`crate::lr::fuse_row`]): the midpoint at every
/// width. On the native pathway's validation it beat 0.625 on all four sets at 160 px; 0.375
/// won three of four at both widths and lost the synthetic scenes (`train/experiments.json`,
/// `census_companion`).
pub const FUSE_HEAD_WEIGHT: u8 = 128;

/// The share, in 256ths, of `fuse-all`'s first fusion (the head with the census SGM, share
/// [`FUSE_HEAD_WEIGHT`]) in its second, with the descriptor SGM, where both checks pass (then
/// moved by the head's confidence). Chosen on the validation sets (`train/experiments.json`,
/// `census_companion`: it won all eight against the head fused with the SGM alone; 0.75 was
/// tried too).
pub const FUSE_ALL_FIRST_WEIGHT: u8 = 160;

/// Pixel disparities searched alongside a head of `candidates` patch columns: the same reach.
pub const fn disparities(candidates: usize) -> usize {
    candidates.saturating_mul(CELL_W)
}

/// `u32` scratch of a stream over views `width` px wide with `disparities` pixel disparities:
/// both views' codes of one pixel row, and both SGM sums.
pub const fn scratch_u32_len(width: usize, disparities: usize) -> usize {
    let cells = sgm::state_len(width / CELL_W, disparities);
    (2 * width).saturating_add(cells.saturating_mul(2))
}

/// `u16` scratch of the same stream: both SGM states (vertical and diagonal,
/// [`state_u16_len`]), then both cost rows and the right view's disparity row
/// ([`row_u16_len`]).
pub const fn scratch_u16_len(width: usize, disparities: usize) -> usize {
    state_u16_len(width, disparities).saturating_add(row_u16_len(width, disparities))
}

/// `u16` values the stream carries from row to row: both views' SGM states (vertical and
/// diagonal aggregates).
pub const fn state_u16_len(width: usize, disparities: usize) -> usize {
    sgm::state_len(width / CELL_W, disparities).saturating_mul(4)
}

/// `u16` scratch of one row: both cost rows and the right view's disparity row.
pub const fn row_u16_len(width: usize, disparities: usize) -> usize {
    let cols = width / CELL_W;
    sgm::state_len(cols, disparities).saturating_mul(2).saturating_add(cols)
}

/// Bytes of [`scratch_u32_len`] and [`scratch_u16_len`] together.
pub const fn stream_bytes(width: usize, disparities: usize) -> usize {
    scratch_u32_len(width, disparities)
        .saturating_mul(4)
        .saturating_add(scratch_u16_len(width, disparities).saturating_mul(2))
}

/// The census SGM of one band, token row after token row, with its left-right check.
pub struct CensusSgm<'a> {
    width: usize,
    disparities: usize,
    max_diff_q8: u16,
    uniqueness: u8,
    /// A row's scratch, when the stream owns it ([`CensusSgm::new`]; empty for
    /// [`CensusSgm::state_only`]): [`scratch_u32_len`] and [`row_u16_len`] values.
    scratch_u32: &'a mut [u32],
    scratch_u16: &'a mut [u16],
    left_sgm: SgmStream<'a>,
    right_sgm: SgmStream<'a>,
}

impl<'a> CensusSgm<'a> {
    /// A stream over views `width` px wide (a multiple of the cell width), searching
    /// `disparities` pixel disparities (1..=64), its check keeping cells within `max_diff_q8`
    /// (Q8 patch columns); scratch of [`scratch_u32_len`] and [`scratch_u16_len`].
    pub fn new(
        width: usize,
        disparities: usize,
        penalties: Penalties,
        max_diff_q8: u16,
        scratch_u32: &'a mut [u32],
        scratch_u16: &'a mut [u16],
    ) -> Result<Self, Error> {
        // The shape and the parts' lengths are checked by `state_only` and `with_scratch`; the
        // whole u16 scratch here, before it is split.
        Error::check_len(
            "census SGM u16 scratch",
            scratch_u16_len(width, disparities),
            scratch_u16.len(),
        )?;
        let (state, scratch_u16) = scratch_u16.split_at_mut(state_u16_len(width, disparities).min(scratch_u16.len()));
        Self::state_only(width, disparities, penalties, max_diff_q8, state)?.with_scratch(scratch_u32, scratch_u16)
    }

    /// The stream with a row's scratch of its own for [`CensusSgm::push_row`]:
    /// [`scratch_u32_len`] and [`row_u16_len`] values.
    pub fn with_scratch(self, scratch_u32: &'a mut [u32], scratch_u16: &'a mut [u16]) -> Result<Self, Error> {
        let (w, n) = (self.width, self.disparities);
        Error::check_len("census SGM u32 scratch", scratch_u32_len(w, n), scratch_u32.len())?;
        Error::check_len("census SGM u16 scratch", row_u16_len(w, n), scratch_u16.len())?;
        Ok(Self {
            scratch_u32,
            scratch_u16,
            ..self
        })
    }

    /// A stream without a row's scratch of its own: each row brings it
    /// ([`CensusSgm::push_row_in`]), so what the stream carries from row to row (`state`,
    /// [`state_u16_len`] values) can live apart from the scratch, which the caller may reuse
    /// between rows. Otherwise as [`CensusSgm::new`].
    pub fn state_only(
        width: usize,
        disparities: usize,
        penalties: Penalties,
        max_diff_q8: u16,
        state: &'a mut [u16],
    ) -> Result<Self, Error> {
        let cols = width / CELL_W;
        if cols == 0 {
            return Err(Error::EmptyImage);
        }
        if !width.is_multiple_of(CELL_W) {
            return Err(Error::NotMultiple {
                what: "width",
                value: width,
                multiple: CELL_W,
            });
        }
        check_candidates(disparities)?;
        Error::check_len("census SGM state", state_u16_len(width, disparities), state.len())?;
        let cells = cols * disparities;
        let (left_vertical, rest) = state.split_at_mut(cells);
        let (left_diagonal, rest) = rest.split_at_mut(cells);
        let (right_vertical, right_diagonal) = rest.split_at_mut(cells);
        let left_sgm = SgmStream::state_only(cols, disparities, penalties, left_vertical, left_diagonal)?;
        let right_sgm = SgmStream::state_only(cols, disparities, penalties, right_vertical, right_diagonal)?;
        Ok(Self {
            width,
            disparities,
            max_diff_q8,
            uniqueness: DEFAULT_UNIQUENESS,
            scratch_u32: &mut [],
            scratch_u16: &mut [],
            left_sgm,
            right_sgm,
        })
    }

    /// Rejects cells whose aggregated costs have no clear winner besides failing the check
    /// (`ratio` percent, StereoSGBM's `uniquenessRatio`, at most 99; 0 keeps them; default
    /// [`DEFAULT_UNIQUENESS`]).
    pub fn with_uniqueness(mut self, ratio: u8) -> Self {
        self.uniqueness = ratio.min(99);
        self
    }

    /// The next token row: `left[j]` and `right[j]` hold view row `clamp(4 t + j - 2)` for
    /// `j = 0..8` ([`WINDOW_ROWS`]), `width` px each. Writes the left view's disparity in Q8
    /// patch columns and its check's mask (1 = kept); returns the number kept.
    pub fn push_row(
        &mut self,
        left: &[&[u8]],
        right: &[&[u8]],
        disparity: &mut [u16],
        kept: &mut [u8],
    ) -> Result<usize, Error> {
        let (scratch_u32, scratch_u16) = (
            core::mem::take(&mut self.scratch_u32),
            core::mem::take(&mut self.scratch_u16),
        );
        let pushed = self.push_row_in(left, right, (&mut *scratch_u32, &mut *scratch_u16), disparity, kept);
        (self.scratch_u32, self.scratch_u16) = (scratch_u32, scratch_u16);
        pushed
    }

    /// [`CensusSgm::push_row`] with the row's scratch brought along: [`scratch_u32_len`] and
    /// [`row_u16_len`] values (their contents do not matter).
    pub fn push_row_in(
        &mut self,
        left: &[&[u8]],
        right: &[&[u8]],
        (scratch_u32, scratch_u16): (&mut [u32], &mut [u16]),
        disparity: &mut [u16],
        kept: &mut [u8],
    ) -> Result<usize, Error> {
        let (w, n) = (self.width, self.disparities);
        for window in [left, right] {
            Error::check_len("census SGM window", WINDOW_ROWS, window.len())?;
            for row in window {
                Error::check_len("census SGM pixel row", w, row.len())?;
            }
        }
        Error::check_len("census SGM u32 scratch", scratch_u32_len(w, n), scratch_u32.len())?;
        Error::check_len("census SGM u16 scratch", row_u16_len(w, n), scratch_u16.len())?;
        let cells = (w / CELL_W) * n;
        let (codes, sums) = scratch_u32.split_at_mut(2 * w);
        let (left_sum, right_sum) = sums.split_at_mut(cells);
        let (left_cost, rest) = scratch_u16.split_at_mut(cells);
        let (right_cost, right_row) = rest.split_at_mut(cells);
        left_cost.fill(0);
        right_cost.fill(0);
        for i in 0..PATCH_H {
            let rows = i..i + 2 * CENSUS_RADIUS + 1;
            let (codes_left, codes_right) = codes.split_at_mut(w);
            census_codes(left.get(rows.clone()).unwrap_or_default(), CENSUS_RADIUS, codes_left);
            census_codes(right.get(rows).unwrap_or_default(), CENSUS_RADIUS, codes_right);
            add_distances(codes_left, codes_right, n, left_cost, right_cost);
        }
        self.left_sgm.push_row_in(left_cost, left_sum, disparity)?;
        self.right_sgm.push_row_in(right_cost, right_sum, right_row)?;
        for d in disparity.iter_mut().chain(right_row.iter_mut()) {
            *d = pixels_to_columns(*d);
        }
        consistent_row(disparity, right_row, self.max_diff_q8, kept)?;
        let ratio = self.uniqueness;
        let sums = &*left_sum;
        let mut count = 0;
        for (cell, k) in sums.chunks_exact(n.max(1)).zip(kept.iter_mut()) {
            *k &= unique(cell, ratio) as u8;
            count += *k as usize;
        }
        Ok(count)
    }
}

/// Whether a cell's aggregated costs have a clear winner: every candidate more than one away
/// from the lowest costs more than `100 / (100 - ratio)` times it (StereoSGBM's uniqueness
/// ratio, in percent; 0 keeps every cell). Strictly more, so a flat aggregate (a textureless
/// cell, every candidate at the same cost) has no winner.
fn unique(costs: &[u32], ratio: u8) -> bool {
    if ratio == 0 {
        return true;
    }
    let Some((best, &low)) = costs.iter().enumerate().min_by_key(|&(_, &c)| c) else {
        return true;
    };
    let scale = 100u64.saturating_sub(ratio as u64);
    costs
        .iter()
        .enumerate()
        .filter(|&(k, _)| k.abs_diff(best) > 1)
        .all(|(_, &c)| c as u64 * scale > low as u64 * 100)
}

/// Q8 pixels to Q8 patch columns, rounded half up.
fn pixels_to_columns(q8_px: u16) -> u16 {
    ((q8_px as u32 + (CELL_W as u32 / 2)) / CELL_W as u32) as u16
}

/// Adds one pixel row's distances to both cost rows (`cols x n`, disparities fastest): left
/// pixel `x` against right pixel `x - d`, each distance computed once and added to the left
/// cell of `x` and the right cell of `x - d`; [`OUTSIDE_COST`] where the other pixel is outside
/// the view (left pixels `x < d`, right pixels `x + d >= width`). [`add_distances_reference`]
/// is the specification; rows up to [`FAST_ROW`] pixels take the faster path, which computes a
/// disparity's distances along the row in one vectorisable loop, then sums each cell's four.
fn add_distances(left: &[u32], right: &[u32], n: usize, left_cost: &mut [u16], right_cost: &mut [u16]) {
    let width = left.len().min(right.len()) / CELL_W * CELL_W;
    let mut distances = [0u8; FAST_ROW];
    let (Some(h), Some(left), Some(right)) = (distances.get_mut(..width), left.get(..width), right.get(..width)) else {
        return add_distances_reference(left, right, n, left_cost, right_cost);
    };
    let cols = width / CELL_W;
    for d in 0..n {
        // h[xr]: right pixel xr against left pixel xr + d, for the pairs inside the view.
        let pairs = width.saturating_sub(d);
        let h = h.get_mut(..pairs).unwrap_or_default();
        let lefts = left.get(d..).unwrap_or_default();
        for ((h, &l), &r) in h.iter_mut().zip(lefts).zip(right) {
            *h = hamming(l, r) as u8;
        }
        let h = &*h;
        // Pixel `k` of a cell of four: its distance, or the outside cost.
        let at = |i: Option<usize>| i.and_then(|i| h.get(i)).map_or(OUTSIDE_COST, |&v| v as u16);
        let add = |cost: Option<&mut u16>, sum: u16| {
            if let Some(cost) = cost {
                *cost = cost.saturating_add(sum);
            }
        };
        // Right cell c holds right pixels 4c..4c+4, inside while below `pairs`; left cell c
        // holds left pixels 4c..4c+4, matched to right pixels 4c - d.., inside from `d` on.
        let (full_right, full_left) = ((pairs / CELL_W).min(cols), d.div_ceil(CELL_W).min(cols));
        let costs = right_cost.get_mut(d..).unwrap_or_default().iter_mut().step_by(n);
        for (four, cost) in h.chunks_exact(CELL_W).zip(costs) {
            *cost = cost.saturating_add(cell_sum(four));
        }
        for c in full_right..cols {
            let sum = (c * CELL_W..(c + 1) * CELL_W).map(|xr| at(Some(xr))).sum();
            add(right_cost.get_mut(c * n + d), sum);
        }
        for c in 0..full_left {
            let sum = (c * CELL_W..(c + 1) * CELL_W).map(|x| at(x.checked_sub(d))).sum();
            add(left_cost.get_mut(c * n + d), sum);
        }
        let from = (full_left * CELL_W).saturating_sub(d);
        let costs = left_cost
            .get_mut(full_left * n + d..)
            .unwrap_or_default()
            .iter_mut()
            .step_by(n);
        for (four, cost) in h.get(from..).unwrap_or_default().chunks_exact(CELL_W).zip(costs) {
            *cost = cost.saturating_add(cell_sum(four));
        }
    }
}

/// The sum of a cell's four distances (each at most 32) from one word: the bytes' sum lands in
/// the top byte of the word times `0x0101_0101` (at most 128, so nothing carries past it).
#[inline(always)]
fn cell_sum(four: &[u8]) -> u16 {
    let word = match four {
        &[a, b, c, d] => u32::from_le_bytes([a, b, c, d]),
        _ => return four.iter().map(|&v| v as u16).sum(),
    };
    (word.wrapping_mul(0x0101_0101) >> 24) as u16
}

/// Widest row [`add_distances`] takes its faster path on (its distances live on the stack).
const FAST_ROW: usize = 640;

/// [`add_distances`] pixel by pixel: the specification.
fn add_distances_reference(left: &[u32], right: &[u32], n: usize, left_cost: &mut [u16], right_cost: &mut [u16]) {
    let width = left.len().min(right.len()) / CELL_W * CELL_W;
    let add = |costs: &mut [u16], x: usize, d: usize, cost: u16| {
        if let Some(c) = costs.get_mut(x / CELL_W * n + d) {
            *c = c.saturating_add(cost);
        }
    };
    for d in 0..n {
        for x in 0..width.min(d) {
            add(left_cost, x, d, OUTSIDE_COST);
        }
        for x in width.saturating_sub(d)..width {
            add(right_cost, x, d, OUTSIDE_COST);
        }
        let pairs = left.get(d..width).unwrap_or_default().iter().zip(right);
        for (xr, (&l, &r)) in pairs.enumerate() {
            let cost = (l ^ r).count_ones() as u16;
            add(left_cost, xr + d, d, cost);
            add(right_cost, xr, d, cost);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::Rng;

    const W: usize = 48;
    const H: usize = 16;
    const N: usize = 16;

    /// A textured pair whose left pixel `x` is right pixel `x - shift`.
    fn shifted_pair(shift: usize) -> ([u8; W * H], [u8; W * H]) {
        let mut rng = Rng::new(41);
        let mut base = [0u8; (W + 8) * H];
        for b in base.iter_mut() {
            *b = rng.range(0, 255) as u8;
        }
        let (mut left, mut right) = ([0u8; W * H], [0u8; W * H]);
        for y in 0..H {
            for x in 0..W {
                left[y * W + x] = base[y * (W + 8) + x];
                right[y * W + x] = base[y * (W + 8) + x + shift];
            }
        }
        (left, right)
    }

    fn window(view: &[u8], t: usize) -> [&[u8]; WINDOW_ROWS] {
        let mut rows: [&[u8]; WINDOW_ROWS] = [&[]; WINDOW_ROWS];
        for (j, row) in rows.iter_mut().enumerate() {
            let y = window_row(t, j, H);
            *row = &view[y * W..(y + 1) * W];
        }
        rows
    }

    #[test]
    fn a_constant_shift_is_found_and_kept_where_its_match_is_inside() {
        let (left, right) = shifted_pair(8);
        let (mut s32, mut s16) = ([0u32; scratch_u32_len(W, N)], [0u16; scratch_u16_len(W, N)]);
        let mut sgm = CensusSgm::new(W, N, DEFAULT_PENALTIES, 256, &mut s32, &mut s16).unwrap();
        let (mut d, mut k) = ([0u16; W / 4], [0u8; W / 4]);
        for t in 0..H / 4 {
            sgm.push_row(&window(&left, t), &window(&right, t), &mut d, &mut k)
                .unwrap();
            // 8 px = 2 patch columns = 512 in Q8, give or take the parabola step.
            for c in 2..W / 4 {
                assert!(d[c].abs_diff(512) <= 16, "row {t} cell {c}: {}", d[c]);
                assert_eq!(k[c], 1, "row {t} cell {c}");
            }
        }
    }

    /// A stream whose rows bring their scratch gives what one with its own scratch does,
    /// whatever the scratch held; scratch of the wrong length is an error.
    #[test]
    fn rows_bringing_their_scratch_give_the_same_rows() {
        let (left, right) = shifted_pair(5);
        let (mut s32, mut s16) = ([0u32; scratch_u32_len(W, N)], [0u16; scratch_u16_len(W, N)]);
        let mut own = CensusSgm::new(W, N, DEFAULT_PENALTIES, 256, &mut s32, &mut s16).unwrap();
        let mut state = [0u16; state_u16_len(W, N)];
        let mut apart = CensusSgm::state_only(W, N, DEFAULT_PENALTIES, 256, &mut state).unwrap();
        let (mut r32, mut r16) = ([u32::MAX; scratch_u32_len(W, N)], [3u16; row_u16_len(W, N)]);
        for t in 0..H / 4 {
            let (mut d, mut k) = ([0u16; W / 4], [0u8; W / 4]);
            let kept = own
                .push_row(&window(&left, t), &window(&right, t), &mut d, &mut k)
                .unwrap();
            let (mut d2, mut k2) = ([0u16; W / 4], [0u8; W / 4]);
            let scratch = (&mut r32[..], &mut r16[..]);
            let kept2 = (apart.push_row_in(&window(&left, t), &window(&right, t), scratch, &mut d2, &mut k2)).unwrap();
            assert_eq!((d, k, kept), (d2, k2, kept2), "row {t}");
            r32.fill(9);
        }
        let short = (&mut r32[1..], &mut r16[..]);
        let (mut d, mut k) = ([0u16; W / 4], [0u8; W / 4]);
        assert!(apart
            .push_row_in(&window(&left, 0), &window(&right, 0), short, &mut d, &mut k)
            .is_err());
        assert!(apart
            .push_row(&window(&left, 0), &window(&right, 0), &mut d, &mut k)
            .is_err());
        assert!(CensusSgm::state_only(W, N, DEFAULT_PENALTIES, 256, &mut state[1..]).is_err());
    }

    #[test]
    fn the_distances_charge_the_outside_and_count_the_right_cells() {
        // Identical views: every distance at d = 0 is 0; at d > 0 the first d left pixels and
        // the last d right pixels are outside.
        let codes: [u32; 8] = [1, 2, 4, 8, 16, 32, 64, 128];
        let (mut l, mut r) = ([0u16; 2 * 3], [0u16; 2 * 3]);
        add_distances(&codes, &codes, 3, &mut l, &mut r);
        assert_eq!(l[0], 0);
        assert_eq!(l[1], OUTSIDE_COST + 3 * 2, "x = 0 outside, x = 1..3 differ by two bits");
        assert_eq!(l[3 + 2], 4 * 2);
        assert_eq!(r[3 + 1], 3 * 2 + OUTSIDE_COST, "right x = 7 has no left x + 1");
    }

    #[test]
    fn the_fast_distances_are_the_reference_ones() {
        let mut rng = Rng::new(17);
        for value in [0, 1, u32::MAX, 0x00ff_ffff, 0x8000_0001, 0x5555_5555] {
            assert_eq!(hamming(value, 0), value.count_ones(), "{value:#x}");
        }
        for _ in 0..10_000 {
            let (a, b) = (
                rng.range(0, u32::MAX as i64) as u32,
                rng.range(0, u32::MAX as i64) as u32,
            );
            assert_eq!(hamming(a, b), (a ^ b).count_ones(), "{a:#x} {b:#x}");
        }
        const MAX_W: usize = FAST_ROW + 8;
        const MAX_N: usize = 20;
        for (width, n) in [
            (4, 1),
            (8, 3),
            (12, 16),
            (16, 20),
            (36, 9),
            (48, 16),
            (FAST_ROW, 20),
            (MAX_W, 7),
        ] {
            let (mut l, mut r) = ([0u32; MAX_W], [0u32; MAX_W]);
            for (a, b) in l.iter_mut().zip(r.iter_mut()).take(width) {
                (*a, *b) = (rng.range(0, 1 << 24) as u32, rng.range(0, 1 << 24) as u32);
            }
            let cells = width / CELL_W * n;
            let (mut fast_l, mut fast_r) = ([0u16; MAX_W / CELL_W * MAX_N], [0u16; MAX_W / CELL_W * MAX_N]);
            // Some costs start near saturation, as the reference's saturating adds allow.
            for (i, (a, b)) in fast_l.iter_mut().zip(fast_r.iter_mut()).take(cells).enumerate() {
                let start = if i % 7 == 0 { u16::MAX - 30 } else { i as u16 };
                (*a, *b) = (start, start);
            }
            let (mut want_l, mut want_r) = (fast_l, fast_r);
            add_distances(&l[..width], &r[..width], n, &mut fast_l[..cells], &mut fast_r[..cells]);
            add_distances_reference(&l[..width], &r[..width], n, &mut want_l[..cells], &mut want_r[..cells]);
            for i in 0..cells {
                assert_eq!(fast_l[i], want_l[i], "left width {width} n {n} cell {i}");
                assert_eq!(fast_r[i], want_r[i], "right width {width} n {n} cell {i}");
            }
        }
    }

    #[test]
    fn uniqueness_rejects_a_flat_aggregate_and_keeps_a_clear_winner() {
        assert!(unique(&[50, 40, 10, 41, 60], 10));
        assert!(!unique(&[50, 40, 10, 41, 11], 10), "a rival two away within 10 %");
        assert!(unique(&[50, 40, 10, 41, 11], 0), "ratio 0 keeps every cell");
        assert!(
            unique(&[50, 11, 10, 11, 60], 50),
            "the winner's neighbours are no rivals"
        );
        // Through the stream: a demanding ratio rejects cells of a noisy pair the default keeps.
        let (left, right) = shifted_pair(8);
        let kept_with = |ratio: u8| {
            let (mut s32, mut s16) = ([0u32; scratch_u32_len(W, N)], [0u16; scratch_u16_len(W, N)]);
            let mut sgm = CensusSgm::new(W, N, DEFAULT_PENALTIES, 256, &mut s32, &mut s16)
                .unwrap()
                .with_uniqueness(ratio);
            let (mut d, mut k) = ([0u16; W / 4], [0u8; W / 4]);
            (0..H / 4)
                .map(|t| {
                    sgm.push_row(&window(&left, t), &window(&right, t), &mut d, &mut k)
                        .unwrap()
                })
                .sum::<usize>()
        };
        assert_eq!(kept_with(0), kept_with(DEFAULT_UNIQUENESS));
        assert!(kept_with(99) < kept_with(0), "{} vs {}", kept_with(99), kept_with(0));
    }

    #[test]
    fn bad_sizes_are_errors() {
        let (mut s32, mut s16) = ([0u32; scratch_u32_len(W, N)], [0u16; scratch_u16_len(W, N)]);
        assert!(matches!(
            CensusSgm::new(W + 1, N, DEFAULT_PENALTIES, 256, &mut s32, &mut s16),
            Err(Error::NotMultiple { .. })
        ));
        assert!(matches!(
            CensusSgm::new(W, N, DEFAULT_PENALTIES, 256, &mut s32[1..], &mut s16),
            Err(Error::BufferSize { .. })
        ));
        assert!(matches!(
            CensusSgm::new(W, 65, DEFAULT_PENALTIES, 256, &mut s32, &mut s16),
            Err(Error::Candidates { .. }) | Err(Error::BufferSize { .. })
        ));
        assert!(matches!(
            CensusSgm::new(0, N, DEFAULT_PENALTIES, 256, &mut [], &mut []),
            Err(Error::EmptyImage)
        ));
        let (left, right) = shifted_pair(0);
        let mut sgm = CensusSgm::new(W, N, DEFAULT_PENALTIES, 256, &mut s32, &mut s16).unwrap();
        let (mut d, mut k) = ([0u16; W / 4], [0u8; W / 4]);
        let short = &window(&left, 0)[..WINDOW_ROWS - 1];
        assert!(sgm.push_row(short, &window(&right, 0), &mut d, &mut k).is_err());
        assert!(sgm
            .push_row(&window(&left, 0), &window(&right, 0), &mut d[1..], &mut k)
            .is_err());
    }
}
