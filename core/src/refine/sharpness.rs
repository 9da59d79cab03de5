//! Sharpness equalisation of the views before the refinement's census (issue 14): where one view
//! is defocused, the census codes of the sharp view no longer match, and the refinement's gain
//! vanishes (160 px validation pairs, right view under a 5x5 box blur: refined 0.892 epe against
//! 0.889 unrefined; with the sharper view blurred to the other's sharpness first, 0.702).
//!
//! The rules are those of `train/bino_train/sharpness.py` (the specification), per output row
//! `y`:
//! 1. `box(v, k)`: the mean of the `(2k + 1)^2` window, coordinates clamped to the image,
//!    rounded half up (`(sum + n / 2) / n`); [`box_row`] makes one row of it.
//! 2. `g(v, k, row)`: the sum of `|s(x + 1) - s(x)|` along the row, `s = box(box(v, k), 1)`
//!    ([`gradient_sum`] of a row of `s`).
//! 3. `S(v, k)`: `g` summed over the rows `y - WINDOW ..= y + WINDOW` (clamped).
//! 4. [`decide`]: the sharper view (left on ties) is blurred only when `100 own > (100 +
//!    MARGIN_PCT) target`, with the radius in `0..=MAX_RADIUS` whose `S` comes closest to the
//!    other view's (ties to the smaller radius);
//!    4a. and only when it is also sharper relative to its own coarse gradients: `100 S(s, 0)
//!    S(o, MAX_RADIUS) > (100 + CONTRAST_MARGIN_PCT) S(o, 0) S(s, MAX_RADIUS)`, so that a view
//!    with less contrast (exposure gain, a tone curve: smaller gradients at every scale) is not
//!    read as a defocused one (which loses its fine gradients more than its coarse ones).
//! 5. Row `y`'s census reads `box(sharper, k)` in place of the sharper view.
//!
//! The rules' building blocks, [`SharpnessWindow`] (the decisions, streaming, equal to the
//! whole-map ones), [`EqualisedRefiner`] (the streaming refinement with them, equal to the
//! whole-map one row for row), [`refine_map_equalised`] (the whole-map reference, pinned bit for
//! bit to the Python by `tests/fixtures/refine/equalised.bin`), and the pipeline's refinement
//! stage behind `pipeline::Refine::equalise` (its windows widened to [`equalised_reach`], equal
//! to the whole-map reference over every band layout). On in every command, preset and the
//! firmware (`pipeline::Refine::EQUALISE`).
//!
//! Integers only; every sum fits: `g <= 255 (W - 1)`, so `S < 2^32` for any `W <= 2^20 / 7`, and
//! the comparisons run in `u64` (rule 4a's products of two sums in `u128`).

use super::{refine_row, token_rows, window_row, RefineParams, RowRefiner, TokenRows, ViewRows, MAX_WINDOW_ROWS};
use crate::Error;

/// Rows above and below the output row whose sharpness decides it.
pub const WINDOW: usize = 3;
/// How much sharper (%) the sharper view must be before it is blurred.
pub const MARGIN_PCT: u64 = 25;
/// Largest box radius tried (5x5).
pub const MAX_RADIUS: usize = 2;
/// How much sharper (%) relative to its coarse gradients the sharper view must be (rule 4a).
pub const CONTRAST_MARGIN_PCT: u64 = 15;

/// Which view an output row's census reads blurred, and by how much.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Decision {
    /// `true`: the right view; `false`: the left.
    pub right: bool,
    /// Box radius, `0` (nothing blurred) to [`MAX_RADIUS`].
    pub radius: usize,
}

impl Decision {
    /// Nothing blurred.
    pub const NONE: Self = Self {
        right: false,
        radius: 0,
    };
}

