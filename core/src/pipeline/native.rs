//! The native pathway: one encoder pass per band on the actual pair (L, R), its de-positioned
//! fused grid ([`Encoder::pair_tokens_in_place`]) read row by row by the native head. Its
//! left-right check needs no second pass: the right view's disparity is read from the left
//! head's own logits ([`head::right_view_row`]), row by row as they leave the head.
//!
//! Arena layout, in order: the two views' pixel band; with several bands the head stream; the
//! check's rows; the refinement's state; then the encoder's scratch, which after each pass
//! holds the band's pair tokens at its front, with one band the head stream after them, then
//! the refinement's row scratch. Each band is finished — its pass, every head row it makes
//! computable — before the next is loaded. With weights whose token rows do not depend on
//! their place in the band, a band's pass computes only the rows the band before did not
//! ([`Fresh`]): the shared rows stay at the scratch's front.
//!
//! [`Encoder::pair_tokens_in_place`]: crate::model::encoder::Encoder::pair_tokens_in_place

use super::api::{BandEncoder, RefineInput, Report, RowSource, Sink, Stage};
use super::census_stage::{self, CensusStage};
use super::context::Context;
use super::feeding::{BandRows, Fresh};
use super::head_check::{Feed, HeadRows, OnePassCheck, OnePassRows};
use super::layout::aligned;
use super::refine_stage::{BandView, RefineIo, Refinement};
use super::sizing::{native_census_bytes, native_check_bytes, refine_parts};
use crate::arena::split;
use crate::band::{Band, BandPlan};
use crate::config::{DIM, PATCH_H};
use crate::model::encoder::GrayBand;
use crate::model::head::{self, HeadStream, HeadView, HeadWeights};
use crate::model::ids::HeadKind;
use crate::Error;

/// Runs the native pathway over every band of `plan`, each band's pass by `encoder`; `ctx.head`
/// holds the native head's weights and the arena was checked against [`arena_bytes`].
pub(super) fn run(
    ctx: &Context<'_, '_>,
    encoder: &mut impl BandEncoder,
    source: &mut impl RowSource,
    plan: &BandPlan,
    arena: &mut [u8],
    sink: &mut impl Sink,
) -> Result<Report, Error> {
    let weights = ctx.head.ok_or(Error::MissingReadout { readout: "head" })?;
    let streaming = plan.len() > 1;
    let (width, cols, band_px) = (ctx.width, ctx.cols, ctx.band_px);
    let pixel_len = band_px * width;
    let nd = ctx.opts.head_candidates;
    let head_len = aligned(head::arena_bytes_with(HeadKind::Native, cols, nd));
    let check_len = native_check_bytes(cols, ctx.head_lr());
    let census_len = native_census_bytes(width, ctx.opts, ctx.refine);
    let state_len = aligned(ctx.refine.map_or(0, |r| refine_parts(ctx.height, width, r).0));
    let too_small = ctx.too_small(arena.len());
    let (pixels, rest) = split(arena, 2 * pixel_len).ok_or(too_small)?;
    let (left_px, right_px) = pixels.split_at_mut(pixel_len);
    let (check_arena, rest) = split(rest, check_len).ok_or(too_small)?;
    let (census_arena, rest) = split(rest, census_len).ok_or(too_small)?;
    let (state_arena, scratch) = split(rest, state_len).ok_or(too_small)?;
    let mut readouts = Readouts::new(ctx, weights, check_arena, census_arena, state_arena, streaming)?;
    let mut rows = BandRows::new(source, width);
    let mut report = Report {
        rows: ctx.height / PATCH_H,
        cols,
        bands: plan.len(),
        pixels: 2 * pixel_len,
        ..Report::default()
    };
    let (mut after_tokens, mut scratch_used) = (0, 0);
    let row_len = cols * 2 * DIM;
    for (i, band) in plan.iter().enumerate() {
        rows.advance(band, left_px, right_px, Some(&mut readouts.refine), sink)?;
        // The rows this band shares with the band before stay at the scratch's front, where
        // that band's tokens are; the pass computes the rest after them.
        let fresh = Fresh::of(plan, i, ctx.shared_rows());
        fresh.keep(scratch, row_len, "pair token band")?;
        let fresh_px = band_px - fresh.kept * PATCH_H;
        let left = GrayBand::new(fresh.pixels(left_px, width), width, fresh_px)?;
        let right = GrayBand::new(fresh.pixels(right_px, width), width, fresh_px)?;
        let kept_len = fresh.kept * row_len;
        sink.stage(Stage::EncodePair);
        let (encoder_used, len) = encoder.pair_pass(left, right, scratch.get_mut(kept_len..).unwrap_or_default())?;
        // A stand-in encoder may answer with any length: the band's tokens are `2 x DIM` codes
        // a cell.
        Error::check_len("pair token band", (fresh_px / PATCH_H) * row_len, len)?;
        report.encoder = report.encoder.max(kept_len + encoder_used);
        let (tokens, rest) = split(scratch, kept_len + len).ok_or(too_small)?;
        let tokens: &[i8] = bytemuck::cast_slice(tokens);
        sink.pair_band(band, tokens);
        // Each band's head stream starts afresh after the band's tokens, so nothing of the
        // head outlives the band and the arena does not grow with the image's height.
        let (arena, rest) = split(rest, head_len).ok_or(too_small)?;
        let mut stream = HeadStream::with_candidates(weights, cols, nd, HeadView::Left, arena)?;
        let pass = Pass {
            band,
            tokens,
            view: rows.view(left_px, right_px),
        };
        let used = pass.run(ctx, &mut readouts, &mut stream, rest, sink)?;
        scratch_used = scratch_used.max(used);
        after_tokens = after_tokens.max(len + head_len);
    }
    readouts.refine.done()?;
    report.streams = readouts.check_used + readouts.census_used;
    report.refine = readouts.refine.used() + scratch_used;
    report.head_kept = readouts.check.as_ref().map_or(0, |check| check.kept);
    report.fused_kept = readouts.census.as_ref().map_or(0, |census| census.kept);
    let fixed = report.pixels + check_len + census_len + state_len;
    report.arena_used = fixed + report.encoder.max(after_tokens + scratch_used);
    Ok(report)
}

