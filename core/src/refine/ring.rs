//! The faster refinement of consecutive rows: [`RowRefiner::refine_row`] gives what the
//! reference [`refine_row`](super::refine_row) gives, bit for bit (tested against it), with
//! less work:
//! - a ring of census rows: the census codes of image row `v` are computed once, in slot
//!   `v % (2b + 1)`, and kept while the next output rows' boxes still cover it (the reference
//!   recomputes the `2b + 1` box rows of both views for every output row);
//! - the census of a row's interior (every neighbour inside the row) as one pass over the row
//!   per neighbour, which the compiler vectorises (MVE on the Cortex-M55); the `r` pixels at each
//!   end take the reference's clamped path;
//! - the box sums by column, sliding: `A(k)` is the sum over the box's columns of a column cost
//!   (the Hamming distances of the `2b + 1` box rows at one column), and a candidate disparity
//!   the previous pixel had too (its centre candidate may differ: the sets overlap) shares all
//!   but one column with it, so one column cost is computed and the sum moves by the new column
//!   less the oldest. Integer sums in another order: exact.
//!
//! The views must stay the same image between calls (the pipeline's do); after the scratch
//! was used for something else, or for another image, start again with [`RowRefiner::new`].

use super::{
    bilinear, census_row, check_row_inputs, subpixel_step, winner, RefineParams, TokenRows, ViewRows, FRAC_BITS,
    MAX_BOX_RADIUS, MAX_CANDIDATES, MAX_WINDOW_ROWS,
};
use crate::config::CELL_W;
use crate::Error;

/// Most box rows (and columns).
const MAX_BOX: usize = 2 * MAX_BOX_RADIUS + 1;
/// A slot that holds no row.
const EMPTY: usize = usize::MAX;

/// The refinement of one image's rows with a ring of census rows in a caller's scratch of
/// [`scratch_len`](super::scratch_len) entries.
pub struct RowRefiner<'s> {
    params: RefineParams,
    width: usize,
    /// `2b + 1` left-view census rows, then as many right-view rows.
    census: &'s mut [u32],
    /// Image row held by each slot.
    held: [usize; MAX_BOX],
}

impl<'s> RowRefiner<'s> {
    /// A refiner for rows of `width` pixels with `params`; `scratch` must hold
    /// [`scratch_len`](super::scratch_len)`(width, params)` entries (its contents are unused).
    pub fn new(scratch: &'s mut [u32], width: usize, params: &RefineParams) -> Result<Self, Error> {
        params.check()?;
        if width == 0 {
            return Err(Error::EmptyImage);
        }
        Error::check_len("refinement scratch", super::scratch_len(width, params), scratch.len())?;
        Ok(Self {
            params: *params,
            width,
            census: scratch,
            held: [EMPTY; MAX_BOX],
        })
    }

    /// Drops the census rows kept so far: the next row computes its own (for a caller that
    /// changed what the views hold, as the sharpness equalisation does between rows).
    pub fn forget(&mut self) {
        self.held = [EMPTY; MAX_BOX];
    }