/// One row of `box(v, radius)`: `rows` are the `2 radius + 1` image rows `v - radius ..= v +
/// radius` (clamped to the image by the caller, so a border row may appear several times), each
/// `out.len()` pixels. Errors: [`Error::OutOfRange`] for a radius above [`MAX_RADIUS`],
/// [`Error::BufferSize`] for the wrong number or length of rows, [`Error::EmptyImage`] for an
/// empty `out`.
pub fn box_row(rows: &[&[u8]], radius: usize, out: &mut [u8]) -> Result<(), Error> {
    let mut columns = [0u16; MAX_ROW];
    box_row_checked(rows, radius, out, &mut columns)
}

/// [`box_row`] with `columns` (at least [`MAX_ROW`] entries; contents unused) as the scratch of
/// its column sums.
fn box_row_checked(rows: &[&[u8]], radius: usize, out: &mut [u8], columns: &mut [u16]) -> Result<(), Error> {
    if radius > MAX_RADIUS {
        return Err(Error::OutOfRange {
            what: "box radius",
            value: radius,
            min: 0,
            max: MAX_RADIUS,
        });
    }
    let width = out.len();
    if width == 0 {
        return Err(Error::EmptyImage);
    }
    let taps = 2 * radius + 1;
    Error::check_len("box rows", taps, rows.len())?;
    for row in rows {
        Error::check_len("box row", width, row.len())?;
    }
    box_row_with(rows, radius, out, columns)
}

/// [`box_row`] on checked arguments with `columns`, at least `out.len()` entries, as the column
/// sums' scratch: column sums first (`u16`: at most 5 x 255), then the horizontal window over
/// them ([`window_lanes`]).
fn box_row_with(rows: &[&[u8]], radius: usize, out: &mut [u8], columns: &mut [u16]) -> Result<(), Error> {
    let width = out.len();
    let Some(columns) = columns.get_mut(..width) else {
        return Err(Error::BufferSize {
            what: "box row",
            expected: MAX_ROW,
            found: width,
        });
    };
    let Some((first, others)) = rows.split_first() else {
        return Err(Error::BufferSize {
            what: "box rows",
            expected: 2 * radius + 1,
            found: 0,
        });
    };
    for (c, &p) in columns.iter_mut().zip(first.iter()) {
        *c = p as u16;
    }
    for row in others {
        for (c, &p) in columns.iter_mut().zip(row.iter()) {
            *c += p as u16;
        }
    }
    window_lanes(columns, radius, out);
    Ok(())
}

/// The horizontal window of [`box_row_with`]: the clamped ends pixel by pixel, the interior as
/// shifted copies of the column sums added lane by lane (the compiler vectorises it: Helium on
/// the Cortex-M55; fewer instructions than a sliding sum on the Cortex-M7 too), divided by a
/// multiply and a shift.
fn window_lanes(columns: &[u16], radius: usize, out: &mut [u8]) {
    let width = out.len();
    let taps = 2 * radius + 1;
    let n = (taps * taps) as u32;
    let last = width.saturating_sub(1);
    // Pixel x's window, clamped at the row's ends (and where the row is narrower than it).
    let clamped = |x: usize| -> u8 {
        let sum: u32 = (0..taps)
            .map(|j| {
                columns
                    .get((x + j).saturating_sub(radius).min(last))
                    .copied()
                    .unwrap_or(0) as u32
            })
            .sum();
        ((sum + n / 2) / n) as u8
    };
    let inner = width.saturating_sub(2 * radius);
    if inner == 0 || radius == 0 {
        for (x, o) in out.iter_mut().enumerate() {
            *o = clamped(x);
        }
        return;
    }
    for x in (0..radius).chain(width - radius..width) {
        if let Some(o) = out.get_mut(x) {
            *o = clamped(x);
        }
    }
    let out = out.get_mut(radius..width - radius).unwrap_or_default();
    let shifted = |j: usize| columns.get(j..j + inner).unwrap_or_default();
    match radius {
        1 => {
            let (a, b, c) = (shifted(0), shifted(1), shifted(2));
            for (((o, &a), &b), &c) in out.iter_mut().zip(a).zip(b).zip(c) {
                *o = div_rounded::<1>(a as u32 + b as u32 + c as u32);
            }
        }
        2 => {
            let (a, b, c, d, e) = (shifted(0), shifted(1), shifted(2), shifted(3), shifted(4));
            for (((((o, &a), &b), &c), &d), &e) in out.iter_mut().zip(a).zip(b).zip(c).zip(d).zip(e) {
                *o = div_rounded::<2>(a as u32 + b as u32 + c as u32 + d as u32 + e as u32);
            }
        }
        // Beyond MAX_RADIUS (refused before): the clamped path throughout.
        _ => {
            for (i, o) in out.iter_mut().enumerate() {
                *o = clamped(i + radius);
            }
        }
    }
}

