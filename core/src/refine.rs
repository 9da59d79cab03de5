//! Pixel refinement (issue 14): a token-grid disparity (one value per 4x4 view cell) to one
//! disparity per pixel, by a census match of the two views in a small window around the
//! bilinearly upsampled grid. Integers only; one output row at a time.
//!
//! # Sizes
//! The views are `H x W` (`u8`, row-major, equal sizes); the token grid is `ceil(H / 4) x
//! ceil(W / 4)` in the readouts' format (`u16`, Q8 patch columns, one patch column = 4 px).
//! The pipeline only makes views whose sides are multiples of 4 ([`check_view_size`]), where
//! that is its `(H / 4) x (W / 4)` grid and step 1 below is `cv2.resize(..., INTER_LINEAR)`
//! of the grid to `4T x 4P` (the host's `upsample_disparity`); the rounded-up grid lets any
//! view size through, a partial last cell upsampled by the same rule.
//!
//! # Algorithm (the specification; `train/bino_train/refine.py` transcribes it as `refine_int`)
//! For the pixel `(y, x)`, with `S` = [`RefineParams::search`], `r` = census radius, `b` = box
//! radius and `lambda` = [`RefineParams::lambda`]:
//! 1. **Bilinear, `d0` in Q8 px.** Pixel `x` of cell `c = x / 4` reads the cells `(c - 1, c)`
//!    for `x mod 4` in {0, 1} and `(c, c + 1)` for {2, 3}, the second with weight `f / 8`,
//!    `f = 5, 7, 1, 3` by `x mod 4` (source coordinate `(x + 0.5) / 4 - 0.5`); cells clamped
//!    to the grid. The same on rows. With `D` the grid in Q8 columns,
//!    `d0 = (sum of w_y w_x 4 D + 32) >> 6`, the weights in 1/8 (exact in 1/64, then rounded
//!    half up). `d0 <= 4 * 65535`, a `u32`.
//! 2. **Census.** `base = (d0 + 128) >> 8` (`d0` rounded to whole px, half up). The census code
//!    of a pixel has one bit per neighbour of its `(2r + 1)^2` window, set where the neighbour
//!    is below the centre; neighbours in raster order (rows top to bottom, columns left to
//!    right, centre skipped), bit 0 first (24 bits for `r = 2`); coordinates clamped to the
//!    image (edge replicate).
//! 3. **Costs.** For `k = -S..=S`, `d = base + k` is a candidate when `d >= 0` and
//!    `x - d >= 0`. Its aggregated cost `A(k)` sums, over the `(2b + 1)^2` box pixels
//!    `v = clamp(y + i)`, `u = clamp(x + j)`, `|i|, |j| <= b`, the Hamming distance between
//!    the left code at `(v, u)` and the right code at `(v, clamp(u - d))` (every box pixel at
//!    the centre's `d`; a box pixel left of the right view's column 0 compares with column 0,
//!    the validity being the centre's alone). Total cost `c(k) = 256 A(k) + lambda |256 d - d0|`.
//! 4. **Winner.** The valid `k` of lowest `c(k)`; ties go to the smaller `|k|`, then to the
//!    smaller `d` (candidates are visited as `k = 0, -1, +1, -2, +2, ...`, the first strict
//!    minimum kept).
//! 5. **Sub-pixel.** When `k - 1` and `k + 1` are both in `-S..=S` and valid and
//!    `denom = c(k - 1) - 2 c(k) + c(k + 1) > 0`, the step is
//!    `((c(k - 1) - c(k + 1)) * 128) / denom` (division truncating toward zero), clamped to
//!    `-128..=128`; else 0. Refined = `max(256 d + step, 0)`. Without a valid candidate the
//!    pixel keeps `d0`.
//! 6. **Output**: Q8 px, saturated at `u16::MAX`.
//!
//! No value overflows: `A(k) <= 24 (2b + 1)^2 <= 1176`, and `|256 base - d0| <= 128`, so
//! `|256 d - d0| <= 128 + 256 S <= 2176` and `c(k) <= 256 * 1176 + 4096 * 2176 < 2^24` for
//! every parameter set [`RefineParams::check`] accepts (the sums saturate regardless).
//!
//! # Streaming
//! [`refine_row`] makes output row `y` from the view rows `y - reach ..= y + reach` (clamped to
//! the image; `reach = r + b`, 4 for the defaults: census +-2 around each row of the box +-2)
//! and the two token rows [`token_rows`] names, so a caller keeps a ring of
//! [`RefineParams::window_rows`] rows of each view and of two token rows, plus the census scratch
//! of [`scratch_len`]; [`stream_bytes`] totals them for the budget. [`refine_map`] runs it on
//! whole maps. This is the reference: each call recomputes the census of its box rows.
//! [`RowRefiner`] ([`ring`]) is the faster variant the pipeline runs: a ring of census rows in
//! the same scratch, the census interior vectorisable, box sums by column; it agrees with
//! [`refine_row`] bit for bit (tested on every parameter range and odd sizes).
//!
//! ```
//! use bino_core::refine::{refine_map, scratch_len, RefineParams};
//! // 8x8 views whose right view is the left one shifted by 2 px; a 2x2 grid reading 1.5 px
//! // (0.375 patch columns, Q8 96) is refined to 2 px where the match is defined.
//! let left: [u8; 64] = core::array::from_fn(|i| ((i * 97 + i / 8 * 31) % 251) as u8);
//! let right: [u8; 64] = core::array::from_fn(|i| left[(i / 8) * 8 + (i % 8 + 2).min(7)]);
//! let params = RefineParams::DEFAULT;
//! let mut scratch = [0u32; scratch_len(8, &RefineParams::DEFAULT)];
//! let mut out = [0u16; 64];
//! refine_map(&left, &right, 8, &[96; 4], &params, &mut scratch, &mut out)?;
//! assert_eq!((out[3 * 8 + 4] + 128) >> 8, 2);
//! # Ok::<(), bino_core::Error>(())
//! ```
//!
//! [`check_view_size`]: crate::config::check_view_size

