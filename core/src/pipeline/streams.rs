//! The export pathway's readout streams: per kept token row the no-linkage WTA, SGM, both
//! left-right checks, the census SGM (for `fuse-all`) and the refinement's input, state that
//! carries from band to band; then per band the shared head on the band's own rows (and its
//! check, the mirrored head rerun on the same rows), a stream that ends with the band.

use super::api::{MatchedRow, RefineInput, Sink, Stage};
use super::census_stage::{self, CensusStage};
use super::context::Context;
use super::feeding::kept_row;
use super::head_check::HEAD_CHECK_ROWS;
use super::head_check::{CheckedRows, Feed, HeadCheck, HeadRows};
use super::refine_stage::{BandView, RefineIo, Refinement};
use super::row_buffers::{row_bytes, RowBuffers};
use super::sizing::{matching_state_bytes, refine_parts, resident_bytes};
use crate::arena::Carver;
use crate::band::Band;
use crate::census;
use crate::config::{CELL_W, PATCH_H};
use crate::lr::{consistent_row, fuse_head_weight, right_view_costs, wta_costs};
use crate::matching::{cost_row, inverse_norms, match_row};
use crate::model::head::{self, HeadSink, HeadStream, HeadView, KeptRows};
#[cfg(doc)]
use crate::sgm::Penalties;
use crate::sgm::{cell_guide, state_len, SgmStream};
use crate::Error;

/// The readouts' resident state, what carries from row to row and band to band: both views'
/// SGM aggregates, the head's check, the census stage's SGM state and ring, and the refinement.
/// A row's buffers are each band's ([`RowBuffers`]), and so is the head's stream
/// ([`Streams::push_band`]).
pub(super) struct Streams<'a> {
    cols: usize,
    max_cols: usize,
    lr_max_diff_q8: u16,
    /// The SGM's jump penalty follows the views' brightness ([`Penalties::edge`]).
    guided: bool,
    /// The census stage's views and candidates (with the census stage).
    census_shape: Option<(usize, usize)>,
    sgm: SgmStream<'a>,
    sgm_right: SgmStream<'a>,
    /// With `head_lr`: the check of a band's left head rows against its mirrored head's.
    check: Option<HeadCheck<'a>>,
    /// With a `fuse-all+lr` refinement: the census SGM, its rows kept for the head's check.
    census: Option<CensusStage<'a>>,
    /// The refinement (when the run has one): the readout it reads and its state.
    pub(super) refine: Refinement<'a>,
    pub(super) used: usize,
    pub(super) wta_kept: usize,
    pub(super) sgm_kept: usize,
}

impl<'a> Streams<'a> {
    /// The streams of a run, cut from `arena` (the refinement's state after them); `several`:
    /// several bands, so the refinement keeps the rows a band load drops.
    pub(super) fn new(ctx: &Context<'_, '_>, arena: &'a mut [u8], several: bool) -> Result<Self, Error> {
        let (cols, max_cols) = (ctx.cols, ctx.opts.max_cols);
        let shape = ctx.head_shape();
        let streams = resident_bytes(cols, max_cols, shape);
        let (arena, refine_arena) = arena.split_at_mut(streams.min(arena.len()));
        // The census stage sits at the front of the streams' region (its own alignment).
        let census_shape = shape.census.then_some((ctx.width, shape.candidates));
        let census_len = match census_shape {
            Some((width, candidates)) => census_stage::resident_bytes(width, candidates, HEAD_CHECK_ROWS),
            None => 0,
        };
        let (census_arena, arena) = arena.split_at_mut(census_len.min(arena.len()));
        let (census, census_used) = match census_shape {
            Some((width, candidates)) => {
                let limits = (candidates, ctx.opts.lr_max_diff_q8);
                let carved = CensusStage::carve(census_arena, width, ctx.height, limits, HEAD_CHECK_ROWS, false)?;
                (Some(carved.0), carved.1)
            }
            None => (None, 0),
        };
        let state = ctx.refine.map_or(0, |r| refine_parts(ctx.height, ctx.width, r).0);
        let available = streams.saturating_add(refine_arena.len());
        let state_arena = refine_arena.get_mut(..state).ok_or(Error::ArenaTooSmall {
            needed: streams.saturating_add(state),
            available,
        })?;
        let refine = Refinement::new(ctx.refine, ctx.width, ctx.height, several, state_arena)?;
        let volume_row = state_len(cols, max_cols);
        let guided = ctx.opts.penalties.guided();
        let matching = matching_state_bytes(cols, max_cols, guided);
        let (matching_arena, check_arena) = arena.split_at_mut(matching.min(arena.len()));
        let mut carver = Carver::new(matching_arena, matching)?;
        let pen = ctx.opts.penalties;
        let mut sgm = SgmStream::state_only(cols, max_cols, pen, carver.u16s(volume_row)?, carver.u16s(volume_row)?)?;
        let mut sgm_right =
            SgmStream::state_only(cols, max_cols, pen, carver.u16s(volume_row)?, carver.u16s(volume_row)?)?;
        // The previous rows' guides take arena only when the SGM uses them (the default does
        // not); bytes, so they come last and need no alignment.
        if guided {
            sgm = sgm.with_guide(carver.u8s(cols)?)?;
            sgm_right = sgm_right.with_guide(carver.u8s(cols)?)?;
        }
        let mut used = carver.used();
        let check = if ctx.head_lr() {
            // fuse-all fuses the head with the census first, that with the SGM here.
            let weight = if shape.census {
                census::FUSE_ALL_FIRST_WEIGHT
            } else {
                fuse_head_weight(ctx.width)
            };
            let (check, check_used) =
                HeadCheck::carve(check_arena, cols, HEAD_CHECK_ROWS, ctx.opts.lr_max_diff_q8, weight)?;
            used = matching + check_used;
            Some(check)
        } else {
            None
        };
        // The census stage's bytes precede the rest (`matching` counts from the rest's start).
        used = census_len.max(census_used).saturating_add(used);
        Ok(Self {
            cols,
            max_cols,
            lr_max_diff_q8: ctx.opts.lr_max_diff_q8,
            guided,
            census_shape,
            sgm,
            sgm_right,
            check,
            census,
            refine,
            used,
            wta_kept: 0,
            sgm_kept: 0,
        })
    }

