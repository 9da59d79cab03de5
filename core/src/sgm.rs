//! Semi-global matching over the row-wise cosine costs, in one top-to-bottom pass.
//!
//! A streaming pass sees each token row once, so the paths are the ones that only look back:
//! left to right and right to left within the row (the whole row is there), top to bottom,
//! and the top-left to bottom-right diagonal. Their aggregated costs are summed and the
//! minimum is refined by a parabola, as the no-linkage readout is (SGM + local refinement).
//! Memory: the previous row's vertical and diagonal aggregates and the current row's cost and
//! sum (`cols x candidates` each); never the cost volume of the image.

use crate::matching::{check_candidates, DISPARITY_FRAC_BITS, MAX_CANDIDATES};
/// The matching cost's scale, defined by the matching stage (re-exported here, where the
/// aggregation's penalties are in the same unit).
pub use crate::matching::{COST_EXCLUDED, COST_ONE};
use crate::Error;

/// SGM smoothness penalties in cost units: `p1` for a change of one candidate between
/// neighbours, `p2` for any larger jump (`p2 >= p1`).
///
/// With `edge > 0` and a guide (each cell's mean grey level, [`SgmStream::push_row_guided`]),
/// `p2` falls where neighbouring cells differ in brightness, as Hirschmueller's intensity-
/// adaptive `P2`: `max(p1, p2 * edge / (edge + |g_p - g_q|))`, halved at a difference of
/// `edge` grey levels. Depth edges mostly are brightness edges, so a surface's disparity spreads
/// over its flat interior but stops at its outline.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Penalties {
    /// Penalty for a one-column disparity change.
    pub p1: u16,
    /// Penalty for a larger change.
    pub p2: u16,
    /// Grey-level difference at which `p2` halves; 0: `p2` everywhere.
    pub edge: u8,
}

impl Penalties {
    /// Whether the jump penalty follows a guide (`edge > 0`): the SGM then needs one.
    pub const fn guided(self) -> bool {
        self.edge > 0
    }

    /// The jump penalty between cells of mean grey levels `a` and `b`.
    #[inline]
    pub fn jump(self, a: u8, b: u8) -> u32 {
        let (p1, p2) = (self.p1 as u32, self.p2 as u32);
        if self.edge == 0 {
            return p2;
        }
        let edge = self.edge as u32;
        (p2 * edge / (edge + a.abs_diff(b) as u32)).max(p1)
    }
}

/// The penalties every command, the firmware and the board apps run (`preset::OPTIONS`),
/// chosen off the eval split (`train/experiments.json`, `sgm_penalties_p7`): with the p7
/// weights, 96 / 192 beat the earlier 64 / 256 at 320 px on all three validations (int8
/// sgm+lr+ref epe / bad1tok: held-out train pairs against left-right-consistent StereoSGBM
/// 0.567 / 2.32 -> 0.561 / 2.27, synthetic scenes with exact disparity 1.638 / 9.52 -> 1.579 /
/// 8.79, the same with real textures 2.807 / 13.60 -> 2.695 / 12.70); a larger p1 holds
/// textureless spans together, a smaller p2 lets object edges jump.
pub const DEFAULT_PENALTIES: Penalties = Penalties {
    p1: 96,
    p2: 192,
    edge: 0,
};

/// Streaming SGM state over rows of `cols` cells with `candidates` disparities each.
pub struct SgmStream<'a> {
    cols: usize,
    candidates: usize,
    penalties: Penalties,
    vertical: &'a mut [u16],
    diagonal: &'a mut [u16],
    sum: &'a mut [u32],
    /// The previous row's guide ([`SgmStream::with_guide`]).
    prev_guide: Option<&'a mut [u8]>,
    rows_seen: usize,
}

/// `u16` values the state keeps (`vertical` and `diagonal`), and `u32` values of `sum`;
/// saturates at `usize::MAX` for sizes no memory holds, which [`SgmStream::new`] then rejects.
pub const fn state_len(cols: usize, candidates: usize) -> usize {
    cols.saturating_mul(candidates)
}