/// One band after its encoder pass: its pair tokens and pixel rows.
struct Pass<'d> {
    band: Band,
    tokens: &'d [i8],
    view: BandView<'d>,
}

impl Pass<'_> {
    /// The band's rows through a fresh head `stream` to its end, the refinement's row scratch
    /// cut from `scratch`. Returns the row scratch's bytes.
    fn run(
        &self,
        ctx: &Context<'_, '_>,
        readouts: &mut Readouts<'_, '_>,
        stream: &mut HeadStream<'_, '_>,
        scratch: &mut [u8],
        sink: &mut impl Sink,
    ) -> Result<usize, Error> {
        let mut io = ctx.refine_io(self.view, scratch)?;
        readouts.push_band(stream, self.band, self.tokens, &mut io, sink)?;
        Ok(io.scratch.used())
    }
}

/// What outlives a pass: the check's rows (with `head_lr`), the census stage (for the fused
/// readout) and the refinement.
struct Readouts<'a, 'w> {
    cols: usize,
    weights: HeadWeights<'w>,
    check: Option<OnePassCheck<'a>>,
    check_used: usize,
    census: Option<CensusStage<'a>>,
    census_used: usize,
    refine: Refinement<'a>,
}

impl<'a, 'w> Readouts<'a, 'w> {
    fn new(
        ctx: &Context<'_, '_>,
        weights: HeadWeights<'w>,
        check: &'a mut [u8],
        census: &'a mut [u8],
        state: &'a mut [u8],
        streaming: bool,
    ) -> Result<Self, Error> {
        let cols = ctx.cols;
        let (check, check_used) = if ctx.head_lr() {
            let (check, used) = OnePassCheck::carve(check, cols, ctx.opts.lr_max_diff_q8)?;
            (Some(check), used)
        } else {
            (None, 0)
        };
        let (census, census_used) = match ctx.refine {
            Some(r) if r.input == RefineInput::FusedCensusLr => {
                let nd = ctx.opts.head_candidates;
                let lr = ctx.opts.lr_max_diff_q8;
                let (stage, used) =
                    CensusStage::carve(census, ctx.width, ctx.height, (nd, lr), census_stage::RING_ROWS, true)?;
                (Some(stage), used)
            }
            _ => (None, 0),
        };
        let refine = Refinement::new(ctx.refine, ctx.width, ctx.height, streaming, state)?;
        Ok(Self {
            cols,
            weights,
            check,
            check_used,
            census,
            census_used,
            refine,
        })
    }