    /// [`refine_row`](super::refine_row) of output row `y` (same arguments, same result, same
    /// errors), reusing the census rows earlier calls computed.
    pub fn refine_row(
        &mut self,
        y: usize,
        rows: &ViewRows<'_>,
        tokens: &TokenRows<'_>,
        out: &mut [u16],
    ) -> Result<(), Error> {
        let (width, height, params) = (self.width, rows.height, self.params);
        Error::check_len("refined row", width, out.len())?;
        check_row_inputs(y, width, rows, tokens, &params)?;
        let cells = width.div_ceil(CELL_W);

        let (r, b) = (params.census_radius, params.box_radius);
        let box_rows = 2 * b + 1;
        // Box row i is image row v = clamp(y + i - b), in slot v % box_rows (the box's rows are
        // consecutive, so their slots differ); its census reads window entries from v + b - y.
        let mut slots = [0usize; MAX_BOX];
        for (i, slot) in slots.iter_mut().enumerate().take(box_rows) {
            let v = super::window_row(y, i, b, height);
            *slot = v % box_rows;
            if self.held.get(*slot) == Some(&v) {
                continue;
            }
            let top = (v + b).saturating_sub(y);
            let (left, right) = self.census.split_at_mut(box_rows * width);
            let at = *slot * width..(*slot + 1) * width;
            census_fast(
                rows.left.get(top..).unwrap_or_default(),
                r,
                left.get_mut(at.clone()).unwrap_or_default(),
            );
            census_fast(
                rows.right.get(top..).unwrap_or_default(),
                r,
                right.get_mut(at).unwrap_or_default(),
            );
            if let Some(h) = self.held.get_mut(*slot) {
                *h = v;
            }
        }
        let (left, right) = self.census.split_at(box_rows * width);
        let mut box_l: [&[u32]; MAX_BOX] = [&[]; MAX_BOX];
        let mut box_r: [&[u32]; MAX_BOX] = [&[]; MAX_BOX];
        for i in 0..box_rows {
            let at = slots[i] * width..(slots[i] + 1) * width;
            box_l[i] = left.get(at.clone()).unwrap_or_default();
            box_r[i] = right.get(at).unwrap_or_default();
        }
        let (box_l, box_r) = (&box_l[..box_rows], &box_r[..box_rows]);

        let search = params.search as i64;
        let candidates = 2 * params.search + 1;
        let mut costs = [0u32; MAX_CANDIDATES];
        let mut valid = [false; MAX_CANDIDATES];
        // One sliding box per candidate disparity, in slot `d % candidates` (a pixel's candidates
        // are consecutive, so their slots differ): a disparity the previous pixel had too costs
        // one new column, whatever the previous pixel's centre candidate was.
        let mut windows = [Window::EMPTY; MAX_CANDIDATES];
        let boxes = Boxes {
            left: box_l,
            right: box_r,
            radius: b,
            last: width - 1,
        };
        // The previous pixel's valid disparities (none before the first).
        let mut previous: Option<(usize, usize)> = None;
        // New columns' costs of the disparities sliding at this pixel, from the lowest.
        let mut fresh = [0u32; MAX_CANDIDATES];
        for (x, o) in out.iter_mut().enumerate() {
            let d0 = bilinear(x, y, tokens, cells);
            let base = ((d0 + 128) >> FRAC_BITS) as i64;
            // Valid disparities `lo..=hi` (0 <= d <= x); those the previous pixel had too slide,
            // their new column's costs computed together.
            let lo = (base - search).max(0) as usize;
            let hi = (base + search).min(x as i64);
            let valid_now = (hi >= lo as i64).then_some((lo, hi.max(0) as usize));
            let sliding = match (valid_now, previous) {
                (Some((lo, hi)), Some((plo, phi))) if lo.max(plo) <= hi.min(phi) => Some((lo.max(plo), hi.min(phi))),
                _ => None,
            };
            if let Some((slo, shi)) = sliding {
                let new = fresh.get_mut(..shi - slo + 1).unwrap_or_default();
                column_costs(box_l, box_r, (x + b).min(width - 1), slo, new);
            }
            previous = valid_now;
            for (slot, (c, ok)) in costs.iter_mut().zip(valid.iter_mut()).take(candidates).enumerate() {
                let d = base + slot as i64 - search;
                *ok = d >= 0 && d <= x as i64;
                if !*ok {
                    *c = u32::MAX;
                    continue;
                }
                let new = match sliding {
                    Some((slo, shi)) if (slo as i64..=shi as i64).contains(&d) => fresh.get(d as usize - slo).copied(),
                    _ => None,
                };
                let hamming = match windows.get_mut(d as usize % candidates) {
                    Some(window) => window.sum_at(&boxes, x, d as usize, new),
                    None => 0,
                };
                let penalty = (d << FRAC_BITS).abs_diff(d0 as i64);
                *c = (hamming << FRAC_BITS).saturating_add(params.lambda.saturating_mul(penalty as u32));
            }
            *o = match winner(&costs[..candidates], &valid[..candidates], params.search) {
                Some(slot) => {
                    let d = base + slot as i64 - search;
                    let step = subpixel_step(&costs[..candidates], &valid[..candidates], slot);
                    ((d << FRAC_BITS) + step).clamp(0, u16::MAX as i64) as u16
                }
                None => d0.min(u16::MAX as u32) as u16,
            };
        }
        Ok(())
    }
}

/// The census codes of one output row's box rows, and the box's shape.
struct Boxes<'b> {
    left: &'b [&'b [u32]],
    right: &'b [&'b [u32]],
    /// Box radius `b`.
    radius: usize,
    /// The row's last column.
    last: usize,
}

/// The box sum `A` of one candidate disparity at one pixel: the column costs of its `2b + 1`
/// columns (a ring, the leftmost at `at`) and their sum.
#[derive(Clone, Copy)]
struct Window {
    /// Disparity and pixel the sums are for (`usize::MAX`: none yet).
    d: usize,
    x: usize,
    at: usize,
    sum: u32,
    columns: [u32; MAX_BOX],
}