use crate::config::{CELL_W, MAX_HEIGHT, PATCH_H};
use crate::Error;

/// Largest census radius: `(2r + 1)^2 - 1` bits must fit a `u32`.
pub const MAX_CENSUS_RADIUS: usize = 2;
/// Largest search radius, in pixels.
pub const MAX_SEARCH: usize = 8;
/// Largest aggregation-box radius.
pub const MAX_BOX_RADIUS: usize = 4;
/// Largest disparity penalty (Q8 cost per Q8 pixel away from `d0`).
pub const MAX_LAMBDA: u32 = 4096;
/// Most view rows an output row reads (`2 (r + b) + 1` at the largest radii).
pub const MAX_WINDOW_ROWS: usize = 2 * (MAX_CENSUS_RADIUS + MAX_BOX_RADIUS) + 1;
/// Most candidates a pixel has.
const MAX_CANDIDATES: usize = 2 * MAX_SEARCH + 1;
/// Fraction bits of the disparities in and out.
const FRAC_BITS: u32 = 8;
/// Weight in 1/8 of the second of the two cells a pixel reads, by pixel index mod 4.
const SECOND_WEIGHT: [u32; 4] = [5, 7, 1, 3];

/// The refinement's parameters. [`RefineParams::DEFAULT`] holds the values a prototype chose on
/// held-out train pairs (w160, the head's `+lr` grid: EPE against confident SGBM 0.796 -> 0.511),
/// its box widened from 5x5 to 9x9 in session 34 on the same pairs (0.491 -> 0.432 equalised).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RefineParams {
    /// Census window radius: `1..=`[`MAX_CENSUS_RADIUS`] (2: 5x5, 24 bits).
    pub census_radius: usize,
    /// Candidates `base - search ..= base + search`, px: `0..=`[`MAX_SEARCH`].
    pub search: usize,
    /// Cost per Q8 px between a candidate and `d0`, in Q8 summed-Hamming units (`50` = 2 per
    /// mean Hamming distance of a 5x5 box per px): `0..=`[`MAX_LAMBDA`].
    pub lambda: u32,
    /// Aggregation box radius: `0..=`[`MAX_BOX_RADIUS`] (4: 9x9).
    pub box_radius: usize,
}

impl RefineParams {
    /// Census 5x5, search +-2 px, penalty 2 mean-Hamming units of a 5x5 box per px, box 9x9.
    pub const DEFAULT: Self = Self {
        census_radius: 2,
        search: 2,
        lambda: 50,
        box_radius: 4,
    };

