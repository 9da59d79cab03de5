//! The export pathway's readout streams: per kept token row the no-linkage WTA, SGM, both
//! left-right checks, the census SGM (for `fuse-all`), the shared head (and its check) and the
//! refinement's input.

use super::api::{MatchedRow, RefineInput, Sink, Stage};
use super::census_stage::{self, CensusStage};
use super::context::Context;
use super::feeding::kept_row;
use super::head_check::HEAD_CHECK_ROWS;
use super::head_check::{head_step, CheckedRows, Feed, HeadCheck, HeadRows};
use super::refine_stage::{BandView, RefineIo, Refinement};
use super::sizing::{matching_bytes, refine_parts, stream_bytes};
use crate::arena::Carver;
use crate::band::Band;
use crate::census;
use crate::config::{CELL_W, PATCH_H};
use crate::lr::{consistent_row, fuse_head_weight, right_view_costs, wta_costs};
use crate::matching::{cost_row, inverse_norms, match_row};
use crate::model::head::{self, HeadStream, HeadView};
use crate::model::ids::HeadKind;
#[cfg(doc)]
use crate::sgm::Penalties;
use crate::sgm::{cell_guide, state_len, SgmStream};
use crate::Error;

/// The readouts' state: one token row of buffers plus SGM's and the head's carried state.
pub(super) struct Streams<'a, 'w> {
    cols: usize,
    max_cols: usize,
    lr_max_diff_q8: u16,
    /// The SGM's jump penalty follows the views' brightness ([`Penalties::edge`]).
    guided: bool,
    inv_left: &'a mut [u32],
    inv_right: &'a mut [u32],
    cost: &'a mut [u16],
    cost_right: &'a mut [u16],
    sgm: SgmStream<'a>,
    sgm_right: SgmStream<'a>,
    wta: &'a mut [u16],
    wta_right: &'a mut [u16],
    sgm_out: &'a mut [u16],
    sgm_right_out: &'a mut [u16],
    wta_mask: &'a mut [u8],
    sgm_mask: &'a mut [u8],
    /// Each cell's mean grey level in the left and right view (guided SGM only).
    guide_left: &'a mut [u8],
    guide_right: &'a mut [u8],
    head: Option<HeadStream<'a, 'w>>,
    /// With `head_lr`: the mirrored head and the check.
    check: Option<(Option<HeadStream<'a, 'w>>, HeadCheck<'a>)>,
    /// With a `fuse-all+lr` refinement: the census SGM, its rows kept for the head's check.
    census: Option<CensusStage<'a>>,
    /// The refinement (when the run has one): the readout it reads and its state.
    pub(super) refine: Refinement<'a>,
    pub(super) used: usize,
    pub(super) wta_kept: usize,
    pub(super) sgm_kept: usize,
}

impl<'a, 'w> Streams<'a, 'w> {
    /// The streams of a run; `streaming`: several bands, so the head's check (if any) streams
    /// a mirrored head beside the left one instead of rerunning the band after it.
    pub(super) fn new(ctx: &Context<'_, 'w>, arena: &'a mut [u8], streaming: bool) -> Result<Self, Error> {
        let (cols, max_cols) = (ctx.cols, ctx.opts.max_cols);
        let shape = ctx.head_shape();
        let streams = stream_bytes(cols, max_cols, shape, streaming);
        let (arena, refine_arena) = arena.split_at_mut(streams.min(arena.len()));
        // The census stage sits at the front of the streams' region (its own alignment).
        let census_len = if shape.census {
            census_stage::bytes(ctx.width, shape.candidates, HEAD_CHECK_ROWS)
        } else {
            0
        };
        let (census_arena, arena) = arena.split_at_mut(census_len.min(arena.len()));
        let (census, census_used) = if shape.census {
            let (stage, used) = CensusStage::carve(
                census_arena,
                ctx.width,
                ctx.height,
                shape.candidates,
                ctx.opts.lr_max_diff_q8,
                HEAD_CHECK_ROWS,
            )?;
            (Some(stage), used)
        } else {
            (None, 0)
        };
        let state = ctx.refine.map_or(0, |r| refine_parts(ctx.height, ctx.width, r, true).0);
        let available = streams.saturating_add(refine_arena.len());
        let state_arena = refine_arena.get_mut(..state).ok_or(Error::ArenaTooSmall {
            needed: streams.saturating_add(state),
            available,
        })?;
        let refine = Refinement::new(ctx.refine, ctx.width, ctx.height, streaming, true, state_arena)?;
        let volume_row = state_len(cols, max_cols);
        let guided = ctx.opts.penalties.guided();
        let matching = matching_bytes(cols, max_cols, guided);
        let (matching_arena, head_arena) = arena.split_at_mut(matching.min(arena.len()));
        let mut carver = Carver::new(matching_arena, matching)?;
        let inv_left = carver.u32s(cols)?;
        let inv_right = carver.u32s(cols)?;
        let cost = carver.u16s(volume_row)?;
        let cost_right = carver.u16s(volume_row)?;
        let mut sgm = SgmStream::new(
            cols,
            max_cols,
            ctx.opts.penalties,
            carver.u16s(volume_row)?,
            carver.u16s(volume_row)?,
            carver.u32s(volume_row)?,
        )?;
        let mut sgm_right = SgmStream::new(
            cols,
            max_cols,
            ctx.opts.penalties,
            carver.u16s(volume_row)?,
            carver.u16s(volume_row)?,
            carver.u32s(volume_row)?,
        )?;
        let wta = carver.u16s(cols)?;
        let wta_right = carver.u16s(cols)?;
        let sgm_out = carver.u16s(cols)?;
        let sgm_right_out = carver.u16s(cols)?;
        let wta_mask = carver.u8s(cols)?;
        let sgm_mask = carver.u8s(cols)?;
        // The guides take arena only when the SGM uses them (the default does not); bytes,
        // so they come last and need no alignment.
        let guide_cols = if guided { cols } else { 0 };
        if guided {
            sgm = sgm.with_guide(carver.u8s(cols)?)?;
            sgm_right = sgm_right.with_guide(carver.u8s(cols)?)?;
        }
        let guide_left = carver.u8s(guide_cols)?;
        let guide_right = carver.u8s(guide_cols)?;
        let mut used = carver.used();
        let (head, check) = match ctx.head {
            Some(w) => {
                let nd = ctx.opts.head_candidates;
                let head_len = head::arena_bytes_with(HeadKind::Export, cols, nd);
                let (left_arena, check_arena) = head_arena.split_at_mut(head_len.min(head_arena.len()));
                let stream = HeadStream::with_candidates(w, cols, nd, HeadView::Left, left_arena)?;
                used = matching + stream.arena_used();
                let check = if ctx.head_lr() {
                    let (mirror, rest) = if streaming {
                        let len = head_len.min(check_arena.len());
                        let (mirror_arena, rest) = check_arena.split_at_mut(len);
                        let mirror = HeadStream::with_candidates(w, cols, nd, HeadView::Right, mirror_arena)?;
                        used += mirror.arena_used();
                        (Some(mirror), rest)
                    } else {
                        (None, check_arena)
                    };
                    // fuse-all fuses the head with the census first, that with the SGM here.
                    let weight = if shape.census {
                        census::FUSE_ALL_FIRST_WEIGHT
                    } else {
                        fuse_head_weight(ctx.width)
                    };
                    let (check, check_used) =
                        HeadCheck::carve(rest, cols, HEAD_CHECK_ROWS, ctx.opts.lr_max_diff_q8, weight)?;
                    used += check_used;
                    Some((mirror, check))
                } else {
                    None
                };
                (Some(stream), check)
            }
            None => (None, None),
        };
        // The census stage's bytes precede the rest (`matching` counts from the rest's start).
        used = census_len.max(census_used).saturating_add(used);
        Ok(Self {
            cols,
            max_cols,
            lr_max_diff_q8: ctx.opts.lr_max_diff_q8,
            guided,
            inv_left,
            inv_right,
            cost,
            cost_right,
            sgm,
            sgm_right,
            wta,
            wta_right,
            sgm_out,
            sgm_right_out,
            wta_mask,
            sgm_mask,
            guide_left,
            guide_right,
            head,
            check,
            census,
            refine,
            used,
            wta_kept: 0,
            sgm_kept: 0,
        })
    }

