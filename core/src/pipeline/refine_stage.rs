//! The pixel refinement ([`crate::refine`]) as a stage of the pipeline: token rows of one
//! readout in (as the readouts emit them), refined pixel rows out through [`Sink::refined`],
//! top to bottom, each image row once.
//!
//! # When a pixel row is made
//! Pixel row `y` reads the token rows [`token_rows`]`(y)` (`c - 1, c` or `c, c + 1`, `c = y / 4`)
//! and the view rows `y - reach ..= y + reach` ([`RefineParams::reach`], 4 for the defaults).
//! Token row `t` arriving makes pixel rows `4t - 2 ..= 4t + 1` computable (the last token row
//! also the two below it), so two token rows are all the stage keeps, filled by the readout's
//! left-right check when the readout is a `+lr` one (its [`Fill`], as the host fills),
//! with that check's masks: the pixels of rejected cells keep the bilinear step
//! ([`keep_rejected_row`]).
//!
//! # Where the view rows come from
//! From the pipeline's own band buffer whenever they are still there: the matching readouts
//! (nolink, sgm) emit token row `t` while the band holding it is in the buffer, and the rows
//! `t` needs lie at least [`CUT_MARGIN`] token rows inside that band (the band plan cuts in the
//! middle of each overlap), so they never need a copy. The heads' rows leave with the band too:
//! on either pathway each band's head runs on the band's own rows and ends with it. Only a
//! reach beyond the margin (the sharpness equalisation's 8 rows) needs rows a band load drops:
//! before each load the stage copies them into a small ring ([`ring_rows`] with no lag: 2 rows
//! of each view at reach 8, none up to reach 6 or for one band). The stage also takes rows
//! that trail the band by a lag (its tests), the ring growing by 4 view rows a token row.
//!
//! # Memory
//! State kept across bands ([`state_bytes`]): two token rows, their masks and the ring. Scratch used only
//! inside a row ([`scratch_bytes`]): the census codes of [`crate::refine::scratch_len`] and the
//! output row; with several bands it lives in the encoder's scratch (free between passes), with
//! one band beside the readout streams (which share the encoder's scratch after both passes).

use super::api::{Refine, RefineInput, Sink, Stage};
use super::layout::{stage_reach, sum, CUT_MARGIN};
use crate::arena::{Carver, ALIGN_SLACK};
use crate::config::{CELL_W, PATCH_H};
use crate::lr::Fill;
use crate::refine::sharpness::{smoothed_len, EqualisedRefiner, MAX_EQUALISED_ROWS};
use crate::refine::{
    keep_rejected_row, scratch_len, token_rows, window_row, RefineParams, RowRefiner, TokenRows, ViewRows,
};
use crate::Error;

/// View rows of each view the ring holds for a readout whose rows trail the band's by `lag`
/// token rows, with several bands.
///
/// At a band load the last token row received is at most `keep_to - 1 - lag`, so the next pixel
/// row is `y = 4 (keep_to - lag) - 2` and the oldest row still needed `y - reach`; the next band
/// starts at least [`CUT_MARGIN`] token rows above `keep_to`. The rows in between:
/// `4 lag + 2 + reach - 4 CUT_MARGIN` (22 for the head with the default reach of 4; none for
/// `lag` 0 and any reach up to 6).
pub(super) const fn ring_rows(reach: usize, lag: usize) -> usize {
    PATCH_H
        .saturating_mul(lag)
        .saturating_add(PATCH_H / 2)
        .saturating_add(reach)
        .saturating_sub(PATCH_H * CUT_MARGIN)
}

/// Arena bytes of the state kept across bands: two token rows (`u16`), their left-right masks
/// (`u8`) and `ring` rows of both views (`u8`).
pub(super) const fn state_bytes(width: usize, ring: usize) -> usize {
    let cols = width / CELL_W;
    sum(&[
        cols.saturating_mul(2 * 2).saturating_add(1),
        cols.saturating_mul(2),
        ring.saturating_mul(width).saturating_mul(2),
    ])
}