impl<'a> SgmStream<'a> {
    /// A stream over `state_len(cols, candidates)`-long buffers for the vertical and diagonal
    /// aggregates and the per-row sum.
    pub fn new(
        cols: usize,
        candidates: usize,
        penalties: Penalties,
        vertical: &'a mut [u16],
        diagonal: &'a mut [u16],
        sum: &'a mut [u32],
    ) -> Result<Self, Error> {
        let stream = Self::state_only(cols, candidates, penalties, vertical, diagonal)?;
        Error::check_len("SGM row sum", state_len(cols, candidates), sum.len())?;
        Ok(Self { sum, ..stream })
    }

    /// A stream without a row sum of its own: each row brings one ([`SgmStream::push_row_in`]),
    /// so what it carries from row to row (the vertical and diagonal aggregates) can live apart
    /// from a row's scratch, which the caller may reuse for other work between rows.
    pub fn state_only(
        cols: usize,
        candidates: usize,
        penalties: Penalties,
        vertical: &'a mut [u16],
        diagonal: &'a mut [u16],
    ) -> Result<Self, Error> {
        if cols == 0 {
            return Err(Error::EmptyImage);
        }
        check_candidates(candidates)?;
        let len = state_len(cols, candidates);
        for (what, found) in [
            ("SGM vertical state", vertical.len()),
            ("SGM diagonal state", diagonal.len()),
        ] {
            Error::check_len(what, len, found)?;
        }
        Ok(Self {
            cols,
            candidates,
            penalties,
            vertical,
            diagonal,
            sum: &mut [],
            prev_guide: None,
            rows_seen: 0,
        })
    }

    /// Keeps the previous row's guide in `prev_guide` (`cols` bytes), so that
    /// [`SgmStream::push_row_guided`] can adapt the vertical and diagonal paths' `p2` too.
    pub fn with_guide(mut self, prev_guide: &'a mut [u8]) -> Result<Self, Error> {
        Error::check_len("SGM guide state", self.cols, prev_guide.len())?;
        self.prev_guide = Some(prev_guide);
        Ok(self)
    }

    /// The last row's summed aggregates (`cols x candidates`, candidates fastest): what its
    /// disparities were read from (a uniqueness test reads them too); empty for a
    /// [`SgmStream::state_only`] stream, whose rows bring their sums.
    pub fn sums(&self) -> &[u32] {
        self.sum
    }

    /// Aggregates one row of costs (`cols x candidates`, candidates fastest) and writes each
    /// cell's disparity in Q8 patch columns to `out`, with `p2` everywhere.
    pub fn push_row(&mut self, cost: &[u16], out: &mut [u16]) -> Result<(), Error> {
        self.push_own(cost, None, out)
    }

    /// [`SgmStream::push_row`] summing into `sum` (`cols x candidates`, left holding the row's
    /// summed aggregates) instead of the stream's own.
    pub fn push_row_in(&mut self, cost: &[u16], sum: &mut [u32], out: &mut [u16]) -> Result<(), Error> {
        self.push(cost, None, sum, out)
    }

    /// [`SgmStream::push_row_guided`] summing into `sum`, as [`SgmStream::push_row_in`].
    pub fn push_row_guided_in(
        &mut self,
        cost: &[u16],
        guide: &[u8],
        sum: &mut [u32],
        out: &mut [u16],
    ) -> Result<(), Error> {
        self.check_guide(guide)?;
        self.push(cost, Some(guide), sum, out)
    }

    /// [`SgmStream::push_row`] with `guide`, each cell's mean grey level (`cols` bytes): the
    /// jump penalty between two cells is [`Penalties::jump`] of theirs. Needs
    /// [`SgmStream::with_guide`].
    pub fn push_row_guided(&mut self, cost: &[u16], guide: &[u8], out: &mut [u16]) -> Result<(), Error> {
        self.check_guide(guide)?;
        self.push_own(cost, Some(guide), out)
    }

    /// A guide row of the right length, and the state to keep it.
    fn check_guide(&self, guide: &[u8]) -> Result<(), Error> {
        Error::check_len("SGM guide row", self.cols, guide.len())?;
        if self.prev_guide.is_none() {
            return Err(Error::BufferSize {
                what: "SGM guide state",
                expected: self.cols,
                found: 0,
            });
        }
        Ok(())
    }