impl Window {
    const EMPTY: Self = Self {
        d: usize::MAX,
        x: usize::MAX,
        at: 0,
        sum: 0,
        columns: [0; MAX_BOX],
    };

    /// `A` of disparity `d` at pixel `x` (columns `clamp(x - b ..= x + b)`): slid by one column
    /// from pixel `x - 1` when it holds that one's for `d` (the new column's cost `new` when the
    /// caller computed it), else summed anew. Integer sums of the same columns, so exact either
    /// way.
    fn sum_at(&mut self, boxes: &Boxes<'_>, x: usize, d: usize, new: Option<u32>) -> u32 {
        let box_cols = 2 * boxes.radius + 1;
        if self.d == d && self.x.wrapping_add(1) == x {
            let u = (x + boxes.radius).min(boxes.last);
            let new = new.unwrap_or_else(|| column_cost(boxes.left, boxes.right, u, d));
            if let Some(old) = self.columns.get_mut(self.at) {
                self.sum = self.sum + new - *old;
                *old = new;
            }
            self.at = if self.at + 1 == box_cols { 0 } else { self.at + 1 };
        } else {
            let columns = self.columns.get_mut(..box_cols).unwrap_or_default();
            window_columns(boxes, x, d, columns);
            self.sum = columns.iter().sum();
            self.at = 0;
        }
        (self.d, self.x) = (d, x);
        self.sum
    }
}

/// [`column_cost`] of disparity `d` at the box columns of pixel `x` (`clamp(x - b ..= x + b)`)
/// into `out`: where no column or right column is clamped, each box row's codes against the
/// right row's `d` to the left, lane by lane (the compiler vectorises it: Helium on the
/// Cortex-M55); at the row's ends column by column.
fn window_columns(boxes: &Boxes<'_>, x: usize, d: usize, out: &mut [u32]) {
    let cols = out.len();
    let interior = x
        .checked_sub(boxes.radius)
        .filter(|&u0| u0 >= d && u0 + cols - 1 <= boxes.last);
    let Some(u0) = interior else {
        for (j, c) in out.iter_mut().enumerate() {
            let u = (x + j).saturating_sub(boxes.radius).min(boxes.last);
            *c = column_cost(boxes.left, boxes.right, u, d);
        }
        return;
    };
    out.fill(0);
    for (l, r) in boxes.left.iter().zip(boxes.right) {
        let (Some(l), Some(r)) = (l.get(u0..u0 + cols), r.get(u0 - d..u0 - d + cols)) else {
            continue;
        };
        for ((c, &a), &b) in out.iter_mut().zip(l).zip(r) {
            *c += hamming(a, b);
        }
    }
}

/// [`column_cost`] of the disparities `d_lo..d_lo + out.len()` at column `u` into `out`, every
/// one at most `u` (so no right column is clamped): each box row's left code at `u` against the
/// consecutive right codes `u - d`, a loop the compiler vectorises (Helium on the Cortex-M55).
fn column_costs(left: &[&[u32]], right: &[&[u32]], u: usize, d_lo: usize, out: &mut [u32]) {
    let count = out.len();
    // Right columns u - d_lo - count + 1 ..= u - d_lo: the highest disparity first.
    let first = (u + 1).checked_sub(d_lo + count);
    let mut reversed = [0u32; MAX_CANDIDATES];
    let (Some(first), Some(acc)) = (first, reversed.get_mut(..count)) else {
        for (k, o) in out.iter_mut().enumerate() {
            *o = column_cost(left, right, u, d_lo + k);
        }
        return;
    };
    for (l, r) in left.iter().zip(right) {
        let code = l.get(u).copied().unwrap_or(0);
        match r.get(first..first + count) {
            Some(codes) => {
                for (a, &c) in acc.iter_mut().zip(codes) {
                    *a += hamming(code, c);
                }
            }
            None => {
                for (j, a) in acc.iter_mut().enumerate() {
                    *a += hamming(code, r.get(first + j).copied().unwrap_or(0));
                }
            }
        }
    }
    for (o, &a) in out.iter_mut().zip(acc.iter().rev()) {
        *o = a;
    }
}