/// Arena bytes of the scratch one pixel row uses: the census codes (`u32`), the output row
/// (`u16`) and, with the sharpness equalisation, the smoothed window rows (`u8`).
pub(super) const fn scratch_bytes(width: usize, params: &RefineParams, equalise: bool) -> usize {
    let smoothed = if equalise { smoothed_len(width, params) } else { 0 };
    sum(&[
        scratch_len(width, params).saturating_mul(4).saturating_add(ALIGN_SLACK),
        width.saturating_mul(2).saturating_add(1),
        smoothed,
    ])
}

/// The pixel rows the band buffer holds now.
#[derive(Debug, Clone, Copy)]
pub(super) struct BandView<'b> {
    /// Image row of buffer row 0.
    pub first: usize,
    /// Rows held.
    pub rows: usize,
    /// Width of a row.
    pub width: usize,
    /// Left-view rows (at least `rows x width` pixels).
    pub left: &'b [u8],
    /// Right-view rows.
    pub right: &'b [u8],
}

impl<'b> BandView<'b> {
    /// Image row `v` of both views, when the buffer holds it.
    pub(super) fn row(&self, v: usize) -> Option<(&'b [u8], &'b [u8])> {
        let i = v.checked_sub(self.first).filter(|&i| i < self.rows)?;
        let range = i * self.width..(i + 1) * self.width;
        Some((self.left.get(range.clone())?, self.right.get(range)?))
    }
}

/// A row refiner, with or without the sharpness equalisation.
// The equalised one carries its window's sums (under 300 bytes); core has no heap to box it in,
// and the difference is stack the row scratch's owner holds anyway.
#[allow(clippy::large_enum_variant)]
enum Refiner<'s> {
    Plain(RowRefiner<'s>),
    Equalised(EqualisedRefiner<'s>),
}

/// The scratch of the pixel rows: the refiner's ring of census rows (valid while the scratch
/// is not lent to the encoder: a new one per band) and the output row.
pub(super) struct Scratch<'s> {
    refiner: Option<Refiner<'s>>,
    out: &'s mut [u16],
    used: usize,
}

impl<'s> Scratch<'s> {
    /// Cuts the scratch for rows of `width` of a `height`-row image from the front of `arena`.
    pub fn new(
        arena: &'s mut [u8],
        width: usize,
        height: usize,
        params: &RefineParams,
        equalise: bool,
    ) -> Result<Self, Error> {
        let mut carver = Carver::new(arena, scratch_bytes(width, params, equalise))?;
        let census = carver.u32s(scratch_len(width, params))?;
        let out = carver.u16s(width)?;
        let refiner = if equalise {
            let smoothed = carver.u8s(smoothed_len(width, params))?;
            Refiner::Equalised(EqualisedRefiner::new(census, smoothed, width, height, params)?)
        } else {
            Refiner::Plain(RowRefiner::new(census, width, params)?)
        };
        Ok(Self {
            refiner: Some(refiner),
            out,
            used: carver.used(),
        })
    }

    /// The scratch of `refine` for a run of `width x height` views, cut from `arena`; none
    /// without the refinement.
    pub fn of(refine: Option<&Refine>, arena: &'s mut [u8], width: usize, height: usize) -> Result<Self, Error> {
        match refine {
            Some(r) => Self::new(arena, width, height, &r.params, r.equalise),
            None => Ok(Self::none()),
        }
    }

    /// No scratch (a run without the refinement).
    pub fn none() -> Self {
        Self {
            refiner: None,
            out: &mut [],
            used: 0,
        }
    }

    /// Arena bytes it took.
    pub fn used(&self) -> usize {
        self.used
    }
}

/// What a call into the stage reads and writes besides its state: the band buffer's rows, held
/// for `'v`, and the row scratch, for `'s` (the census run lends the buffer anew for each token
/// row, as its rows arrive, and keeps the scratch, its census rows, for the band).
pub(super) struct RefineIoOf<'v, 's> {
    /// The band buffer.
    pub view: BandView<'v>,
    /// The row scratch.
    pub scratch: Scratch<'s>,
}