    /// A row summed into the stream's own sum.
    fn push_own(&mut self, cost: &[u16], guide: Option<&[u8]>, out: &mut [u16]) -> Result<(), Error> {
        let sum = core::mem::take(&mut self.sum);
        let pushed = self.push(cost, guide, sum, out);
        self.sum = sum;
        pushed
    }

    fn push(&mut self, cost: &[u16], guide: Option<&[u8]>, sum: &mut [u32], out: &mut [u16]) -> Result<(), Error> {
        let (cols, d) = (self.cols, self.candidates);
        Error::check_len("SGM cost row", cols * d, cost.len())?;
        Error::check_len("disparity row", cols, out.len())?;
        Error::check_len("SGM row sum", cols * d, sum.len())?;
        let pen = self.penalties;
        // The jump penalty between cell `p` of this row and cell `q` of `other` (this row's
        // guide or the previous one); `p2` without a guide.
        let jump = |p: usize, q: usize, other: Option<&[u8]>| match (guide, other) {
            (Some(g), Some(o)) => pen.jump(g.get(p).copied().unwrap_or(0), o.get(q).copied().unwrap_or(0)),
            _ => pen.p2 as u32,
        };
        let first = self.rows_seen == 0;
        sum.iter_mut().for_each(|s| *s = 0);
        let mut running = [0u16; MAX_CANDIDATES];
        let mut next = [0u16; MAX_CANDIDATES];
        // Left to right, then right to left.
        for order in [false, true] {
            for i in 0..cols {
                let p = if order { cols - 1 - i } else { i };
                let c = &cost[p * d..(p + 1) * d];
                if i == 0 {
                    next[..d].copy_from_slice(c);
                } else {
                    let from = if order { p + 1 } else { p - 1 };
                    step(c, &running[..d], pen.p1, jump(p, from, guide), &mut next[..d]);
                }
                running[..d].copy_from_slice(&next[..d]);
                add(&mut sum[p * d..(p + 1) * d], &next[..d]);
            }
        }
        let prev_guide = self.prev_guide.as_deref();
        // Top to bottom: each cell from the same column of the previous row (in place).
        // Diagonal: from column p - 1 of the previous row, so columns go right to left.
        for p in (0..cols).rev() {
            let c = &cost[p * d..(p + 1) * d];
            let cell = p * d..(p + 1) * d;
            if first {
                next[..d].copy_from_slice(c);
            } else {
                step(
                    c,
                    &self.vertical[cell.clone()],
                    pen.p1,
                    jump(p, p, prev_guide),
                    &mut next[..d],
                );
            }
            self.vertical[cell.clone()].copy_from_slice(&next[..d]);
            add(&mut sum[cell.clone()], &next[..d]);
            if first || p == 0 {
                next[..d].copy_from_slice(c);
            } else {
                let from = &self.diagonal[(p - 1) * d..p * d];
                step(c, from, pen.p1, jump(p, p - 1, prev_guide), &mut next[..d]);
            }
            self.diagonal[cell.clone()].copy_from_slice(&next[..d]);
            add(&mut sum[cell], &next[..d]);
        }
        for (p, o) in out.iter_mut().enumerate() {
            *o = refine_min(&sum[p * d..(p + 1) * d]);
        }
        if let (Some(g), Some(prev)) = (guide, self.prev_guide.as_deref_mut()) {
            prev.copy_from_slice(g);
        }
        self.rows_seen += 1;
        Ok(())
    }
}