/// `(sum + n / 2) / n` for a window of `n = (2R + 1)^2` pixels (`R` 1 or 2), `sum` at most `n x
/// 255`, as a multiply by `ceil(2^20 / n)` and a shift: exact over that range (tested
/// exhaustively), and a vector unit has no division.
#[inline(always)]
fn div_rounded<const R: usize>(sum: u32) -> u8 {
    let n = ((2 * R + 1) * (2 * R + 1)) as u32;
    let magic = (1u32 << 20).div_ceil(n);
    (((sum + n / 2) * magic) >> 20) as u8
}

/// Widest row [`box_row`] takes (the widest view a blob supports).
pub const MAX_ROW: usize = 640;

/// `sum |row[x + 1] - row[x]|` (rule 2, on a row of `box(box(v, k), 1)`).
pub fn gradient_sum(row: &[u8]) -> u32 {
    row.windows(2).map(|w| w[0].abs_diff(w[1]) as u32).sum()
}

/// Rules 4 and 4a from the window sums `S(left, k)` and `S(right, k)`, `k = 0..=MAX_RADIUS`;
/// `contrast_margin_pct` `None` leaves rule 4a out.
pub fn decide(
    left: &[u64; MAX_RADIUS + 1],
    right: &[u64; MAX_RADIUS + 1],
    margin_pct: u64,
    contrast_margin_pct: Option<u64>,
) -> Decision {
    let (is_right, sharper, other) = if left[0] >= right[0] {
        (false, left, right)
    } else {
        (true, right, left)
    };
    let target = other[0];
    if sharper[0].saturating_mul(100) <= target.saturating_mul(100 + margin_pct) {
        return Decision {
            right: is_right,
            radius: 0,
        };
    }
    let mut best = 0;
    for k in 1..=MAX_RADIUS {
        if sharper[k].abs_diff(target) < sharper[best].abs_diff(target) {
            best = k;
        }
    }
    if let Some(margin) = contrast_margin_pct {
        // Both sides are products of two sums (< 2^64 each for real images); saturating, so
        // any input is defined.
        let wide = |a: u64, b: u64, pct: u64| (a as u128).saturating_mul(b as u128).saturating_mul(pct as u128);
        let own = wide(sharper[0], other[MAX_RADIUS], 100);
        let theirs = wide(target, sharper[MAX_RADIUS], 100u64.saturating_add(margin));
        if own <= theirs {
            best = 0;
        }
    }
    Decision {
        right: is_right,
        radius: best,
    }
}

/// View rows above and below an output row that its decision reads: the `WINDOW` rows of
/// sums, each a row of `box(box(v, k), 1)`, so `1 + MAX_RADIUS` rows more.
pub const DECISION_REACH: usize = WINDOW + 1 + MAX_RADIUS;

/// Rows a decision window holds.
pub const DECISION_ROWS: usize = 2 * DECISION_REACH + 1;

/// Slots of the sums' ring: the `2 WINDOW + 1` rows one decision reads.
const SUM_ROWS: usize = 2 * WINDOW + 1;

