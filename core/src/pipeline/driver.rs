//! The driver: [`Pipeline`] checks a run, cuts the arena and moves band after band through the
//! encoder and the readout streams (the native pathway in `native.rs`).

use super::api::{Options, Pathway, Refine, RefineInput, Report, RowSource, Sink, Stage};
use super::feeding::BandRows;
use super::native;
use super::refine_stage::{BandView, RefineIo, Scratch};
use super::sizing::{arena_bytes_run, band_pixel_rows, max, refine_parts, stream_bytes, ReadoutShape};
use super::streams::Streams;
use crate::band::BandPlan;
use crate::config::{check_view_size, DIM, PATCH_H};
use crate::matching::check_candidates;
use crate::model::encoder::{Encoder, GrayBand};
use crate::model::head::{self, HeadWeights};
use crate::model::ids::HeadKind;
use crate::model::probe::NoProbe;
use crate::Error;
#[cfg(doc)]
use {
    super::{arena_bytes_for, arena_bytes_refined},
    crate::refine::RefineParams,
};

/// The int8 encoder and (optionally) the heads of both pathways over one weight blob.
#[derive(Clone, Copy)]
pub struct Pipeline<'w> {
    pub(super) encoder: Encoder<'w>,
    pub(super) head: Option<HeadWeights<'w>>,
    pub(super) native: Option<HeadWeights<'w>>,
}

impl<'w> Pipeline<'w> {
    /// The pipeline of a blob; a head the blob does not carry (or carries incomplete) is left
    /// out, and a run that needs it is an error naming its first missing tensor.
    pub fn new(blob: crate::blob::Blob<'w>) -> Result<Self, Error> {
        Ok(Self {
            encoder: Encoder::new(blob)?,
            head: HeadWeights::for_kind(blob, HeadKind::Export).ok(),
            native: HeadWeights::for_kind(blob, HeadKind::Native).ok(),
        })
    }

    /// Whether the blob carries the shared head (export pathway).
    pub fn has_head(&self) -> bool {
        self.head.is_some()
    }

    /// Whether the blob carries `pathway`'s head (the native pathway needs one to run at all).
    pub fn has_head_of(&self, pathway: Pathway) -> bool {
        match pathway {
            Pathway::Export => self.head.is_some(),
            Pathway::Native => self.native.is_some(),
        }
    }

    /// Runs the pair `source` delivers through every readout, in `arena`
    /// ([`arena_bytes_for`] bytes at least).
    pub fn run(
        &self,
        source: &mut impl RowSource,
        opts: &Options,
        arena: &mut [u8],
        sink: &mut impl Sink,
    ) -> Result<Report, Error> {
        self.run_with(source, opts, None, arena, sink)
    }

    /// [`Pipeline::run`] with the pixel refinement of `refine.input`'s token grid: pixel rows
    /// go to [`Sink::refined`]. The arena must hold [`arena_bytes_refined`] bytes.
    ///
    /// Errors as [`Pipeline::run`], and [`Error::MissingReadout`] for a head input of a run
    /// without the head (or, for [`RefineInput::HeadLr`], [`RefineInput::FusedLr`] and
    /// [`RefineInput::FusedAllLr`], without its check; the last two also on the native pathway,
    /// which has no descriptor SGM; [`RefineInput::FusedCensusLr`] on the export pathway),
    /// [`Error::OutOfRange`] for bad [`RefineParams`]. A census input ([`RefineInput::Census`],
    /// [`RefineInput::CensusLr`]) runs no encoder and no head: it is
    /// [`run_census`](super::run_census), in [`census_arena_bytes`](super::census_arena_bytes).
    pub fn run_refined(
        &self,
        source: &mut impl RowSource,
        opts: &Options,
        refine: &Refine,
        arena: &mut [u8],
        sink: &mut impl Sink,
    ) -> Result<Report, Error> {
        self.run_with(source, opts, Some(refine), arena, sink)
    }