    /// Cells the head's left-right check kept (0 without it).
    pub(super) fn head_kept(&self) -> usize {
        self.check.as_ref().map_or(0, |(_, check)| check.kept)
    }

    /// Cells the fused readout kept (0 without the head's check).
    pub(super) fn fused_kept(&self) -> usize {
        self.check.as_ref().map_or(0, |(_, check)| check.fusion.kept)
    }

    /// Feeds the rows `band` keeps.
    pub(super) fn push_band(
        &mut self,
        band: Band,
        left: &[i8],
        right: &[i8],
        io: &mut RefineIo<'_>,
        sink: &mut impl Sink,
    ) -> Result<(), Error> {
        for row in band.keep_from..band.keep_to {
            let (l, r) = kept_row(band, row, self.cols, left, right)?;
            self.push_row(row, l, r, io, sink)?;
        }
        Ok(())
    }

    /// Token row `row`'s guides: each cell's mean grey level in either view, from the band
    /// buffer's pixel rows (the band was encoded from them, so it holds them).
    fn guides(&mut self, row: usize, view: &BandView<'_>) -> Result<(), Error> {
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
        cell_guide(&left, CELL_W, self.guide_left)?;
        cell_guide(&right, CELL_W, self.guide_right)
    }

    fn push_row(
        &mut self,
        row: usize,
        left: &[i8],
        right: &[i8],
        io: &mut RefineIo<'_>,
        sink: &mut impl Sink,
    ) -> Result<(), Error> {
        let mc = self.max_cols;
        sink.stage(Stage::Match);
        inverse_norms(left, self.inv_left)?;
        inverse_norms(right, self.inv_right)?;
        match_row(left, right, self.inv_right, mc, self.wta)?;
        cost_row(left, right, self.inv_left, self.inv_right, mc, self.cost)?;
        right_view_costs(self.cost, mc, self.cost_right)?;
        sink.stage(Stage::Sgm);
        if self.guided {
            self.guides(row, &io.view)?;
            self.sgm.push_row_guided(self.cost, self.guide_left, self.sgm_out)?;
            self.sgm_right
                .push_row_guided(self.cost_right, self.guide_right, self.sgm_right_out)?;
        } else {
            self.sgm.push_row(self.cost, self.sgm_out)?;
            self.sgm_right.push_row(self.cost_right, self.sgm_right_out)?;
        }
        sink.stage(Stage::LeftRight);
        wta_costs(self.cost_right, mc, self.wta_right)?;
        self.wta_kept += consistent_row(self.wta, self.wta_right, self.lr_max_diff_q8, self.wta_mask)?;
        self.sgm_kept += consistent_row(self.sgm_out, self.sgm_right_out, self.lr_max_diff_q8, self.sgm_mask)?;
        if let Some((_, check)) = self.check.as_mut() {
            // The head's checked row `row` arrives a few rows later; it is fused with this one.
            check.keep_sgm(row, self.sgm_out, self.sgm_mask)?;
        }
        if let Some(census) = self.census.as_mut() {
            // While the band holding the row's census window is loaded; kept for the head too.
            sink.stage(Stage::Sgm);
            census.compute(row, &io.view)?;
        }
        sink.matched(&MatchedRow {
            row,
            wta_q8: self.wta,
            sgm_q8: self.sgm_out,
            wta_consistent: self.wta_mask,
            sgm_consistent: self.sgm_mask,
        });
        if let Some((input, stage)) = self.refine.0.as_mut() {
            let matched = match *input {
                RefineInput::Nolink => Some((&*self.wta, None)),
                RefineInput::NolinkLr => Some((&*self.wta, Some(&*self.wta_mask))),
                RefineInput::Sgm => Some((&*self.sgm_out, None)),
                RefineInput::SgmLr => Some((&*self.sgm_out, Some(&*self.sgm_mask))),
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
        self.head_rows(Some((left, right)), io, sink)
    }

    /// The head streams on the next descriptor row, or (`None`) at the end of the input.
    fn head_rows(
        &mut self,
        input: Option<(&[i8], &[i8])>,
        io: &mut RefineIo<'_>,
        sink: &mut impl Sink,
    ) -> Result<(), Error> {
        let Some(head) = self.head.as_mut() else {
            return Ok(());
        };
        sink.stage(Stage::Head);
        match self.check.as_mut() {
            Some((mirror, check)) => {
                let mut rows = HeadRows {
                    sink: &mut *sink,
                    check: Some(&mut *check),
                    refine: Feed::of(&mut self.refine.0, io, RefineInput::Head, Stage::Head),
                };
                head_step(head, input, &mut rows)?;
                if let Some(mirror) = mirror {
                    let mut rows = CheckedRows {
                        sink: &mut *sink,
                        check,
                        census: self.census.as_mut(),
                        refine: Feed::checked(&mut self.refine.0, io, Stage::Head),
                    };
                    head_step(mirror, input, &mut rows)?;
                }
            }
            None => {
                let mut rows = HeadRows {
                    sink: &mut *sink,
                    check: None,
                    refine: Feed::of(&mut self.refine.0, io, RefineInput::Head, Stage::Head),
                };
                head_step(head, input, &mut rows)?;
            }
        }
        self.refine.check()
    }

    pub(super) fn finish(&mut self, io: &mut RefineIo<'_>, sink: &mut impl Sink) -> Result<(), Error> {
        self.head_rows(None, io, sink)
    }

    /// One band, after [`Streams::finish`]: the mirrored head over the band's rows on the left
    /// head's arena, checked against the left rows it kept (a no-op unless the check is on and
    /// not already streamed).
    pub(super) fn check_head_band(
        &mut self,
        band: Band,
        left: &[i8],
        right: &[i8],
        io: &mut RefineIo<'_>,
        sink: &mut impl Sink,
    ) -> Result<(), Error> {
        let (Some(head), Some((None, check))) = (self.head.as_mut(), self.check.as_mut()) else {
            return Ok(());
        };
        sink.stage(Stage::Head);
        head.restart(HeadView::Right);
        let mut rows = CheckedRows {
            sink,
            check,
            census: self.census.as_mut(),
            refine: Feed::checked(&mut self.refine.0, io, Stage::Head),
        };
        for row in band.keep_from..band.keep_to {
            let (l, r) = kept_row(band, row, self.cols, left, right)?;
            head.push_row(l, r, &mut rows)?;
        }
        head.finish(&mut rows)?;
        self.refine.check()
    }
}