/// [`RefineIoOf`] with the buffer and the scratch lent for the same span (a band).
pub(super) type RefineIo<'b> = RefineIoOf<'b, 'b>;

/// The stage's state across bands.
pub(super) struct RefineStage<'a> {
    params: RefineParams,
    /// View rows above and below a pixel row it reads ([`stage_reach`]).
    reach: usize,
    width: usize,
    height: usize,
    cols: usize,
    grid_rows: usize,
    /// Token row `t` in slot `t % 2`.
    tokens: &'a mut [u16],
    /// Its left-right mask in slot `t % 2` (all 1 without a check).
    masks: &'a mut [u8],
    /// Token rows received.
    received: usize,
    /// Next pixel row to emit.
    next_y: usize,
    /// Image row `v` in slot `v % ring_rows`, for `v` in `ring_from..ring_to`.
    ring_left: &'a mut [u8],
    ring_right: &'a mut [u8],
    ring_rows: usize,
    ring_from: usize,
    ring_to: usize,
    used: usize,
    /// The first error of a push from inside a head callback (which cannot return one).
    failed: Option<Error>,
    /// How a `+lr` row's rejected cells are filled.
    fill: Fill,
}

impl<'a> RefineStage<'a> {
    /// The stage for `height x width` views, its state cut from `arena`, with a ring of
    /// `ring_rows` rows; `equalise`: with the sharpness equalisation.
    pub fn new(
        params: RefineParams,
        equalise: bool,
        width: usize,
        height: usize,
        ring_rows: usize,
        arena: &'a mut [u8],
    ) -> Result<Self, Error> {
        params.check()?;
        let cols = width / CELL_W;
        let mut carver = Carver::new(arena, state_bytes(width, ring_rows))?;
        let tokens = carver.u16s(2 * cols)?;
        let masks = carver.u8s(2 * cols)?;
        let ring_left = carver.u8s(ring_rows * width)?;
        let ring_right = carver.u8s(ring_rows * width)?;
        Ok(Self {
            params,
            reach: stage_reach(&params, equalise),
            width,
            height,
            cols,
            grid_rows: height / PATCH_H,
            tokens,
            masks,
            received: 0,
            next_y: 0,
            ring_left,
            ring_right,
            ring_rows,
            ring_from: 0,
            ring_to: 0,
            used: carver.used(),
            failed: None,
            fill: Fill::FromLeft,
        })
    }

    /// The stage filling `+lr` rows by `fill` (from the left unless told).
    pub fn with_fill(self, fill: Fill) -> Self {
        Self { fill, ..self }
    }

    /// Arena bytes of its state.
    pub fn used(&self) -> usize {
        self.used
    }

    /// Takes token row `row` (the next one) of the readout, `cols` Q8 patch columns, filled by
    /// `mask` (its left-right check) when given; emits every pixel row that became computable.
    pub fn push(
        &mut self,
        row: usize,
        disparity_q8: &[u16],
        mask: Option<&[u8]>,
        io: &mut RefineIoOf<'_, '_>,
        sink: &mut impl Sink,
    ) -> Result<(), Error> {
        if row != self.received || row >= self.grid_rows {
            return Err(Error::OutOfRange {
                what: "refined token row",
                value: row,
                min: self.received,
                max: self.received,
            });
        }
        let cols = self.cols;
        let slot = self
            .tokens
            .get_mut((row % 2) * cols..(row % 2 + 1) * cols)
            .unwrap_or_default();
        Error::check_len("refined token row", slot.len(), disparity_q8.len())?;
        slot.copy_from_slice(disparity_q8);
        let kept = self
            .masks
            .get_mut((row % 2) * cols..(row % 2 + 1) * cols)
            .unwrap_or_default();
        match mask {
            Some(mask) => {
                // The fill checks the mask against the token row, as long as `kept`.
                self.fill.apply(slot, mask)?;
                kept.iter_mut().zip(mask).for_each(|(k, &m)| *k = m);
            }
            None => kept.fill(1),
        }
        self.received += 1;
        self.emit(io, sink)
    }