/// The Hamming distance of two census codes: `(a ^ b).count_ones()`, spelt out so that a loop of
/// it vectorises (the Cortex-M55's Helium has no population count; the compiler leaves
/// `count_ones` scalar there, a dozen instructions per pixel).
#[inline(always)]
pub(crate) fn hamming(a: u32, b: u32) -> u32 {
    let x = a ^ b;
    let x = x - ((x >> 1) & 0x5555_5555);
    let x = (x & 0x3333_3333) + ((x >> 2) & 0x3333_3333);
    // Each byte now holds its own count (at most 8); the bytes' sum is at most 32.
    let x = (x + (x >> 4)) & 0x0f0f_0f0f;
    let x = x + (x >> 8);
    (x + (x >> 16)) & 0x3f
}

/// Hamming distances of the box rows at column `u`, left code at `u` against right code at
/// `u - d` (column 0 where that is left of the view).
fn column_cost(left: &[&[u32]], right: &[&[u32]], u: usize, d: usize) -> u32 {
    let ur = u.saturating_sub(d);
    left.iter()
        .zip(right)
        .map(|(l, r)| (l.get(u).copied().unwrap_or(0) ^ r.get(ur).copied().unwrap_or(0)).count_ones())
        .sum()
}

/// The reference's census of one row (`window[j]` = image row `clamp(v + j - r)`), its interior
/// one neighbour at a time over the whole row.
pub(crate) fn census_fast(window: &[&[u8]], r: usize, out: &mut [u32]) {
    let width = out.len();
    if width < 2 * r + 1 || window.len() < 2 * r + 1 {
        census_row(window, r, out);
        return;
    }
    let mut rows: [&[u8]; MAX_WINDOW_ROWS] = [&[]; MAX_WINDOW_ROWS];
    for (dst, src) in rows.iter_mut().zip(window).take(2 * r + 1) {
        if src.len() != width {
            census_row(window, r, out);
            return;
        }
        *dst = src;
    }
    let centre = rows[r].get(r..width - r).unwrap_or_default();
    let interior = out.get_mut(r..width - r).unwrap_or_default();
    interior.fill(0);
    let mut bit = 0u32;
    for (j, row) in rows.iter().enumerate().take(2 * r + 1) {
        for i in 0..=2 * r {
            if i == r && j == r {
                continue;
            }
            let neighbours = row.get(i..i + width - 2 * r).unwrap_or_default();
            for ((code, &c), &n) in interior.iter_mut().zip(centre).zip(neighbours) {
                *code |= u32::from(n < c) << bit;
            }
            bit += 1;
        }
    }
    // The clamped ends, as the reference computes them.
    let mut edge = [0u32; 2 * super::MAX_CENSUS_RADIUS + 1];
    for (start, len) in [(0, r), (width - r, r)] {
        census_at(&rows[..2 * r + 1], r, width, start, &mut edge[..len]);
        if let Some(dst) = out.get_mut(start..start + len) {
            dst.copy_from_slice(&edge[..len]);
        }
    }
}

/// The reference's census of pixels `start..start + out.len()` of a row of `width`.
fn census_at(window: &[&[u8]], r: usize, width: usize, start: usize, out: &mut [u32]) {
    let centre_row = window.get(r).copied().unwrap_or_default();
    for (n, code) in out.iter_mut().enumerate() {
        let u = start + n;
        let centre = centre_row.get(u).copied().unwrap_or(0);
        let mut bits = 0u32;
        let mut bit = 0u32;
        for (j, row) in window.iter().enumerate() {
            for i in 0..=2 * r {
                if i == r && j == r {
                    continue;
                }
                let col = (u + i).saturating_sub(r).min(width - 1);
                bits |= u32::from(row.get(col).copied().unwrap_or(0) < centre) << bit;
                bit += 1;
            }
        }
        *code = bits;
    }
}

#[cfg(test)]
mod tests {
    use super::super::{refine_row, scratch_len, token_rows, window_row};
    use super::*;
    use crate::testutil::Rng;

    const MAX_W: usize = 40;
    const MAX_H: usize = 20;