/// The streaming form of [`decide_map_row`]: the sums `g(v, k, row)` of each image row computed
/// once and kept in a ring of the `2 WINDOW + 1` rows a decision reads (consecutive output rows
/// share all but one), from the view rows around the output row. The views must stay the same
/// image between calls; for another image make a new window.
pub struct SharpnessWindow {
    width: usize,
    height: usize,
    /// Image row whose sums each slot holds.
    held: [usize; SUM_ROWS],
    /// Per slot, `g` of the left then the right view, `k = 0..=MAX_RADIUS`.
    sums: [[[u32; MAX_RADIUS + 1]; 2]; SUM_ROWS],
}

impl SharpnessWindow {
    /// A window for `width x height` views (`width <= MAX_ROW`).
    pub fn new(width: usize, height: usize) -> Result<Self, Error> {
        if width == 0 || height == 0 {
            return Err(Error::EmptyImage);
        }
        if width > MAX_ROW {
            return Err(Error::TooWide { width, max: MAX_ROW });
        }
        Ok(Self {
            width,
            height,
            held: [usize::MAX; SUM_ROWS],
            sums: [[[0; MAX_RADIUS + 1]; 2]; SUM_ROWS],
        })
    }

    /// The decision for output row `y`: `left` and `right` hold [`DECISION_ROWS`] rows each,
    /// entry `e` the image row [`window_row`]`(y, e, DECISION_REACH, height)`. Equal to
    /// [`decide_map_row`] of the whole maps. Errors: [`Error::OutOfRange`] for `y`,
    /// [`Error::BufferSize`] for a window or row of the wrong length.
    pub fn decide(&mut self, y: usize, left: &[&[u8]], right: &[&[u8]]) -> Result<Decision, Error> {
        if y >= self.height {
            return Err(Error::OutOfRange {
                what: "row",
                value: y,
                min: 0,
                max: self.height - 1,
            });
        }
        for rows in [left, right] {
            Error::check_len("decision window", DECISION_ROWS, rows.len())?;
            for row in rows {
                Error::check_len("decision window row", self.width, row.len())?;
            }
        }
        let mut totals = [[0u64; MAX_RADIUS + 1]; 2];
        // The rows' scratch, set up once for the rows this decision adds (one, row after row).
        let mut work: Option<Work> = None;
        for i in 0..SUM_ROWS {
            let r = window_row(y, i, WINDOW, self.height);
            let slot = r % SUM_ROWS;
            if self.held.get(slot) != Some(&r) {
                let work = work.get_or_insert_with(Work::new);
                let mut sums = [[0u32; MAX_RADIUS + 1]; 2];
                for (g, rows) in sums.iter_mut().zip([left, right]) {
                    for (k, v) in g.iter_mut().enumerate() {
                        *v = self.gradient(y, r, k, rows, work)?;
                    }
                }
                if let (Some(s), Some(h)) = (self.sums.get_mut(slot), self.held.get_mut(slot)) {
                    *s = sums;
                    *h = r;
                }
            }
            let sums = self.sums.get(slot).copied().unwrap_or_default();
            for (t, g) in totals.iter_mut().zip(sums) {
                for (t, g) in t.iter_mut().zip(g) {
                    *t += g as u64;
                }
            }
        }
        Ok(decide(&totals[0], &totals[1], MARGIN_PCT, Some(CONTRAST_MARGIN_PCT)))
    }

    /// `g(view, k, r)` from the window around output row `y` (`rows`, as [`Self::decide`]).
    fn gradient(&self, y: usize, r: usize, k: usize, rows: &[&[u8]], work: &mut Work) -> Result<u32, Error> {
        let (width, height) = (self.width, self.height);
        // Image row q of the window: entry q + DECISION_REACH - y (every row read lies in it).
        let entry = |q: usize| {
            rows.get((q + DECISION_REACH).saturating_sub(y))
                .copied()
                .unwrap_or_default()
        };
        let Work {
            blurred,
            smooth,
            columns,
        } = work;
        let mut three: [&[u8]; 3] = [&[]; 3];
        if k == 0 {
            // box(v, 0) is the view itself.
            for (i, t) in three.iter_mut().enumerate() {
                *t = entry(window_row(r, i, 1, height));
            }
        } else {
            for (i, b) in blurred.iter_mut().enumerate() {
                let q = window_row(r, i, 1, height);
                let mut source: [&[u8]; 2 * MAX_RADIUS + 1] = [&[]; 2 * MAX_RADIUS + 1];
                for (j, s) in source.iter_mut().enumerate().take(2 * k + 1) {
                    *s = entry(window_row(q, j, k, height));
                }
                box_row_checked(
                    source.get(..2 * k + 1).unwrap_or_default(),
                    k,
                    b.get_mut(..width).unwrap_or_default(),
                    columns,
                )?;
            }
            for (t, b) in three.iter_mut().zip(blurred.iter()) {
                *t = b.get(..width).unwrap_or_default();
            }
        }
        let smooth = smooth.get_mut(..width).unwrap_or_default();
        box_row_checked(&three, 1, smooth, columns)?;
        Ok(gradient_sum(smooth))
    }
}

