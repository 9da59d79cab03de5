//! The export pathway's run: each band encoded twice, on (L, L) and (R, R), its descriptor maps
//! read by every readout ([`Streams`]), band after band. One loop serves one band and several:
//! only where the resident streams live differs (below).
//!
//! Arena layout, in order: the two views' pixel band, the left descriptors of the band, then
//! - one band (images up to 48 rows): the encoder's scratch, reused after both passes for the
//!   right descriptors (written in place), the resident streams and the refinement's state, the
//!   band's head stream, the readouts' row buffers and the refinement's row scratch;
//! - several bands: the resident streams and the refinement's state (what carries from band to
//!   band: the SGMs' aggregates, the head's check, the census stage's ring), then the encoder's
//!   scratch, which between passes holds the right descriptors, the band's head stream, the
//!   readouts' row buffers and the refinement's row scratch.
//!
//! The head stream starts afresh on each band's own rows (those it keeps and the head's reach
//! around them) and ends with the band, its check rerunning the mirrored head on the same
//! stream: nothing of the head outlives a band, so the arena does not grow with the height.

use super::api::{BandEncoder, Report, RowSource, Sink};
use super::context::Context;
use super::feeding::{BandRows, Fresh};
use super::refine_stage::BandView;
use super::sizing::{band_head_bytes, refine_parts, resident_region};
use super::streams::Streams;
use crate::arena::split;
use crate::band::{Band, BandPlan};
use crate::config::{DIM, PATCH_H};
use crate::model::head::{HeadStream, HeadView};
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
    let too_small = ctx.too_small(arena.len());
    let desc_len = (band_px / PATCH_H) * cols * DIM;
    let (pixels, rest) = split(arena, 2 * band_px * width).ok_or(too_small)?;
    let (left_px, right_px) = pixels.split_at_mut(band_px * width);
    let (desc_left, scratch) = split(rest, desc_len).ok_or(too_small)?;
    let desc_left: &mut [i8] = bytemuck::cast_slice_mut(desc_left);
    let several = plan.len() > 1;
    let state_len = refine.map_or(0, |r| refine_parts(height, width, r).0);
    // The resident streams and the refinement's state: with several bands they carry state
    // from band to band, so they sit before the encoder's scratch; with one band they are made
    // after the right descriptors, in the scratch both passes are done with.
    let resident_len = resident_region(cols, opts.max_cols, ctx.head_shape(), state_len);
    let head_len = match ctx.head {
        Some(_) => band_head_bytes(cols, opts.head_candidates),
        None => 0,
    };
    let (resident_arena, scratch) = split(scratch, if several { resident_len } else { 0 }).ok_or(too_small)?;
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
    let mut band_used = 0;
    for (i, band) in plan.iter().enumerate() {
        rows.advance(band, left_px, right_px, resident.as_mut().map(|s| &mut s.refine), sink)?;
        let fresh = Fresh::of(plan, i, ctx.shared_rows());
        let (encoder_used, right_desc, rest) =
            ctx.encode(encoder, (left_px, right_px), fresh, desc_left, scratch, sink)?;
        sink.band(band, desc_left, right_desc);
        report.encoder = report.encoder.max(encoder_used);
        let pass = Pass {
            band,
            left: desc_left,
            right: right_desc,
            view: rows.view(left_px, right_px),
            head_len,
            last: i + 1 == plan.len(),
        };
        let used = match resident.as_mut() {
            Some(streams) => pass.run(ctx, streams, rest, &mut report, sink)?,
            None => {
                let (arena, rest) = split(rest, resident_len).ok_or(too_small)?;
                resident_len + pass.run(ctx, &mut Streams::new(ctx, arena, false)?, rest, &mut report, sink)?
            }
        };
        band_used = band_used.max(used);
    }
    report.arena_used = match several {
        true => report.pixels + desc_len + resident_len + report.encoder.max(desc_len + band_used),
        false => report.pixels + desc_len + report.encoder.max(desc_len + band_used),
    };
    Ok(report)
}

/// One band after both encoder passes: its descriptor maps and pixel rows.
struct Pass<'d> {
    band: Band,
    left: &'d [i8],
    right: &'d [i8],
    view: BandView<'d>,
    /// Bytes of the band's head stream (0 without the head).
    head_len: usize,
    /// The run's last band.
    last: bool,
}

impl Pass<'_> {
    /// The band through `streams` and a fresh head stream cut from the front of `scratch`, the
    /// readouts' row buffers and the refinement's row scratch after it; after the last band
    /// the streams' counts in `report` (the refinement's state and row scratch in
    /// `report.refine`). Returns the bytes of `scratch` used.
    fn run(
        &self,
        ctx: &Context<'_, '_>,
        streams: &mut Streams<'_>,
        scratch: &mut [u8],
        report: &mut Report,
        sink: &mut impl Sink,
    ) -> Result<usize, Error> {
        let available = scratch.len();
        let (head_arena, scratch) = split(scratch, self.head_len).ok_or(Error::ArenaTooSmall {
            needed: self.head_len,
            available,
        })?;
        let mut head = match ctx.head {
            Some(w) => Some(HeadStream::with_candidates(
                w,
                ctx.cols,
                ctx.opts.head_candidates,
                HeadView::Left,
                head_arena,
            )?),
            None => None,
        };
        let head_used = head.as_ref().map_or(0, HeadStream::arena_used);
        let rows_len = streams.row_bytes();
        let available = scratch.len();
        let (rows, scratch) = split(scratch, rows_len).ok_or(Error::ArenaTooSmall {
            needed: rows_len,
            available,
        })?;
        let mut io = ctx.refine_io(self.view, scratch)?;
        let maps = (self.band, self.left, self.right);
        let rows_used = streams.push_band(maps, head.as_mut(), rows, &mut io, sink)?;
        let scratch_used = io.scratch.used();
        report.refine = report.refine.max(streams.refine.used() + scratch_used);
        report.streams = report.streams.max(streams.used + head_used + rows_used);
        if self.last {
            streams.refine.done()?;
            (report.wta_kept, report.sgm_kept) = (streams.wta_kept, streams.sgm_kept);
            (report.head_kept, report.fused_kept) = (streams.head_kept(), streams.fused_kept());
        }
        Ok(match scratch_used {
            0 => self.head_len + rows_used,
            _ => self.head_len + rows_len + scratch_used,
        })
    }
}