/// One SGM path step: `L[k] = C[k] + min(P[k], P[k +- 1] + p1, min P + p2) - min P`.
/// Over the shortest of the three rows; the end candidates have one neighbour, the others run
/// in one loop without branches (the compiler vectorises it: Helium on the Cortex-M55).
fn step(cost: &[u16], prev: &[u16], p1: u16, p2: u32, out: &mut [u16]) {
    let d = cost.len().min(prev.len()).min(out.len());
    let (Some(cost), Some(prev), Some(out)) = (cost.get(..d), prev.get(..d), out.get_mut(..d)) else {
        return;
    };
    let min_prev = prev.iter().copied().min().unwrap_or(0) as u32;
    let jump = min_prev + p2;
    let p1 = p1 as u32;
    // best >= min_prev, so the subtraction cannot wrap; the sum stays below 2^16 as long as
    // costs and p2 do (cost <= 2 * COST_ONE, p2 checked by the caller's choice).
    let cell = |c: u16, best: u32| (c as u32 + best.min(jump) - min_prev).min(u16::MAX as u32) as u16;
    let (Some(&m_first), Some(&m_last)) = (prev.first(), prev.last()) else {
        return;
    };
    if d == 1 {
        if let (Some(o), Some(&c)) = (out.first_mut(), cost.first()) {
            *o = cell(c, m_first as u32);
        }
        return;
    }
    // The ends: their one neighbour (each other's when there are two).
    let (n_first, n_last) = (prev.get(1).copied().unwrap_or(0), prev.get(d - 2).copied().unwrap_or(0));
    let (c_first, c_last) = (cost.first().copied().unwrap_or(0), cost.last().copied().unwrap_or(0));
    if let Some(o) = out.first_mut() {
        *o = cell(c_first, (m_first as u32).min(n_first as u32 + p1));
    }
    if let Some(o) = out.last_mut() {
        *o = cell(c_last, (m_last as u32).min(n_last as u32 + p1));
    }
    let (Some(inner), Some(cost_inner)) = (out.get_mut(1..d - 1), cost.get(1..d - 1)) else {
        return;
    };
    let (Some(left), Some(mid), Some(right)) = (prev.get(..d - 2), prev.get(1..d - 1), prev.get(2..)) else {
        return;
    };
    let rows = inner.iter_mut().zip(cost_inner).zip(left).zip(mid).zip(right);
    for ((((o, &c), &l), &m), &r) in rows {
        *o = cell(c, (m as u32).min(l as u32 + p1).min(r as u32 + p1));
    }
}

/// The guide of one token row: each cell's mean grey level over `rows` (the cell's pixel rows
/// of one view), `out.len()` cells of `cell_w` pixels; the sum rounds to nearest. Rows shorter
/// than the cells are an error.
pub fn cell_guide(rows: &[&[u8]], cell_w: usize, out: &mut [u8]) -> Result<(), Error> {
    let width = out.len().saturating_mul(cell_w);
    let count = rows.len().saturating_mul(cell_w) as u32;
    if count == 0 {
        return Err(Error::EmptyImage);
    }
    for row in rows {
        if row.len() < width {
            return Err(Error::BufferSize {
                what: "SGM guide pixel row",
                expected: width,
                found: row.len(),
            });
        }
    }
    for (c, o) in out.iter_mut().enumerate() {
        let span = c * cell_w..(c + 1) * cell_w;
        let total: u32 = rows
            .iter()
            .map(|r| {
                r.get(span.clone())
                    .map_or(0, |px| px.iter().map(|&v| v as u32).sum::<u32>())
            })
            .sum();
        *o = ((total + count / 2) / count).min(255) as u8;
    }
    Ok(())
}

fn add(sum: &mut [u32], path: &[u16]) {
    sum.iter_mut().zip(path).for_each(|(s, &v)| *s += v as u32);
}

/// First minimum plus the parabola step (clamped to half a column), Q8.
pub(crate) fn refine_min(costs: &[u32]) -> u16 {
    let mut best = 0;
    for (k, &c) in costs.iter().enumerate() {
        if c < costs[best] {
            best = k;
        }
    }
    let base = (best as i64) << DISPARITY_FRAC_BITS;
    let step = match (best.checked_sub(1).and_then(|k| costs.get(k)), costs.get(best + 1)) {
        (Some(&l), Some(&r)) => {
            let (l, at, r) = (l as i64, costs[best] as i64, r as i64);
            let denom = l - 2 * at + r;
            if denom > 0 {
                let half = 1i64 << (DISPARITY_FRAC_BITS - 1);
                let num = (l - r) << DISPARITY_FRAC_BITS;
                let den = 2 * denom;
                let half_den = den / 2;
                let num = if num >= 0 { num + half_den } else { num - half_den };
                // Below 2^22 (every aggregate of `u16` paths) both fit `i32`, whose division is
                // one instruction on the Cortex-M cores: the same quotient.
                const SMALL: i64 = 1 << 22;
                let q = if l < SMALL && at < SMALL && r < SMALL {
                    (num as i32 / den as i32) as i64
                } else {
                    num / den
                };
                q.clamp(-half, half)
            } else {
                0
            }
        }
        _ => 0,
    };
    (base + step).clamp(0, u16::MAX as i64) as u16
}