    /// [`RefineParams::DEFAULT`] with the search radius following the view width: round(width /
    /// 80) px, within `2..=`[`MAX_SEARCH`] (±2 px below 200 px, ±4 at 320, ±8 from 600). The
    /// token grid's errors in pixels grow with the width as the disparities do; chosen on the 22
    /// held-out train pairs against left-right-consistent StereoSGBM (float head+lr at 320 px:
    /// ±2 / 3 / 4 px refine to 0.772 / 0.754 / 0.750 px epe; at 160 px ±2 stays).
    pub const fn for_width(width: usize) -> Self {
        let search = width.saturating_add(40) / 80;
        let search = if search < 2 {
            2
        } else if search > MAX_SEARCH {
            MAX_SEARCH
        } else {
            search
        };
        Self {
            search,
            ..Self::DEFAULT
        }
    }

    /// [`Error::OutOfRange`] for a parameter outside its range.
    pub fn check(&self) -> Result<(), Error> {
        let range = |what, value: usize, min, max| {
            if (min..=max).contains(&value) {
                Ok(())
            } else {
                Err(Error::OutOfRange { what, value, min, max })
            }
        };
        range("census radius", self.census_radius, 1, MAX_CENSUS_RADIUS)?;
        range("search", self.search, 0, MAX_SEARCH)?;
        range("lambda", self.lambda as usize, 0, MAX_LAMBDA as usize)?;
        range("box radius", self.box_radius, 0, MAX_BOX_RADIUS)
    }

    /// View rows above (and below) an output row that it reads: census plus box radius.
    pub const fn reach(&self) -> usize {
        self.census_radius.saturating_add(self.box_radius)
    }

    /// View rows an output row reads: `2 reach + 1` (13 for the defaults).
    pub const fn window_rows(&self) -> usize {
        self.reach().saturating_mul(2).saturating_add(1)
    }
}

impl Default for RefineParams {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// The view rows one output row `y` reads: entry `e` of each is image row
/// [`window_row`]`(y, e, reach, height)`, i.e. `y - reach + e` clamped to the image.
#[derive(Debug, Clone, Copy)]
pub struct ViewRows<'a> {
    /// Rows of the views (the image height `H`).
    pub height: usize,
    /// [`RefineParams::window_rows`] left-view rows of `W` pixels.
    pub left: &'a [&'a [u8]],
    /// The same rows of the right view.
    pub right: &'a [&'a [u8]],
}

/// The two token rows one output row reads (rows [`token_rows`]`(y, T)` of the grid), each
/// `ceil(W / 4)` Q8 patch columns; the same row twice where the bilinear step is clamped.
#[derive(Debug, Clone, Copy)]
pub struct TokenRows<'a> {
    /// The upper row.
    pub first: &'a [u16],
    /// The lower row.
    pub second: &'a [u16],
}

/// Image row held by entry `entry` of a row window around `y`: `y - reach + entry`, clamped to
/// `0..height` (`height >= 1`).
pub const fn window_row(y: usize, entry: usize, reach: usize, height: usize) -> usize {
    let row = y.saturating_add(entry).saturating_sub(reach);
    if row < height {
        row
    } else {
        height.saturating_sub(1)
    }
}

/// Grid rows `(first, second)` the bilinear step reads for pixel row `y` of a view whose grid has
/// `grid_rows` rows: `(c - 1, c)` or `(c, c + 1)`, `c = y / 4`, clamped to the grid.
pub const fn token_rows(y: usize, grid_rows: usize) -> (usize, usize) {
    taps(y, grid_rows)
}

/// `u32` entries of [`refine_row`]'s census scratch for views `width` pixels wide: the census
/// codes of the `2b + 1` box rows of both views.
pub const fn scratch_len(width: usize, params: &RefineParams) -> usize {
    let box_rows = params.box_radius.saturating_mul(2).saturating_add(1);
    box_rows.saturating_mul(2).saturating_mul(width)
}

/// Bytes a streaming caller holds for the refinement of views `width` pixels wide: a ring of
/// [`RefineParams::window_rows`] rows of each view (`u8`), two token rows (`u16`) and the census
/// scratch of [`scratch_len`] (`u32`); the output row is the caller's. 15,840 bytes for the defaults
/// at `width` 160.
pub const fn stream_bytes(width: usize, params: &RefineParams) -> usize {
    let views = params.window_rows().saturating_mul(2).saturating_mul(width);
    let tokens = width.div_ceil(CELL_W).saturating_mul(2 * 2);
    let scratch = scratch_len(width, params).saturating_mul(4);
    views.saturating_add(tokens).saturating_add(scratch)
}

