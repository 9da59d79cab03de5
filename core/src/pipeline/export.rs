//! The export pathway's run: each band encoded twice, on (L, L) and (R, R), its descriptor maps
//! read by every readout ([`Streams`]), band after band.
//!
//! Arena layout, in order: the two views' pixel band, the left descriptors of the band, then
//! - one band (images up to 48 rows): the encoder's scratch, reused after both passes for the
//!   right descriptors (written in place), the readout streams and the refinement's state and
//!   row scratch;
//! - several bands: the readout streams and the refinement's state (they carry state from band
//!   to band), then the encoder's scratch, which between passes holds the right descriptors and
//!   the refinement's row scratch.

use super::api::{Report, RowSource, Sink};
use super::context::Context;
use super::feeding::BandRows;
use super::layout::max;
use super::sizing::{refine_parts, stream_bytes};
use super::streams::Streams;
use crate::band::BandPlan;
use crate::config::{DIM, PATCH_H};
use crate::Error;

/// Runs the export pathway over every band of `plan`; the arena was checked against the run's
/// size.
pub(super) fn run(
    ctx: &Context<'_, '_>,
    source: &mut impl RowSource,
    plan: &BandPlan,
    arena: &mut [u8],
    sink: &mut impl Sink,
) -> Result<Report, Error> {
    let (opts, refine) = (ctx.opts, ctx.refine);
    let (cols, width, height, band_px) = (ctx.cols, ctx.width, ctx.height, ctx.band_px);
    let token_rows = height / PATCH_H;
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
        let mut streams = Streams::new(ctx, stream_arena, false)?;
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
        let mut streams = Streams::new(ctx, stream_arena, true)?;
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