    /// Arena bytes of a row's buffers ([`RowBuffers`]), cut from each band's scratch.
    pub(super) fn row_bytes(&self) -> usize {
        row_bytes(self.cols, self.max_cols, self.guided, self.census_shape)
    }

    /// Cells the head's left-right check kept (0 without it).
    pub(super) fn head_kept(&self) -> usize {
        self.check.as_ref().map_or(0, |check| check.kept)
    }

    /// Cells the fused readout kept (0 without the head's check).
    pub(super) fn fused_kept(&self) -> usize {
        self.check.as_ref().map_or(0, |check| check.fusion.kept)
    }

    /// Feeds the rows `band` keeps to the matching readouts, each in the row buffers cut from
    /// `rows` ([`Streams::row_bytes`]), then (with the head) the band's rows around them
    /// ([`Band::around_kept`] by [`head::ROW_REACH`]) to `head`, a fresh stream, to its end,
    /// and with the check again to the mirrored head on the same stream: the kept rows'
    /// outputs go on, and nothing of the head or the row buffers outlives the band. Returns
    /// the bytes of `rows` used.
    pub(super) fn push_band(
        &mut self,
        (band, left, right): (Band, &[i8], &[i8]),
        head: Option<&mut HeadStream<'_, '_>>,
        rows: &mut [u8],
        io: &mut RefineIo<'_>,
        sink: &mut impl Sink,
    ) -> Result<usize, Error> {
        let (mut buffers, rows_used) =
            RowBuffers::carve(rows, self.cols, self.max_cols, self.guided, self.census_shape)?;
        for row in band.keep_from..band.keep_to {
            let (l, r) = kept_row(band, row, self.cols, left, right)?;
            self.push_row(row, (l, r), &mut buffers, io, sink)?;
        }
        self.push_heads(BandHead { band, left, right }, head, io, sink)?;
        Ok(rows_used)
    }

    /// The band's rows through the left head and, with the check, the mirrored one.
    fn push_heads(
        &mut self,
        rows: BandHead<'_>,
        head: Option<&mut HeadStream<'_, '_>>,
        io: &mut RefineIo<'_>,
        sink: &mut impl Sink,
    ) -> Result<(), Error> {
        let Some(head) = head else {
            return Ok(());
        };
        sink.stage(Stage::Head);
        let mut out = HeadRows {
            sink: &mut *sink,
            check: self.check.as_mut(),
            refine: Feed::of(&mut self.refine.0, io, RefineInput::Head, Stage::Head),
        };
        rows.run(head, self.cols, &mut out)?;
        self.refine.check()?;
        let Some(check) = self.check.as_mut() else {
            return Ok(());
        };
        head.restart(HeadView::Right);
        let mut out = CheckedRows {
            sink,
            check,
            census: self.census.as_mut(),
            refine: Feed::checked(&mut self.refine.0, io, Stage::Head),
        };
        rows.run(head, self.cols, &mut out)?;
        self.refine.check()
    }