    /// Rows `order` of an `h x w` pair through both, on a smooth or a noisy grid.
    fn agree(seed: u64, w: usize, h: usize, params: &RefineParams, order: &[usize]) {
        let mut rng = Rng::new(seed);
        let (mut left, mut right) = ([0u8; MAX_W * MAX_H], [0u8; MAX_W * MAX_H]);
        let flat = rng.range(0, 3) == 0;
        for i in 0..w * h {
            left[i] = if flat { 100 } else { rng.range(0, 255) as u8 };
            right[i] = rng.range(0, 255) as u8;
        }
        let (grid_rows, cells) = (h.div_ceil(4), w.div_ceil(4));
        let mut grid = [0u16; MAX_W * MAX_H];
        let smooth = rng.range(0, 1) == 0;
        let top = rng.range(0, 40 * 256);
        for g in grid.iter_mut().take(grid_rows * cells) {
            *g = if smooth {
                (top + rng.range(0, 96)) as u16
            } else {
                rng.range(0, 65535) as u16
            };
        }
        let n = scratch_len(w, params);
        let (mut s_ref, mut s_ring) = ([0u32; 2 * MAX_BOX * MAX_W], [0u32; 2 * MAX_BOX * MAX_W]);
        let mut refiner = RowRefiner::new(&mut s_ring[..n], w, params).unwrap();
        let (reach, window) = (params.reach(), params.window_rows());
        for &y in order {
            let mut rl: [&[u8]; MAX_WINDOW_ROWS] = [&[]; MAX_WINDOW_ROWS];
            let mut rr: [&[u8]; MAX_WINDOW_ROWS] = [&[]; MAX_WINDOW_ROWS];
            for e in 0..window {
                let v = window_row(y, e, reach, h);
                rl[e] = &left[v * w..(v + 1) * w];
                rr[e] = &right[v * w..(v + 1) * w];
            }
            let rows = ViewRows {
                height: h,
                left: &rl[..window],
                right: &rr[..window],
            };
            let (a, b) = token_rows(y, grid_rows);
            let tokens = TokenRows {
                first: &grid[a * cells..(a + 1) * cells],
                second: &grid[b * cells..(b + 1) * cells],
            };
            let (mut want, mut got) = ([0u16; MAX_W], [0u16; MAX_W]);
            refine_row(y, &rows, &tokens, params, &mut s_ref[..n], &mut want[..w]).unwrap();
            refiner.refine_row(y, &rows, &tokens, &mut got[..w]).unwrap();
            for x in 0..w {
                assert_eq!(
                    got[x], want[x],
                    "seed {seed} {w}x{h} {params:?} row {y} col {x}: ring {} reference {}",
                    got[x], want[x]
                );
            }
        }
    }

    #[test]
    fn the_ring_refines_every_row_as_the_reference_does() {
        let mut rng = Rng::new(99);
        let mut seed = 0;
        for &w in &[1, 2, 3, 4, 5, 7, 8, 13, 24, 40] {
            for &h in &[1, 2, 3, 5, 9, 20] {
                for census_radius in 1..=2 {
                    for box_radius in 0..=3 {
                        let params = RefineParams {
                            census_radius,
                            box_radius,
                            search: rng.range(0, 8) as usize,
                            lambda: rng.range(0, 4096) as u32,
                        };
                        seed += 1;
                        let mut order = [0usize; MAX_H];
                        for (i, o) in order.iter_mut().enumerate() {
                            *o = i;
                        }
                        // Top to bottom as the pipeline goes, then in a scrambled order.
                        agree(seed, w, h, &params, &order[..h]);
                        for i in (1..h).rev() {
                            order.swap(i, rng.range(0, i as i64) as usize);
                        }
                        agree(seed, w, h, &params, &order[..h]);
                    }
                }
            }
        }
        agree(
            7,
            40,
            20,
            &RefineParams::DEFAULT,
            &[0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19],
        );
    }

    #[test]
    fn bad_shapes_are_errors() {
        let mut scratch = [0u32; scratch_len(10, &RefineParams::DEFAULT)];
        assert!(RowRefiner::new(&mut scratch, 0, &RefineParams::DEFAULT).is_err());
        let short = scratch.len() - 1;
        assert!(RowRefiner::new(&mut scratch[..short], 10, &RefineParams::DEFAULT).is_err());
        let mut refiner = RowRefiner::new(&mut scratch, 10, &RefineParams::DEFAULT).unwrap();
        let row = [0u8; 10];
        let window = [&row[..]; RefineParams::DEFAULT.window_rows()];
        let rows = ViewRows {
            height: 4,
            left: &window,
            right: &window,
        };
        let t = [0u16; 3];
        let tokens = TokenRows { first: &t, second: &t };
        let mut out = [0u16; 10];
        assert!(
            refiner.refine_row(4, &rows, &tokens, &mut out).is_err(),
            "row outside the image"
        );
        assert!(
            refiner.refine_row(0, &rows, &tokens, &mut out[..9]).is_err(),
            "short row"
        );
        assert!(refiner.refine_row(0, &rows, &tokens, &mut out).is_ok());
    }
}