#[cfg(test)]
mod tests {
    use super::*;

    const PEN: Penalties = Penalties {
        p1: 100,
        p2: 400,
        edge: 0,
    };

    fn run(rows: &[[u16; 4 * 3]], out: &mut [[u16; 4]]) {
        let (mut v, mut g, mut s) = ([0u16; 12], [0u16; 12], [0u32; 12]);
        let mut sgm = SgmStream::new(4, 3, PEN, &mut v, &mut g, &mut s).unwrap();
        for (row, o) in rows.iter().zip(out.iter_mut()) {
            sgm.push_row(row, o).unwrap();
        }
    }

    /// A stream whose rows bring their sums gives what one with its own sum does, whatever
    /// the sum held before, and a sum of the wrong length is an error.
    #[test]
    fn rows_bringing_their_sums_aggregate_the_same() {
        let rows: [[u16; 12]; 3] = [
            [900, 0, 900, 0, 900, 900, 700, 20, 0, 900, 10, 900],
            [0, 900, 900, 900, 0, 30, 900, 900, 0, 5, 0, 900],
            [40, 0, 900, 900, 0, 900, 0, 600, 900, 900, 10, 0],
        ];
        let mut own = [[0u16; 4]; 3];
        run(&rows, &mut own);
        let (mut v, mut g) = ([0u16; 12], [0u16; 12]);
        let mut sgm = SgmStream::state_only(4, 3, PEN, &mut v, &mut g).unwrap();
        assert!(sgm.sums().is_empty());
        let mut sum = [u32::MAX; 12];
        for (row, expected) in rows.iter().zip(own) {
            let mut out = [0u16; 4];
            sgm.push_row_in(row, &mut sum, &mut out).unwrap();
            assert_eq!(out, expected);
            sum = [7; 12];
        }
        assert!(sgm.push_row_in(&rows[0], &mut [0u32; 11], &mut [0u16; 4]).is_err());
        assert!(sgm.push_row(&rows[0], &mut [0u16; 4]).is_err(), "no sum of its own");
    }

    #[test]
    fn clear_minima_survive_aggregation() {
        // Every cell prefers candidate 1 strongly.
        let row = [900, 0, 900, 900, 0, 900, 900, 0, 900, 900, 0, 900];
        let mut out = [[0u16; 4]; 3];
        run(&[row; 3], &mut out);
        assert!(out.iter().flatten().all(|&d| d == 256), "{out:?}");
    }

    #[test]
    fn smoothness_overrules_a_weak_outlier() {
        // Cell 2 of the middle row weakly prefers candidate 2; its neighbours want 0 strongly.
        let strong = [0, 800, 800];
        let mut rows = [[0u16; 12]; 3];
        for row in rows.iter_mut() {
            for p in 0..4 {
                row[p * 3..p * 3 + 3].copy_from_slice(&strong);
            }
        }
        rows[1][6..9].copy_from_slice(&[60, 800, 0]);
        let mut out = [[0u16; 4]; 3];
        run(&rows, &mut out);
        assert_eq!(out[1][2] >> 8, 0, "{out:?}");
        // Without aggregation (a single path step from nothing) the outlier would win.
        assert_eq!(refine_min(&[60, 800, 0]) >> 8, 2);
    }