    /// [`RefineStage::push`] from a callback that cannot return an error: keeps the first one
    /// for [`RefineStage::done`].
    pub fn push_or_keep(
        &mut self,
        row: usize,
        disparity_q8: &[u16],
        mask: Option<&[u8]>,
        io: &mut RefineIoOf<'_, '_>,
        sink: &mut impl Sink,
    ) {
        if self.failed.is_none() {
            if let Err(e) = self.push(row, disparity_q8, mask, io, sink) {
                self.failed = Some(e);
            }
        }
    }

    /// The first error kept by [`RefineStage::push_or_keep`].
    pub fn check(&self) -> Result<(), Error> {
        self.failed.map_or(Ok(()), Err)
    }

    /// After the last token row: every pixel row must have been emitted.
    pub fn done(&self) -> Result<(), Error> {
        self.check()?;
        Error::check_len("refined rows", self.height, self.next_y)
    }

    /// Before the band buffer drops its rows above `new_first`: copies the rows the stage still
    /// needs from there into the ring.
    pub fn keep_before(&mut self, view: &BandView<'_>, new_first: usize) -> Result<(), Error> {
        let need_from = self.next_y.saturating_sub(self.reach);
        if need_from >= new_first {
            (self.ring_from, self.ring_to) = (new_first, new_first);
            return Ok(());
        }
        // Rows need_from..new_first: those below the buffer are in the ring already.
        let too_small = Error::BufferSize {
            what: "refinement view ring",
            expected: new_first - need_from,
            found: self.ring_rows,
        };
        if new_first - need_from > self.ring_rows || (need_from < view.first && need_from < self.ring_from) {
            return Err(too_small);
        }
        let w = self.width;
        for v in need_from.max(view.first)..new_first {
            let (Some((l, r)), Some(slot)) = (view.row(v), v.checked_rem(self.ring_rows)) else {
                return Err(too_small);
            };
            let at = slot * w..(slot + 1) * w;
            let (Some(dl), Some(dr)) = (self.ring_left.get_mut(at.clone()), self.ring_right.get_mut(at)) else {
                return Err(too_small);
            };
            dl.copy_from_slice(l);
            dr.copy_from_slice(r);
        }
        (self.ring_from, self.ring_to) = (need_from, new_first);
        Ok(())
    }