    /// Token row `row`'s guides: each cell's mean grey level in either view, from the band
    /// buffer's pixel rows (the band was encoded from them, so it holds them).
    fn guides(row: usize, view: &BandView<'_>, buffers: &mut RowBuffers<'_>) -> Result<(), Error> {
        let first = row.saturating_mul(PATCH_H);
        let mut left: [&[u8]; PATCH_H] = [&[]; PATCH_H];
        let mut right: [&[u8]; PATCH_H] = [&[]; PATCH_H];
        for (i, (l, r)) in left.iter_mut().zip(right.iter_mut()).enumerate() {
            let v = first.saturating_add(i);
            (*l, *r) = view.row(v).ok_or(Error::BufferSize {
                what: "SGM guide: band rows",
                expected: v.saturating_add(1),
                found: view.first.saturating_add(view.rows),
            })?;
        }
        cell_guide(&left, CELL_W, buffers.guide_left)?;
        cell_guide(&right, CELL_W, buffers.guide_right)
    }

    /// Kept token row `row` of both descriptor maps through the matching readouts, in `b`.
    fn push_row(
        &mut self,
        row: usize,
        (left, right): (&[i8], &[i8]),
        b: &mut RowBuffers<'_>,
        io: &mut RefineIo<'_>,
        sink: &mut impl Sink,
    ) -> Result<(), Error> {
        let mc = self.max_cols;
        sink.stage(Stage::Match);
        inverse_norms(left, b.inv_left)?;
        inverse_norms(right, b.inv_right)?;
        match_row(left, right, b.inv_right, mc, b.wta)?;
        cost_row(left, right, b.inv_left, b.inv_right, mc, b.cost)?;
        right_view_costs(b.cost, mc, b.cost_right)?;
        sink.stage(Stage::Sgm);
        if self.guided {
            Self::guides(row, &io.view, b)?;
            self.sgm.push_row_guided_in(b.cost, b.guide_left, b.sum, b.sgm_out)?;
            (self.sgm_right).push_row_guided_in(b.cost_right, b.guide_right, b.sum_right, b.sgm_right_out)?;
        } else {
            self.sgm.push_row_in(b.cost, b.sum, b.sgm_out)?;
            self.sgm_right.push_row_in(b.cost_right, b.sum_right, b.sgm_right_out)?;
        }
        sink.stage(Stage::LeftRight);
        wta_costs(b.cost_right, mc, b.wta_right)?;
        self.wta_kept += consistent_row(b.wta, b.wta_right, self.lr_max_diff_q8, b.wta_mask)?;
        self.sgm_kept += consistent_row(b.sgm_out, b.sgm_right_out, self.lr_max_diff_q8, b.sgm_mask)?;
        if let Some(check) = self.check.as_mut() {
            // The head's checked row `row` comes out after the band's matching; it is fused
            // with this one.
            check.keep_sgm(row, b.sgm_out, b.sgm_mask)?;
        }
        if let (Some(census), Some(scratch)) = (self.census.as_mut(), b.census.as_mut()) {
            // While the band holding the row's census window is loaded; kept for the head too.
            sink.stage(Stage::Sgm);
            census.compute_in(row, &io.view, scratch)?;
        }
        sink.matched(&MatchedRow {
            row,
            wta_q8: b.wta,
            sgm_q8: b.sgm_out,
            wta_consistent: b.wta_mask,
            sgm_consistent: b.sgm_mask,
        });
        if let Some((input, stage)) = self.refine.0.as_mut() {
            let matched = match *input {
                RefineInput::Nolink => Some((&*b.wta, None)),
                RefineInput::NolinkLr => Some((&*b.wta, Some(&*b.wta_mask))),
                RefineInput::Sgm => Some((&*b.sgm_out, None)),
                RefineInput::SgmLr => Some((&*b.sgm_out, Some(&*b.sgm_mask))),
                RefineInput::Head
                | RefineInput::HeadLr
                | RefineInput::FusedLr
                | RefineInput::FusedCensusLr
                | RefineInput::FusedAllLr
                // Never here: the driver runs census inputs without the encoder.
                | RefineInput::Census
                | RefineInput::CensusLr => None,
            };
            if let Some((disparity, mask)) = matched {
                sink.stage(Stage::Refine);
                stage.push(row, disparity, mask, io, sink)?;
            }
        }
        Ok(())
    }
}

/// A band's descriptor maps as a head reads them: the rows around those the band keeps.
struct BandHead<'d> {
    band: Band,
    left: &'d [i8],
    right: &'d [i8],
}

impl BandHead<'_> {
    /// The band's rows within [`head::ROW_REACH`] of its kept rows through `head` (fresh or
    /// restarted) to its end; only the kept rows' outputs reach `out`, numbered in the image.
    fn run(&self, head: &mut HeadStream<'_, '_>, cols: usize, out: &mut impl HeadSink) -> Result<(), Error> {
        let band = self.band;
        let input = band.around_kept(head::ROW_REACH);
        let mut kept = KeptRows {
            inner: out,
            first: input.start,
            keep: band.keep_from..band.keep_to,
        };
        for row in input {
            let (l, r) = kept_row(band, row, cols, self.left, self.right)?;
            head.push_row(l, r, &mut kept)?;
        }
        head.finish(&mut kept)
    }
}