    /// The head weights of `pathway`, when the blob has them.
    fn weights_of(&self, pathway: Pathway) -> Option<HeadWeights<'w>> {
        match pathway {
            Pathway::Export => self.head,
            Pathway::Native => self.native,
        }
    }

    fn run_with(
        &self,
        source: &mut impl RowSource,
        opts: &Options,
        refine: Option<&Refine>,
        arena: &mut [u8],
        sink: &mut impl Sink,
    ) -> Result<Report, Error> {
        if let Some(r) = refine.filter(|r| r.input.census_only()) {
            // The census readout reads pixels only: no encoder pass, no head.
            return super::census_run::run_census(source, opts, Some(r), arena, sink);
        }
        let (width, height) = (source.width(), source.height());
        let (token_rows, cols) = check_view_size(height, width)?;
        if width > self.encoder.max_width() {
            return Err(Error::TooWide {
                width,
                max: self.encoder.max_width(),
            });
        }
        let native = opts.pathway == Pathway::Native;
        if !native {
            check_candidates(opts.max_cols)?;
        }
        head::check_candidates(opts.head_candidates)?;
        let head = match (native || opts.head, self.weights_of(opts.pathway)) {
            (true, Some(w)) => Some(w),
            (true, None) => {
                return Err(Error::Blob(crate::blob::BlobError::MissingTensor {
                    id: head_id(opts.pathway),
                }))
            }
            (false, _) => None,
        };
        let head_lr = head.is_some() && opts.head_lr;
        if let Some(r) = refine {
            r.params.check()?;
            let missing = match r.input {
                RefineInput::Head => head.is_none(),
                RefineInput::HeadLr => !head_lr,
                RefineInput::FusedLr | RefineInput::FusedAllLr => native || !head_lr,
                RefineInput::FusedCensusLr => !native || !head_lr,
                RefineInput::Census | RefineInput::CensusLr => false,
                _ => native,
            };
            if missing {
                return Err(Error::MissingReadout {
                    readout: r.input.name(),
                });
            }
        }
        let needed = arena_bytes_run(height, width, opts, refine);
        if arena.len() < needed {
            return Err(Error::ArenaTooSmall {
                needed,
                available: arena.len(),
            });
        }
        let plan = BandPlan::new(token_rows)?;
        let band_px = band_pixel_rows(height);
        let ctx = Context {
            pipeline: self,
            head,
            opts,
            refine,
            cols,
            width,
            height,
            band_px,
        };
        if native {
            return native::run(&ctx, source, &plan, arena, sink);
        }
        let desc_len = (band_px / PATCH_H) * cols * DIM;
        let (pixels, rest) = arena.split_at_mut(2 * band_px * width);
        let (left_px, right_px) = pixels.split_at_mut(band_px * width);
        let (desc_left, scratch) = rest.split_at_mut(desc_len);
        let desc_left: &mut [i8] = bytemuck::cast_slice_mut(desc_left);
        let mut report = Report {
            rows: token_rows,
            cols,
            bands: plan.len(),
            pixels: 2 * band_px * width,
            descriptors: desc_len,
            ..Report::default()
        };
        let mut rows = BandRows {
            source,
            width,
            first: 0,
            loaded: 0,
        };
        let state_len = match refine {
            Some(r) => refine_parts(height, width, r).0,
            None => 0,
        };
        if plan.len() == 1 {
            let band = plan.get(0).ok_or(Error::EmptyImage)?;
            rows.load(band, left_px, right_px, sink)?;
            let (encoder_used, right_desc, rest) = ctx.encode(left_px, right_px, desc_left, scratch, sink)?;
            sink.band(band, desc_left, right_desc);
            let stream_len = stream_bytes(cols, opts.max_cols, ctx.head_shape(), false) + state_len;
            let (stream_arena, rest) = rest.split_at_mut(stream_len.min(rest.len()));
            let mut streams = Streams::new(&ctx, stream_arena, false)?;
            let mut io = ctx.refine_io(rows.view(left_px, right_px), rest)?;
            streams.push_band(band, desc_left, right_desc, &mut io, sink)?;
            streams.finish(&mut io, sink)?;
            // The whole map is here: the mirrored head reruns the band on the left head's arena.
            streams.check_head_band(band, desc_left, right_desc, &mut io, sink)?;
            streams.refine_done()?;
            report.encoder = encoder_used;
            report.streams = streams.used;
            report.refine = streams.refine_used() + io.scratch.used();
            (report.wta_kept, report.sgm_kept) = (streams.wta_kept, streams.sgm_kept);
            (report.head_kept, report.fused_kept) = (streams.head_kept(), streams.fused_kept());
            let after = match refine {
                // The refinement's state sits at a fixed offset after the streams' region.
                Some(_) => stream_len - state_len + streams.refine_used() + io.scratch.used(),
                None => streams.used,
            };
            report.arena_used = report.pixels + desc_len + max(encoder_used, desc_len + after);
        } else {
            let stream_len = stream_bytes(cols, opts.max_cols, ctx.head_shape(), true);
            let (stream_arena, scratch) = scratch.split_at_mut((stream_len + state_len).min(scratch.len()));
            let mut streams = Streams::new(&ctx, stream_arena, true)?;
            let mut scratch_used = 0;
            for (i, band) in plan.iter().enumerate() {
                if i > 0 {
                    // Rows the refinement still needs that the load drops go to its ring.
                    streams.keep_view_rows(&rows.view(left_px, right_px), band.start * PATCH_H, sink)?;
                }
                rows.load(band, left_px, right_px, sink)?;
                let (encoder_used, right_desc, rest) = ctx.encode(left_px, right_px, desc_left, scratch, sink)?;
                sink.band(band, desc_left, right_desc);
                let mut io = ctx.refine_io(rows.view(left_px, right_px), rest)?;
                streams.push_band(band, desc_left, right_desc, &mut io, sink)?;
                scratch_used = io.scratch.used();
                report.encoder = report.encoder.max(encoder_used);
            }
            // The encoder's scratch is free now: the last rows' refinement uses it from the
            // same offset as between passes.
            let rest = scratch.get_mut(desc_len..).unwrap_or_default();
            let mut io = ctx.refine_io(rows.view(left_px, right_px), rest)?;
            streams.finish(&mut io, sink)?;
            streams.refine_done()?;
            report.streams = streams.used;
            report.refine = streams.refine_used() + scratch_used.max(io.scratch.used());
            (report.wta_kept, report.sgm_kept) = (streams.wta_kept, streams.sgm_kept);
            (report.head_kept, report.fused_kept) = (streams.head_kept(), streams.fused_kept());
            let refine_scratch = match refine {
                Some(_) => desc_len + scratch_used.max(io.scratch.used()),
                None => 0,
            };
            report.arena_used = report.pixels + desc_len + stream_len + state_len + report.encoder.max(refine_scratch);
        }
        Ok(report)
    }
}