    #[test]
    fn the_parabola_step_divides_as_in_i64_on_both_sides_of_its_fast_path() {
        // The rule in i64, as documented on `refine_min`.
        let rule = |c: [u32; 3]| -> i64 {
            let (l, at, r) = (c[0] as i64, c[1] as i64, c[2] as i64);
            let denom = l - 2 * at + r;
            if denom <= 0 {
                return 0;
            }
            let num = (l - r) << DISPARITY_FRAC_BITS;
            let den = 2 * denom;
            let q = if num >= 0 { num + den / 2 } else { num - den / 2 } / den;
            q.clamp(-128, 128)
        };
        let mut rng = crate::testutil::Rng::new(23);
        for i in 0..20_000 {
            let max = if i % 2 == 0 { (1 << 22) - 1 } else { 1 << 30 };
            let mut c = [0u32; 3].map(|_| rng.range(0, max) as u32);
            // The middle one the first minimum, as refine_min steps only around that.
            c[1] = c[1].min(c[0]).min(c[2]);
            c[0] = c[0].max(c[1] + 1);
            let want = (256 + rule(c)).clamp(0, u16::MAX as i64) as u16;
            assert_eq!(refine_min(&c), want, "{c:?}");
        }
    }

    #[test]
    fn step_follows_the_recurrence() {
        let prev = [10, 50, 300];
        let mut out = [0u16; 3];
        step(&[5, 5, 5], &prev, PEN.p1, PEN.p2 as u32, &mut out);
        // k=0: min(10, 50+100, 10+400) - 10 = 0; k=1: min(50, 10+100, 300+100, 410) - 10 = 40;
        // k=2: min(300, 50+100, 410) - 10 = 140.
        assert_eq!(out, [5, 45, 145]);
        // Against the recurrence candidate by candidate, at every length up to MAX_CANDIDATES,
        // random costs up to the u16 saturation.
        let mut rng = crate::testutil::Rng::new(31);
        for d in 1..=MAX_CANDIDATES {
            for _ in 0..20 {
                let top = if rng.range(0, 1) == 0 { 2000 } else { u16::MAX as i64 };
                let (mut cost, mut prev) = ([0u16; MAX_CANDIDATES], [0u16; MAX_CANDIDATES]);
                for (c, p) in cost.iter_mut().zip(prev.iter_mut()).take(d) {
                    (*c, *p) = (rng.range(0, top) as u16, rng.range(0, top) as u16);
                }
                let (p1, p2) = (rng.range(0, 300) as u16, rng.range(300, 3000) as u32);
                let min_prev = prev[..d].iter().copied().min().unwrap() as u32;
                let mut got = [0u16; MAX_CANDIDATES];
                step(&cost[..d], &prev[..d], p1, p2, &mut got[..d]);
                for k in 0..d {
                    let mut best = prev[k] as u32;
                    if k > 0 {
                        best = best.min(prev[k - 1] as u32 + p1 as u32);
                    }
                    if k + 1 < d {
                        best = best.min(prev[k + 1] as u32 + p1 as u32);
                    }
                    let want = (cost[k] as u32 + best.min(min_prev + p2) - min_prev).min(u16::MAX as u32) as u16;
                    assert_eq!(got[k], want, "d {d} k {k}");
                }
            }
        }
    }

    #[test]
    fn the_jump_penalty_halves_at_the_edge_scale_and_never_falls_below_p1() {
        let pen = Penalties {
            p1: 100,
            p2: 400,
            edge: 8,
        };
        assert_eq!(pen.jump(50, 50), 400);
        assert_eq!(pen.jump(50, 58), 200);
        assert_eq!(pen.jump(58, 50), 200);
        assert_eq!(pen.jump(0, 255), 100);
        assert_eq!(PEN.jump(0, 255), 400, "edge 0: p2 everywhere");
    }

    #[test]
    fn a_flat_guide_changes_nothing_and_a_bright_edge_lets_the_disparity_jump() {
        // One row of four cells: cells 0-1 want candidate 0, cells 2-3 weakly prefer 2 (by less
        // than the left-to-right path's jump penalty p2 = 400 costs, more than p1 = 100 does).
        let want0 = [0u16, 800, 800];
        let weak2 = [40u16, 800, 0];
        let mut row = [0u16; 12];
        for (p, c) in [want0, want0, weak2, weak2].iter().enumerate() {
            row[p * 3..p * 3 + 3].copy_from_slice(c);
        }
        let pen = Penalties {
            p1: 100,
            p2: 400,
            edge: 8,
        };
        let out = |guide: Option<[u8; 4]>| {
            let (mut v, mut g, mut s, mut prev) = ([0u16; 12], [0u16; 12], [0u32; 12], [0u8; 4]);
            let mut sgm = SgmStream::new(4, 3, pen, &mut v, &mut g, &mut s)
                .unwrap()
                .with_guide(&mut prev)
                .unwrap();
            let mut out = [0u16; 4];
            match guide {
                Some(gd) => sgm.push_row_guided(&row, &gd, &mut out).unwrap(),
                None => sgm.push_row(&row, &mut out).unwrap(),
            }
            out.map(|d| d >> 8)
        };
        let plain = out(None);
        assert_eq!(out(Some([90; 4])), plain, "a flat guide is p2 everywhere");
        assert_eq!(plain, [0; 4], "without an edge the jump costs p2");
        let edged = out(Some([30, 30, 200, 200]));
        assert_eq!(edged, [0, 0, 2, 2], "an edge between cells 1 and 2 lets them jump");
    }

