//! The export pathway's run: each band encoded twice, on (L, L) and (R, R), its descriptor maps
//! read by every readout ([`Streams`]), band after band. One loop serves one band and several:
//! only where the streams live differs (below), and the last band ends the streams either way.
//!
//! Arena layout, in order: the two views' pixel band, the left descriptors of the band, then
//! - one band (images up to 48 rows): the encoder's scratch, reused after both passes for the
//!   right descriptors (written in place), the readout streams and the refinement's state and
//!   row scratch;
//! - several bands: the readout streams and the refinement's state (they carry state from band
//!   to band), then the encoder's scratch, which between passes holds the right descriptors and
//!   the refinement's row scratch.

use super::api::{BandEncoder, Report, RowSource, Sink};
use super::context::Context;
use super::feeding::BandRows;
use super::refine_stage::BandView;
use super::sizing::{refine_parts, stream_bytes};
use super::streams::Streams;
use crate::band::{Band, BandPlan};
use crate::config::{DIM, PATCH_H};
use crate::Error;

/// Runs the export pathway over every band of `plan`, each band's passes by `encoder`; the
/// arena was checked against the run's size.
pub(super) fn run(
    ctx: &Context<'_, '_>,
    encoder: &mut impl BandEncoder,
    source: &mut impl RowSource,
    plan: &BandPlan,
    arena: &mut [u8],
    sink: &mut impl Sink,
) -> Result<Report, Error> {
    let (opts, refine) = (ctx.opts, ctx.refine);
    let (cols, width, height, band_px) = (ctx.cols, ctx.width, ctx.height, ctx.band_px);
    let desc_len = (band_px / PATCH_H) * cols * DIM;
    let (pixels, rest) = arena.split_at_mut(2 * band_px * width);
    let (left_px, right_px) = pixels.split_at_mut(band_px * width);
    let (desc_left, scratch) = rest.split_at_mut(desc_len);
    let desc_left: &mut [i8] = bytemuck::cast_slice_mut(desc_left);
    let several = plan.len() > 1;
    let state_len = refine.map_or(0, |r| refine_parts(height, width, r, true).0);
    // The readout streams and the refinement's state: with several bands they carry state from
    // band to band, so they sit before the encoder's scratch; with one band they are made after
    // the right descriptors, in the scratch both passes are done with.
    let streams_len = stream_bytes(cols, opts.max_cols, ctx.head_shape(), several) + state_len;
    let resident_len = if several { streams_len.min(scratch.len()) } else { 0 };
    let (resident_arena, scratch) = scratch.split_at_mut(resident_len);
    let mut resident = match several {
        true => Some(Streams::new(ctx, resident_arena, true)?),
        false => None,
    };
    let mut report = Report {
        rows: height / PATCH_H,
        cols,
        bands: plan.len(),
        pixels: 2 * band_px * width,
        descriptors: desc_len,
        ..Report::default()
    };
    let mut rows = BandRows::new(source, width);
    let mut scratch_used = 0;
    for (i, band) in plan.iter().enumerate() {
        let last = i + 1 == plan.len();
        rows.advance(band, left_px, right_px, resident.as_mut().map(|s| &mut s.refine), sink)?;
        let (encoder_used, right_desc, rest) = ctx.encode(encoder, left_px, right_px, desc_left, scratch, sink)?;
        sink.band(band, desc_left, right_desc);
        report.encoder = report.encoder.max(encoder_used);
        let pass = Pass {
            band,
            left: desc_left,
            right: right_desc,
            view: rows.view(left_px, right_px),
            last,
        };
        let used = match resident.as_mut() {
            Some(streams) => pass.run(ctx, streams, rest, &mut report, sink)?,
            None => {
                let (arena, rest) = rest.split_at_mut(streams_len.min(rest.len()));
                pass.run(ctx, &mut Streams::new(ctx, arena, false)?, rest, &mut report, sink)?
            }
        };
        scratch_used = scratch_used.max(used);
    }
    // `Pass::run` left the refinement's state bytes in `report.refine`.
    let state_used = report.refine;
    report.refine += scratch_used;
    report.arena_used = match (several, refine) {
        (true, _) => {
            let refine_scratch = refine.map_or(0, |_| desc_len + scratch_used);
            report.pixels + desc_len + streams_len + report.encoder.max(refine_scratch)
        }
        (false, Some(_)) => {
            // The refinement's state sits at a fixed offset after the streams' region.
            let after = streams_len - state_len + state_used + scratch_used;
            report.pixels + desc_len + report.encoder.max(desc_len + after)
        }
        (false, None) => report.pixels + desc_len + report.encoder.max(desc_len + report.streams),
    };
    Ok(report)
}

/// One band after both encoder passes: its descriptor maps and pixel rows.
struct Pass<'d> {
    band: Band,
    left: &'d [i8],
    right: &'d [i8],
    view: BandView<'d>,
    /// The run's last band.
    last: bool,
}

impl Pass<'_> {
    /// The band's kept rows through `streams`, the refinement's row scratch cut from `scratch`;
    /// after the last band the streams' end and their counts in `report` (the refinement's
    /// state bytes in `report.refine`). Returns the row scratch's bytes.
    fn run(
        &self,
        ctx: &Context<'_, '_>,
        streams: &mut Streams<'_, '_>,
        scratch: &mut [u8],
        report: &mut Report,
        sink: &mut impl Sink,
    ) -> Result<usize, Error> {
        let mut io = ctx.refine_io(self.view, scratch)?;
        streams.push_band(self.band, self.left, self.right, &mut io, sink)?;
        if self.last {
            streams.finish(&mut io, sink)?;
            // One band: the whole map is here, and the mirrored head reruns the band on the
            // left head's arena (with several it streamed beside the left one).
            streams.check_head_band(self.band, self.left, self.right, &mut io, sink)?;
            streams.refine.done()?;
            report.streams = streams.used;
            report.refine = streams.refine.used();
            (report.wta_kept, report.sgm_kept) = (streams.wta_kept, streams.sgm_kept);
            (report.head_kept, report.fused_kept) = (streams.head_kept(), streams.fused_kept());
        }
        Ok(io.scratch.used())
    }
}