    /// Feeds a fresh head `stream` the band's rows around those it keeps
    /// ([`Band::around_kept`] by [`head::ROW_REACH`]) and ends it; the kept rows' outputs go on.
    fn push_band(
        &mut self,
        stream: &mut HeadStream<'_, '_>,
        band: Band,
        tokens: &[i8],
        io: &mut RefineIo<'_>,
        sink: &mut impl Sink,
    ) -> Result<(), Error> {
        let row_len = self.cols * 2 * DIM;
        let input = band.around_kept(head::ROW_REACH);
        let window = Window {
            first: input.start,
            keep: band.keep_from..band.keep_to,
        };
        for row in input {
            let at = (row - band.start) * row_len;
            let Some(tokens) = tokens.get(at..at + row_len) else {
                return Err(Error::BufferSize {
                    what: "pair token band",
                    expected: band.rows * row_len,
                    found: tokens.len(),
                });
            };
            if let Some(census) = self.census.as_mut().filter(|_| window.keep.contains(&row)) {
                // The census row now, while the band holds its view rows; fused when the
                // head's checked row comes out.
                sink.stage(Stage::Sgm);
                census.compute(row, &io.view)?;
            }
            self.step(stream, Some(tokens), &window, io, sink)?;
        }
        self.step(stream, None, &window, io, sink)
    }

    /// One row (or, `None`, the end) into the head `stream`; its output rows go to the sink,
    /// the check and the refinement.
    fn step(
        &mut self,
        stream: &mut HeadStream<'_, '_>,
        tokens: Option<&[i8]>,
        window: &Window,
        io: &mut RefineIo<'_>,
        sink: &mut impl Sink,
    ) -> Result<(), Error> {
        sink.stage(Stage::Head);
        match self.check.as_mut() {
            Some(check) => {
                // The refinement reads head+lr or the fused readout, or head (the check then
                // only reports).
                let input = match self.refine.0 {
                    Some((input @ (RefineInput::HeadLr | RefineInput::FusedCensusLr), _)) => input,
                    _ => RefineInput::Head,
                };
                let mut rows = OnePassRows {
                    sink: &mut *sink,
                    weights: &self.weights,
                    check,
                    census: self.census.as_mut(),
                    refine: Feed::of(&mut self.refine.0, io, input, Stage::Head),
                    checked: input != RefineInput::Head,
                };
                pair_step(stream, tokens, window, &mut rows)?;
            }
            None => {
                let mut rows = HeadRows {
                    sink: &mut *sink,
                    check: None,
                    refine: Feed::of(&mut self.refine.0, io, RefineInput::Head, Stage::Head),
                };
                pair_step(stream, tokens, window, &mut rows)?;
            }
        }
        self.refine.check()
    }
}

/// A band's head stream in the image: the token row its row 0 is, and the rows it passes on.
struct Window {
    first: usize,
    keep: core::ops::Range<usize>,
}

/// One step of a native head stream: the next pair token row, or (`None`) the end; only the
/// rows the `window` keeps go on to `rows`, numbered in the image.
fn pair_step(
    stream: &mut HeadStream<'_, '_>,
    tokens: Option<&[i8]>,
    window: &Window,
    rows: &mut impl head::HeadSink,
) -> Result<(), Error> {
    let mut kept = head::KeptRows {
        inner: rows,
        first: window.first,
        keep: window.keep.clone(),
    };
    match tokens {
        Some(tokens) => stream.push_pair_row(tokens, &mut kept),
        None => stream.finish(&mut kept),
    }
}