/// Refines output row `y` (`0 <= y < rows.height`) into `out` (`W = out.len()` Q8 px) from the
/// view rows around it, the two token rows of [`token_rows`] and a census scratch of
/// [`scratch_len`]`(W, params)` entries (contents on entry unused; overwritten).
///
/// Errors: [`Error::OutOfRange`] for bad `params` or `y`, [`Error::EmptyImage`] for `W` or the
/// height 0, [`Error::TooTall`] above [`MAX_HEIGHT`], [`Error::BufferSize`] for a window,
/// row, token row or scratch of the wrong length.
pub fn refine_row(
    y: usize,
    rows: &ViewRows<'_>,
    tokens: &TokenRows<'_>,
    params: &RefineParams,
    scratch: &mut [u32],
    out: &mut [u16],
) -> Result<(), Error> {
    params.check()?;
    let width = out.len();
    if width == 0 {
        return Err(Error::EmptyImage);
    }
    check_row_inputs(y, width, rows, tokens, params)?;
    let height = rows.height;
    let cells = width.div_ceil(CELL_W);
    Error::check_len("refinement scratch", scratch_len(width, params), scratch.len())?;

    let (r, b) = (params.census_radius, params.box_radius);
    let box_rows = 2 * b + 1;
    let Some((census_left, census_right)) = scratch.split_at_mut_checked(box_rows * width) else {
        return Err(Error::BufferSize {
            what: "refinement scratch",
            expected: scratch_len(width, params),
            found: scratch.len(),
        });
    };
    // Box row i is image row v = clamp(y + i - b); its census reads rows clamp(v + j - r),
    // which window entry (v + b - y) + j holds (v + b >= y always: clamping moves towards y).
    for i in 0..box_rows {
        let v = window_row(y, i, b, height);
        let top = (v + b).saturating_sub(y);
        let codes_l = census_left.get_mut(i * width..(i + 1) * width).unwrap_or_default();
        census_row(rows.left.get(top..).unwrap_or_default(), r, codes_l);
        let codes_r = census_right.get_mut(i * width..(i + 1) * width).unwrap_or_default();
        census_row(rows.right.get(top..).unwrap_or_default(), r, codes_r);
    }

    let search = params.search as i64;
    let mut costs = [0u32; MAX_CANDIDATES];
    let mut valid = [false; MAX_CANDIDATES];
    let candidates = 2 * params.search + 1;
    for (x, o) in out.iter_mut().enumerate() {
        let d0 = bilinear(x, y, tokens, cells);
        let base = ((d0 + 128) >> FRAC_BITS) as i64;

        for (slot, (c, ok)) in costs.iter_mut().zip(valid.iter_mut()).take(candidates).enumerate() {
            let d = base + slot as i64 - search;
            *ok = d >= 0 && d <= x as i64;
            if !*ok {
                *c = u32::MAX;
                continue;
            }
            let d = d as usize;
            let hamming = box_hamming(census_left, census_right, width, box_rows, x, b, d);
            let penalty = ((d as i64) << FRAC_BITS).abs_diff(d0 as i64);
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

/// The checks [`refine_row`] and [`RowRefiner::refine_row`] share: the image height, the row
/// asked for, the row windows and the token rows, for views `width` pixels wide.
pub(crate) fn check_row_inputs(
    y: usize,
    width: usize,
    rows: &ViewRows<'_>,
    tokens: &TokenRows<'_>,
    params: &RefineParams,
) -> Result<(), Error> {
    let height = rows.height;
    if height == 0 {
        return Err(Error::EmptyImage);
    }
    if height > MAX_HEIGHT {
        return Err(Error::TooTall {
            height,
            max: MAX_HEIGHT,
        });
    }
    if y >= height {
        return Err(Error::OutOfRange {
            what: "output row",
            value: y,
            min: 0,
            max: height - 1,
        });
    }
    let window = params.window_rows();
    Error::check_len("left row window", window, rows.left.len())?;
    Error::check_len("right row window", window, rows.right.len())?;
    for row in rows.left {
        Error::check_len("left view row", width, row.len())?;
    }
    for row in rows.right {
        Error::check_len("right view row", width, row.len())?;
    }
    let cells = width.div_ceil(CELL_W);
    Error::check_len("first token row", cells, tokens.first.len())?;
    Error::check_len("second token row", cells, tokens.second.len())
}

/// [`refine_row`] over whole maps: `left` and `right` are `H x W` views (`W = width`,
/// `H = left.len() / width`), `tokens` the `ceil(H / 4) x ceil(W / 4)` grid (Q8 patch columns),
/// `scratch` of [`scratch_len`]`(W, params)` entries, `out` the `H x W` Q8 px result.
///
/// Errors as [`refine_row`], and [`Error::PairMismatch`] for views of different sizes,
/// [`Error::BufferSize`] for a view that is not whole rows, a grid or output of the wrong size.
pub fn refine_map(
    left: &[u8],
    right: &[u8],
    width: usize,
    tokens: &[u16],
    params: &RefineParams,
    scratch: &mut [u32],
    out: &mut [u16],
) -> Result<(), Error> {
    params.check()?;
    let (height, grid_rows, cells) = map_shape(left, right, width, tokens.len(), out.len())?;

    let (reach, window) = (params.reach(), params.window_rows());
    let mut rows_l: [&[u8]; MAX_WINDOW_ROWS] = [&[]; MAX_WINDOW_ROWS];
    let mut rows_r: [&[u8]; MAX_WINDOW_ROWS] = [&[]; MAX_WINDOW_ROWS];
    let token_row = |t: usize| tokens.get(t * cells..(t + 1) * cells).unwrap_or_default();
    for (y, out_row) in out.chunks_exact_mut(width).enumerate() {
        for (e, (l, r)) in rows_l.iter_mut().zip(rows_r.iter_mut()).take(window).enumerate() {
            let v = window_row(y, e, reach, height);
            *l = left.get(v * width..(v + 1) * width).unwrap_or_default();
            *r = right.get(v * width..(v + 1) * width).unwrap_or_default();
        }
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

/// `(H, grid rows, cells)` of whole maps after checking them as [`refine_map`] documents.
pub(crate) fn map_shape(
    left: &[u8],
    right: &[u8],
    width: usize,
    tokens: usize,
    out: usize,
) -> Result<(usize, usize, usize), Error> {
    if width == 0 || left.is_empty() {
        return Err(Error::EmptyImage);
    }
    if !left.len().is_multiple_of(width) {
        return Err(Error::BufferSize {
            what: "left view",
            expected: left.len() / width * width,
            found: left.len(),
        });
    }
    if right.len() != left.len() {
        return Err(Error::PairMismatch);
    }
    let height = left.len() / width;
    if height > MAX_HEIGHT {
        return Err(Error::TooTall {
            height,
            max: MAX_HEIGHT,
        });
    }
    let (grid_rows, cells) = (height.div_ceil(PATCH_H), width.div_ceil(CELL_W));
    Error::check_len("token grid", grid_rows * cells, tokens)?;
    Error::check_len("refined disparity", left.len(), out)?;
    Ok((height, grid_rows, cells))
}

/// The two cells (or grid rows) pixel `x` reads: `(c - 1, c)` or `(c, c + 1)`, `c = x / 4`,
/// both clamped to `0..cells`.
const fn taps(x: usize, cells: usize) -> (usize, usize) {
    let c = x / CELL_W;
    let (a, b) = if x % CELL_W < 2 {
        (c.saturating_sub(1), c)
    } else {
        (c, c.saturating_add(1))
    };
    let last = cells.saturating_sub(1);
    (if a < last { a } else { last }, if b < last { b } else { last })
}

/// Step 1: `d0` (Q8 px) of pixel `(y, x)` from its two token rows of `cells` cells.
fn bilinear(x: usize, y: usize, tokens: &TokenRows<'_>, cells: usize) -> u32 {
    let (ca, cb) = taps(x, cells);
    let (fx, fy) = (SECOND_WEIGHT[x % 4], SECOND_WEIGHT[y % 4]);
    let cell = |row: &[u16], c: usize| row.get(c).copied().unwrap_or(0) as u32;
    let first = (8 - fx) * cell(tokens.first, ca) + fx * cell(tokens.first, cb);
    let second = (8 - fx) * cell(tokens.second, ca) + fx * cell(tokens.second, cb);
    // <= 64 * 65535 * 4 + 32 < 2^25.
    (((8 - fy) * first + fy * second) * 4 + 32) >> 6
}

/// Census codes of one image row into `out` (its width): `window[j]`, `j = 0..=2r`, holds image
/// row `clamp(v + j - r)` around that row `v`.
fn census_row(window: &[&[u8]], r: usize, out: &mut [u32]) {
    let width = out.len();
    let centre_row = window.get(r).copied().unwrap_or_default();
    for (u, code) in out.iter_mut().enumerate() {
        let centre = centre_row.get(u).copied().unwrap_or(0);
        let mut bits = 0u32;
        let mut bit = 0u32;
        for j in 0..=2 * r {
            let row = window.get(j).copied().unwrap_or_default();
            for i in 0..=2 * r {
                if i == r && j == r {
                    continue;
                }
                let col = (u + i).saturating_sub(r).min(width.saturating_sub(1));
                let neighbour = row.get(col).copied().unwrap_or(0);
                bits |= ((neighbour < centre) as u32).checked_shl(bit).unwrap_or(0);
                bit += 1;
            }
        }
        *code = bits;
    }
}

/// `A(k)`: Hamming distances summed over the box around column `x`, every box pixel at
/// disparity `d`; `left` and `right` hold the box rows' census codes, `width` each.
fn box_hamming(left: &[u32], right: &[u32], width: usize, box_rows: usize, x: usize, b: usize, d: usize) -> u32 {
    let mut sum = 0u32;
    for i in 0..box_rows {
        let row_l = left.get(i * width..(i + 1) * width).unwrap_or_default();
        let row_r = right.get(i * width..(i + 1) * width).unwrap_or_default();
        for j in 0..box_rows {
            let u = (x + j).saturating_sub(b).min(width.saturating_sub(1));
            let code_l = row_l.get(u).copied().unwrap_or(0);
            let code_r = row_r.get(u.saturating_sub(d)).copied().unwrap_or(0);
            sum += (code_l ^ code_r).count_ones();
        }
    }
    sum
}

/// Slot of the lowest valid cost, visiting `k = 0, -1, +1, -2, +2, ...` (slot `k + search`) and
/// keeping the first strict minimum; `None` without a valid candidate.
fn winner(costs: &[u32], valid: &[bool], search: usize) -> Option<usize> {
    let mut best: Option<(usize, u32)> = None;
    for step in 0..=2 * search {
        // step 0, 1, 2, 3, 4 -> k = 0, -1, +1, -2, +2.
        let slot = if step % 2 == 1 {
            search - step.div_ceil(2)
        } else {
            search + step / 2
        };
        let (Some(&cost), Some(true)) = (costs.get(slot), valid.get(slot).copied()) else {
            continue;
        };
        if best.is_none_or(|(_, c)| cost < c) {
            best = Some((slot, cost));
        }
    }
    best.map(|(slot, _)| slot)
}

/// The parabola step (Q8 px, `-128..=128`) at the winning `slot`; 0 unless both neighbours are
/// valid and the parabola opens upwards.
fn subpixel_step(costs: &[u32], valid: &[bool], slot: usize) -> i64 {
    let at = |s: Option<usize>| {
        s.filter(|&s| valid.get(s).copied().unwrap_or(false))
            .and_then(|s| costs.get(s))
            .map(|&c| c as i64)
    };
    let (Some(lo), Some(mid), Some(hi)) = (at(slot.checked_sub(1)), at(Some(slot)), at(slot.checked_add(1))) else {
        return 0;
    };
    let denom = lo - 2 * mid + hi;
    if denom <= 0 {
        return 0;
    }
    // Rust's `/` truncates toward zero; |lo - hi| * 128 < 2^39. Costs below 2^24 (every one of
    // the documented parameter ranges) keep both sides in `i32`, whose division is one
    // instruction on the Cortex-M cores (`i64`'s is a library call): the same quotient.
    const SMALL: i64 = 1 << 24;
    if lo < SMALL && mid < SMALL && hi < SMALL {
        let (num, den) = ((lo - hi) as i32 * 128, denom as i32);
        return ((num / den) as i64).clamp(-128, 128);
    }
    (((lo - hi) * 128) / denom).clamp(-128, 128)
}

mod rejected;
pub mod ring;
pub mod sharpness;

pub use rejected::{keep_rejected_map, keep_rejected_row};

/// Census codes of one pixel row from its window of rows (`window[j]` = row `clamp(v + j - r)`).
pub(crate) use ring::census_fast as census_codes;
pub use ring::RowRefiner;

#[cfg(test)]
mod fixture;
#[cfg(test)]
mod tests;