/// A tensor id of `pathway`'s head (its input LayerNorm), for the error of a head asked of a
/// blob without one.
fn head_id(pathway: Pathway) -> crate::blob::TensorId {
    crate::model::ids::id(crate::model::ids::kind::LAYERNORM, pathway.layernorm())
}

/// What the stages of one run share.
pub(super) struct Context<'p, 'w> {
    pub(super) pipeline: &'p Pipeline<'w>,
    pub(super) head: Option<HeadWeights<'w>>,
    pub(super) opts: &'p Options,
    pub(super) refine: Option<&'p Refine>,
    pub(super) cols: usize,
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) band_px: usize,
}

impl Context<'_, '_> {
    /// Whether this run checks the head left against right.
    pub(super) fn head_lr(&self) -> bool {
        self.head.is_some() && self.opts.head_lr
    }

    /// The head's shape in the arena (sized even without a head: see [`arena_bytes_for`]).
    pub(super) fn head_shape(&self) -> ReadoutShape {
        ReadoutShape {
            lr: self.head_lr(),
            ..ReadoutShape::of(self.opts, self.refine)
        }
    }

    /// The refinement's view of the band buffer and its row scratch, cut from `arena` (none
    /// without the refinement).
    pub(super) fn refine_io<'b>(&self, view: BandView<'b>, arena: &'b mut [u8]) -> Result<RefineIo<'b>, Error> {
        let scratch = match self.refine {
            Some(r) => Scratch::new(arena, self.width, self.height, &r.params, r.equalise)?,
            None => Scratch::none(),
        };
        Ok(RefineIo { view, scratch })
    }

    /// Both encoder passes over the band in the pixel buffers: the left descriptors are copied
    /// to `desc_left`, the right ones stay at the front of `scratch`. Returns the encoder's
    /// high-water, the right descriptors and the rest of `scratch`.
    pub(super) fn encode<'s>(
        &self,
        left_px: &[u8],
        right_px: &[u8],
        desc_left: &mut [i8],
        scratch: &'s mut [u8],
        sink: &mut impl Sink,
    ) -> Result<(usize, &'s [i8], &'s mut [u8]), Error> {
        let encoder = &self.pipeline.encoder;
        sink.stage(Stage::EncodeLeft);
        let view = GrayBand::new(left_px, self.width, self.band_px)?;
        let (left_report, len) = encoder.describe_in_place(view, scratch, &mut NoProbe)?;
        let codes: &[i8] = bytemuck::cast_slice(scratch.get(..len).unwrap_or_default());
        Error::check_len("descriptor band", desc_left.len(), codes.len())?;
        desc_left.copy_from_slice(codes);
        sink.stage(Stage::EncodeRight);
        let view = GrayBand::new(right_px, self.width, self.band_px)?;
        let (right_report, len) = encoder.describe_in_place(view, scratch, &mut NoProbe)?;
        let (right, rest) = scratch.split_at_mut(len);
        let used = left_report.arena_used.max(right_report.arena_used);
        Ok((used, bytemuck::cast_slice(right), rest))
    }
}