/// The scratch of [`SharpnessWindow::gradient`]: three blurred rows, their smoothed row and the
/// column sums, at the widest row.
struct Work {
    blurred: [[u8; MAX_ROW]; 3],
    smooth: [u8; MAX_ROW],
    columns: [u16; MAX_ROW],
}

impl Work {
    fn new() -> Self {
        Self {
            blurred: [[0; MAX_ROW]; 3],
            smooth: [0; MAX_ROW],
            columns: [0; MAX_ROW],
        }
    }
}

/// View rows above and below an output row that [`EqualisedRefiner`] reads with `params`: the
/// refinement's reach plus the widest box, and at least the decision's.
pub const fn equalised_reach(params: &RefineParams) -> usize {
    let census = params.reach() + MAX_RADIUS;
    if census > DECISION_REACH {
        census
    } else {
        DECISION_REACH
    }
}

/// Most rows an [`EqualisedRefiner`] window holds.
pub const MAX_EQUALISED_ROWS: usize = 2 * (super::MAX_CENSUS_RADIUS + super::MAX_BOX_RADIUS + MAX_RADIUS) + 1;

/// `u8` entries of the smoothed-rows scratch an [`EqualisedRefiner`] needs for rows of `width`.
pub const fn smoothed_len(width: usize, params: &RefineParams) -> usize {
    params.window_rows().saturating_mul(width)
}

/// The streaming refinement with sharpness equalisation: per output row the decision of a
/// [`SharpnessWindow`], the sharper view's window rows box-blurred into a scratch when it says
/// so, then a [`RowRefiner`] on those rows (its census rows dropped whenever the decision
/// changes). Equal to [`refine_map_equalised`] row for row, in any order.
pub struct EqualisedRefiner<'s> {
    refiner: RowRefiner<'s>,
    window: SharpnessWindow,
    smoothed: &'s mut [u8],
    params: RefineParams,
    last: Option<Decision>,
}

impl<'s> EqualisedRefiner<'s> {
    /// A refiner for `width x height` views: `census` of [`scratch_len`](super::scratch_len)
    /// and `smoothed` of [`smoothed_len`] entries (contents unused).
    pub fn new(
        census: &'s mut [u32],
        smoothed: &'s mut [u8],
        width: usize,
        height: usize,
        params: &RefineParams,
    ) -> Result<Self, Error> {
        Error::check_len("smoothed rows", smoothed_len(width, params), smoothed.len())?;
        Ok(Self {
            refiner: RowRefiner::new(census, width, params)?,
            window: SharpnessWindow::new(width, height)?,
            smoothed,
            params: *params,
            last: None,
        })
    }