    #[test]
    fn the_guided_push_needs_its_state_and_a_guide_row_per_cell() {
        let (mut v, mut g, mut s) = ([0u16; 12], [0u16; 12], [0u32; 12]);
        let mut out = [0u16; 4];
        let mut sgm = SgmStream::new(4, 3, PEN, &mut v, &mut g, &mut s).unwrap();
        assert!(matches!(
            sgm.push_row_guided(&[0; 12], &[0; 4], &mut out),
            Err(Error::BufferSize {
                what: "SGM guide state",
                ..
            })
        ));
        let mut short = [0u8; 3];
        assert!(matches!(
            sgm.with_guide(&mut short),
            Err(Error::BufferSize {
                what: "SGM guide state",
                ..
            })
        ));
        let (mut v, mut g, mut s, mut prev) = ([0u16; 12], [0u16; 12], [0u32; 12], [0u8; 4]);
        let mut sgm = SgmStream::new(4, 3, PEN, &mut v, &mut g, &mut s)
            .unwrap()
            .with_guide(&mut prev)
            .unwrap();
        assert!(matches!(
            sgm.push_row_guided(&[0; 12], &[0; 3], &mut out),
            Err(Error::BufferSize {
                what: "SGM guide row",
                ..
            })
        ));
    }

    #[test]
    fn the_cell_guide_is_the_rounded_mean_of_each_cell() {
        let rows: [&[u8]; 2] = [&[0, 1, 10, 10, 255, 255], &[1, 1, 10, 11, 255, 255]];
        let mut out = [0u8; 3];
        cell_guide(&rows, 2, &mut out).unwrap();
        assert_eq!(out, [1, 10, 255]); // 3/4 rounds to 1, 41/4 to 10
        assert!(matches!(
            cell_guide(&rows, 2, &mut [0u8; 4]),
            Err(Error::BufferSize {
                what: "SGM guide pixel row",
                ..
            })
        ));
        assert!(matches!(cell_guide(&[], 2, &mut out), Err(Error::EmptyImage)));
    }

    #[test]
    fn bad_buffers_are_errors() {
        let (mut v, mut g, mut s) = ([0u16; 12], [0u16; 11], [0u32; 12]);
        assert!(matches!(
            SgmStream::new(4, 3, PEN, &mut v, &mut g, &mut s),
            Err(Error::BufferSize { .. })
        ));
        let mut g = [0u16; 12];
        assert!(matches!(
            SgmStream::new(4, 0, PEN, &mut v, &mut g, &mut s),
            Err(Error::Candidates { .. })
        ));
        // Regression (fuzzing, issue 12): `cols * candidates` overflowed before any check.
        assert_eq!(state_len(usize::MAX, 3), usize::MAX);
        assert!(matches!(
            SgmStream::new(usize::MAX / 2, 3, PEN, &mut v, &mut g, &mut s),
            Err(Error::BufferSize { .. })
        ));
        let mut sgm = SgmStream::new(4, 3, PEN, &mut v, &mut g, &mut s).unwrap();
        let mut out = [0u16; 4];
        assert!(matches!(
            sgm.push_row(&[0; 11], &mut out),
            Err(Error::BufferSize { .. })
        ));
        assert!(matches!(
            sgm.push_row(&[0; 12], &mut out[..3]),
            Err(Error::BufferSize { .. })
        ));
    }
}