    /// Image row `v` of both views, from the band buffer or the ring.
    fn view_row<'s>(&'s self, view: &BandView<'s>, v: usize) -> Option<(&'s [u8], &'s [u8])> {
        if let Some(rows) = view.row(v) {
            return Some(rows);
        }
        if !(self.ring_from..self.ring_to).contains(&v) {
            return None;
        }
        let slot = v.checked_rem(self.ring_rows)?;
        let at = slot * self.width..(slot + 1) * self.width;
        Some((self.ring_left.get(at.clone())?, self.ring_right.get(at)?))
    }

    /// The left-right mask of token row `t` (kept as [`RefineStage::token_row`] is).
    fn mask_row(&self, t: usize) -> Result<&[u8], Error> {
        self.token_row(t)?;
        let cols = self.cols;
        Ok(self.masks.get((t % 2) * cols..(t % 2 + 1) * cols).unwrap_or_default())
    }

    fn token_row(&self, t: usize) -> Result<&[u16], Error> {
        // Only the last two rows received are kept.
        if t >= self.received || t + 2 < self.received {
            return Err(Error::OutOfRange {
                what: "token row kept for the refinement",
                value: t,
                min: self.received.saturating_sub(2),
                max: self.received.saturating_sub(1),
            });
        }
        let cols = self.cols;
        Ok(self.tokens.get((t % 2) * cols..(t % 2 + 1) * cols).unwrap_or_default())
    }

    /// Emits pixel rows while their token rows and view rows are at hand.
    fn emit(&mut self, io: &mut RefineIoOf<'_, '_>, sink: &mut impl Sink) -> Result<(), Error> {
        let (reach, height) = (self.reach, self.height);
        let window = 2 * reach + 1;
        while self.next_y < height {
            let y = self.next_y;
            let (first, second) = token_rows(y, self.grid_rows);
            if second >= self.received || self.view_row(&io.view, (y + reach).min(height - 1)).is_none() {
                break;
            }
            let mut left: [&[u8]; MAX_EQUALISED_ROWS] = [&[]; MAX_EQUALISED_ROWS];
            let mut right: [&[u8]; MAX_EQUALISED_ROWS] = [&[]; MAX_EQUALISED_ROWS];
            for (e, (l, r)) in left.iter_mut().zip(right.iter_mut()).take(window).enumerate() {
                let v = window_row(y, e, reach, height);
                let Some(rows) = self.view_row(&io.view, v) else {
                    return Err(Error::OutOfRange {
                        what: "view row kept for the refinement",
                        value: v,
                        min: self.ring_from.min(io.view.first),
                        max: io.view.first + io.view.rows,
                    });
                };
                (*l, *r) = rows;
            }
            let rows = ViewRows {
                height,
                left: left.get(..window).unwrap_or_default(),
                right: right.get(..window).unwrap_or_default(),
            };
            let tokens = TokenRows {
                first: self.token_row(first)?,
                second: self.token_row(second)?,
            };
            let scratch = &mut io.scratch;
            let Some(refiner) = scratch.refiner.as_mut() else {
                return Err(Error::BufferSize {
                    what: "refinement scratch",
                    expected: scratch_len(self.width, &self.params),
                    found: 0,
                });
            };
            match refiner {
                Refiner::Plain(r) => r.refine_row(y, &rows, &tokens, scratch.out)?,
                Refiner::Equalised(r) => r.refine_row(y, &rows, &tokens, scratch.out)?,
            }
            keep_rejected_row(y, &tokens, self.mask_row(y / PATCH_H)?, scratch.out)?;
            sink.refined(y, scratch.out);
            self.next_y += 1;
        }
        Ok(())
    }
}

/// A run's refinement, when it has one: the readout it reads and its stage, whose state lives
/// across bands. What every band loop shares: the stage made for the run's band count, the rows
/// it still needs kept before a load drops them, its arena use and its errors.
pub(super) struct Refinement<'a>(pub(super) Option<(RefineInput, RefineStage<'a>)>);

impl<'a> Refinement<'a> {
    /// The stage of `refine` (none without it) for `height x width` views, its state cut from
    /// `state`: with `several_bands` the ring of the rows its readout needs after the next
    /// band's load ([`ring_rows`]: every readout's rows leave with the band that made them),
    /// with one band none.
    pub(super) fn new(
        refine: Option<&Refine>,
        width: usize,
        height: usize,
        several_bands: bool,
        state: &'a mut [u8],
    ) -> Result<Self, Error> {
        let Some(r) = refine else {
            return Ok(Self(None));
        };
        let ring = if several_bands { ring_rows(r.reach(), 0) } else { 0 };
        let stage = RefineStage::new(r.params, r.equalise, width, height, ring, state)?.with_fill(r.input.fill());
        Ok(Self(Some((r.input, stage))))
    }

    /// Before a band load that drops the rows above `new_first`.
    pub(super) fn keep_before(
        &mut self,
        view: &BandView<'_>,
        new_first: usize,
        sink: &mut impl Sink,
    ) -> Result<(), Error> {
        let Some((_, stage)) = self.0.as_mut() else {
            return Ok(());
        };
        sink.stage(Stage::Refine);
        stage.keep_before(view, new_first)
    }

    /// Arena bytes of its state (0 without it).
    pub(super) fn used(&self) -> usize {
        self.0.as_ref().map_or(0, |(_, stage)| stage.used())
    }

    /// The first error a head callback kept.
    pub(super) fn check(&self) -> Result<(), Error> {
        self.0.as_ref().map_or(Ok(()), |(_, stage)| stage.check())
    }

    /// After the last row: every pixel row was emitted and no error kept.
    pub(super) fn done(&self) -> Result<(), Error> {
        self.0.as_ref().map_or(Ok(()), |(_, stage)| stage.done())
    }
}

#[cfg(test)]
mod tests;