    /// Refines output row `y` into `out`: `rows` holds `2 equalised_reach(params) + 1` rows of
    /// each view around `y` (entry `e` the image row [`window_row`]`(y, e, equalised_reach,
    /// H)`), `tokens` as for [`RowRefiner::refine_row`]. Errors as that and
    /// [`SharpnessWindow::decide`].
    pub fn refine_row(
        &mut self,
        y: usize,
        rows: &ViewRows<'_>,
        tokens: &TokenRows<'_>,
        out: &mut [u16],
    ) -> Result<(), Error> {
        // Entries `wide - half ..= wide + half` of a window around `y`: the same clamped rows.
        fn middle<'r, 'a>(side: &'r [&'a [u8]], wide: usize, half: usize) -> &'r [&'a [u8]] {
            side.get(wide - half..wide + half + 1).unwrap_or_default()
        }
        let params = self.params;
        let (reach, wide) = (params.reach(), equalised_reach(&params));
        for side in [rows.left, rows.right] {
            Error::check_len("equalised window", 2 * wide + 1, side.len())?;
        }
        let decision = self.window.decide(
            y,
            middle(rows.left, wide, DECISION_REACH),
            middle(rows.right, wide, DECISION_REACH),
        )?;
        let decision = if decision.radius == 0 { Decision::NONE } else { decision };
        if self.last != Some(decision) {
            self.refiner.forget();
            self.last = Some(decision);
        }
        let (left, right) = (middle(rows.left, wide, reach), middle(rows.right, wide, reach));
        if decision.radius == 0 {
            let plain = ViewRows {
                height: rows.height,
                left,
                right,
            };
            return self.refiner.refine_row(y, &plain, tokens, out);
        }
        let (width, height, k) = (out.len(), rows.height, decision.radius);
        let source = if decision.right { rows.right } else { rows.left };
        for (e, buf) in self.smoothed.chunks_exact_mut(width).enumerate() {
            let v = window_row(y, e, reach, height);
            let mut taps: [&[u8]; 2 * MAX_RADIUS + 1] = [&[]; 2 * MAX_RADIUS + 1];
            for (j, t) in taps.iter_mut().enumerate().take(2 * k + 1) {
                let q = window_row(v, j, k, height);
                *t = source.get((q + wide).saturating_sub(y)).copied().unwrap_or_default();
            }
            box_row(taps.get(..2 * k + 1).unwrap_or_default(), k, buf)?;
        }
        let mut smooth_rows: [&[u8]; MAX_WINDOW_ROWS] = [&[]; MAX_WINDOW_ROWS];
        for (r, buf) in smooth_rows.iter_mut().zip(self.smoothed.chunks_exact(width)) {
            *r = buf;
        }
        let smooth = smooth_rows.get(..2 * reach + 1).unwrap_or_default();
        let (left, right) = if decision.right {
            (left, smooth)
        } else {
            (smooth, right)
        };
        let equalised = ViewRows { height, left, right };
        self.refiner.refine_row(y, &equalised, tokens, out)
    }
}

/// Row `v` of `box(view, k)` of an `H x W` map (rows clamped to the map).
fn map_box_row(view: &[u8], width: usize, height: usize, v: usize, k: usize, out: &mut [u8]) -> Result<(), Error> {
    let mut rows: [&[u8]; 2 * MAX_RADIUS + 1] = [&[]; 2 * MAX_RADIUS + 1];
    for (i, row) in rows.iter_mut().enumerate().take(2 * k + 1) {
        let r = window_row(v, i, k, height);
        *row = view.get(r * width..(r + 1) * width).unwrap_or_default();
    }
    box_row(rows.get(..2 * k + 1).unwrap_or_default(), k, out)
}

/// `g(view, k, row)` of an `H x W` map (rule 2).
fn map_gradient(view: &[u8], width: usize, height: usize, row: usize, k: usize) -> Result<u32, Error> {
    let mut blurred = [[0u8; MAX_ROW]; 3];
    for (i, b) in blurred.iter_mut().enumerate() {
        let r = window_row(row, i, 1, height);
        map_box_row(view, width, height, r, k, b.get_mut(..width).unwrap_or_default())?;
    }
    let mut smooth = [0u8; MAX_ROW];
    let [a, b, c] = &blurred;
    let rows = [
        a.get(..width).unwrap_or_default(),
        b.get(..width).unwrap_or_default(),
        c.get(..width).unwrap_or_default(),
    ];
    let smooth = smooth.get_mut(..width).unwrap_or_default();
    box_row(&rows, 1, smooth)?;
    Ok(gradient_sum(smooth))
}

/// The decision for output row `y` of `H x W` maps (rules 2-4, [`WINDOW`], [`MARGIN_PCT`]).
pub fn decide_map_row(left: &[u8], right: &[u8], width: usize, height: usize, y: usize) -> Result<Decision, Error> {
    let sums = map_window_sums(left, right, width, height, y)?;
    Ok(decide(&sums[0], &sums[1], MARGIN_PCT, Some(CONTRAST_MARGIN_PCT)))
}

/// `S(left, k)` and `S(right, k)` around output row `y` of whole maps (rule 3).
fn map_window_sums(
    left: &[u8],
    right: &[u8],
    width: usize,
    height: usize,
    y: usize,
) -> Result<[[u64; MAX_RADIUS + 1]; 2], Error> {
    let mut sums = [[0u64; MAX_RADIUS + 1]; 2];
    for (view, s) in [left, right].into_iter().zip(sums.iter_mut()) {
        for (k, total) in s.iter_mut().enumerate() {
            for i in 0..=2 * WINDOW {
                *total += map_gradient(view, width, height, window_row(y, i, WINDOW, height), k)? as u64;
            }
        }
    }
    Ok(sums)
}

/// [`refine_map`](super::refine_map) with each output row's census on the views its
/// [`decide_map_row`] decision smooths (rule 5): the reference of the equalised refinement, as
/// `bino_train.sharpness.refine_equalised` computes it. Maps up to [`MAX_ROW`] pixels wide.
pub fn refine_map_equalised(
    left: &[u8],
    right: &[u8],
    width: usize,
    tokens: &[u16],
    params: &RefineParams,
    scratch: &mut [u32],
    out: &mut [u16],
) -> Result<(), Error> {
    params.check()?;
    if width > MAX_ROW {
        return Err(Error::TooWide { width, max: MAX_ROW });
    }
    let (height, grid_rows, cells) = super::map_shape(left, right, width, tokens.len(), out.len())?;
    let (reach, window) = (params.reach(), params.window_rows());
    let token_row = |t: usize| tokens.get(t * cells..(t + 1) * cells).unwrap_or_default();
    let mut smoothed = [[0u8; MAX_ROW]; MAX_WINDOW_ROWS];
    for (y, out_row) in out.chunks_exact_mut(width).enumerate() {
        let decision = decide_map_row(left, right, width, height, y)?;
        let (sharper, other) = if decision.right { (right, left) } else { (left, right) };
        let mut rows_sharp: [&[u8]; MAX_WINDOW_ROWS] = [&[]; MAX_WINDOW_ROWS];
        let mut rows_other: [&[u8]; MAX_WINDOW_ROWS] = [&[]; MAX_WINDOW_ROWS];
        for (e, buf) in smoothed.iter_mut().enumerate().take(window) {
            let v = window_row(y, e, reach, height);
            let buf = buf.get_mut(..width).unwrap_or_default();
            map_box_row(sharper, width, height, v, decision.radius, buf)?;
            if let Some(r) = rows_other.get_mut(e) {
                *r = other.get(v * width..(v + 1) * width).unwrap_or_default();
            }
        }
        for (r, buf) in rows_sharp.iter_mut().zip(smoothed.iter()).take(window) {
            *r = buf.get(..width).unwrap_or_default();
        }
        let (rows_l, rows_r) = if decision.right {
            (&rows_other, &rows_sharp)
        } else {
            (&rows_sharp, &rows_other)
        };
        let rows = ViewRows {
            height,
            left: rows_l.get(..window).unwrap_or_default(),
            right: rows_r.get(..window).unwrap_or_default(),
        };
        let (first, second) = token_rows(y, grid_rows);
        let grid = TokenRows {
            first: token_row(first),
            second: token_row(second),
        };
        refine_row(y, &rows, &grid, params, scratch, out_row)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests;
