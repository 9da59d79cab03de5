//! The native pathway: one encoder pass per band on the actual pair (L, R), its de-positioned
//! fused grid ([`Encoder::pair_tokens_in_place`]) read row by row by the native head. With
//! the head's left-right check a second pass encodes the mirrored pair (mirror R, mirror L),
//! read from the same pixel band without a copy ([`GrayBand::mirrored`]), and feeds the
//! mirrored head ([`HeadView::Right`]).
//!
//! Arena layout, in order: the two views' pixel band; with several bands the head streams (two
//! with the check); the left rows the check keeps; the refinement's state; then the encoder's
//! scratch, which after each pass holds the band's pair tokens at its front, with one band the
//! pass's head stream after them, then the refinement's row scratch. Each band is finished —
//! both passes, every head row they make computable — before the next is loaded.
//!
//! [`Encoder::pair_tokens_in_place`]: crate::model::encoder::Encoder::pair_tokens_in_place

use super::api::{Options, Refine, RefineInput, Report, RowSource, Sink, Stage};
use super::driver::Context;
use super::feeding::BandRows;
use super::head_check::{CheckedRows, Feed, HeadCheck, HeadRows};
use super::refine_stage;
use super::sizing::{band_pixel_rows, check_rows_bytes, max, refine_parts, sum};
use crate::band::{Band, BandPlan};
use crate::config::{BAND_TOKEN_ROWS, CELL_W, DIM, PATCH_H};
use crate::model::encoder::{self, GrayBand};
use crate::model::head::{self, HeadStream, HeadView};
use crate::model::ids::{HeadKind, HEAD_CONVS};
use crate::model::probe::NoProbe;
use crate::pipeline::refine_stage::{BandView, RefineIo, RefineStage};
use crate::Error;

/// Rows of left head disparities the check keeps: the left head runs one band's kept rows (at
/// most [`BAND_TOKEN_ROWS`]) ahead of the mirrored head, and after the last band's pass its
/// finish adds the rows its convolutions held back.
const CHECK_ROWS: usize = BAND_TOKEN_ROWS + HEAD_CONVS;

/// Arena bytes of the check's kept left rows and mask row (0 without the check), rounded up
/// to [`REGION_ALIGN`].
const fn check_bytes(cols: usize, head_lr: bool) -> usize {
    if head_lr {
        aligned(check_rows_bytes(cols, CHECK_ROWS))
    } else {
        0
    }
}

/// Alignment of every region's start: the encoder's scratch starts where the export pathway's
/// does, on a 16-byte boundary, so the assembly kernels' aligned paths apply (the M7's DSP
/// GEMMs fall back to the portable kernels on unaligned rows, half again as many instructions
/// for the whole pass).
const REGION_ALIGN: usize = 16;

/// `bytes` rounded up to [`REGION_ALIGN`] (saturating).
const fn aligned(bytes: usize) -> usize {
    match bytes.checked_add(REGION_ALIGN - 1) {
        Some(n) => n / REGION_ALIGN * REGION_ALIGN,
        None => usize::MAX,
    }
}

/// Arena bytes of a native run of a `height x width` pair (saturating, like every sizing helper).
///
/// One band (images up to 48 rows): each pass's head stream lives in the encoder's scratch
/// after the pass's tokens (the mirrored head after the second pass's), so only the check's
/// rows and the refinement's state sit outside it. Several bands: the head streams carry
/// state from band to band and sit outside the scratch, one per view.
pub(super) const fn arena_bytes(height: usize, width: usize, opts: &Options, refine: Option<&Refine>) -> usize {
    let head_lr = opts.head_lr;
    let band_rows = band_pixel_rows(height);
    let cols = width / CELL_W;
    let pixels = band_rows.saturating_mul(width).saturating_mul(2);
    let tokens = (band_rows / PATCH_H).saturating_mul(cols).saturating_mul(2 * DIM);
    let encoder = encoder::arena_bytes(band_rows, width);
    let head = aligned(head::arena_bytes_with(HeadKind::Native, cols, opts.head_candidates));
    let (state, scratch) = match refine {
        Some(r) => refine_parts(height, width, r),
        None => (0, 0),
    };
    let state = aligned(state);
    let check = check_bytes(cols, head_lr);
    if height <= band_rows {
        let after = sum(&[tokens, head, scratch]);
        sum(&[pixels, check, state, max(encoder, after)])
    } else {
        let heads = if head_lr { head.saturating_mul(2) } else { head };
        sum(&[
            pixels,
            heads,
            check,
            state,
            max(encoder, tokens.saturating_add(scratch)),
        ])
    }
}

/// Runs the native pathway over every band of `plan`; `ctx.head` holds the native head's
/// weights and the arena was checked against [`arena_bytes`].
pub(super) fn run(
    ctx: &Context<'_, '_>,
    source: &mut impl RowSource,
    plan: &BandPlan,
    arena: &mut [u8],
    sink: &mut impl Sink,
) -> Result<Report, Error> {
    let weights = ctx.head.ok_or(Error::MissingReadout { readout: "head" })?;
    let head_lr = ctx.head_lr();
    let streaming = plan.len() > 1;
    let (width, cols, band_px) = (ctx.width, ctx.cols, ctx.band_px);
    let pixel_len = band_px * width;
    let nd = ctx.opts.head_candidates;
    let head_len = aligned(head::arena_bytes_with(HeadKind::Native, cols, nd));
    let stream_len = match (streaming, head_lr) {
        (false, _) => 0,
        (true, false) => head_len,
        (true, true) => 2 * head_len,
    };
    let check_len = check_bytes(cols, head_lr);
    let state_len = aligned(match ctx.refine {
        Some(r) => refine_parts(ctx.height, width, r).0,
        None => 0,
    });
    let too_small = Error::ArenaTooSmall {
        needed: arena_bytes(ctx.height, width, ctx.opts, ctx.refine),
        available: arena.len(),
    };
    let (pixels, rest) = split(arena, 2 * pixel_len).ok_or(too_small)?;
    let (left_px, right_px) = pixels.split_at_mut(pixel_len);
    let (stream_arena, rest) = split(rest, stream_len).ok_or(too_small)?;
    let (check_arena, rest) = split(rest, check_len).ok_or(too_small)?;
    let (state_arena, scratch) = split(rest, state_len).ok_or(too_small)?;
    let mut readouts = Readouts::new(ctx, check_arena, state_arena, streaming)?;
    // Several bands: both streams for the whole run, outside the encoder's scratch.
    let mut streams = if streaming {
        let (left, mirror) = split(stream_arena, head_len).ok_or(too_small)?;
        let mirror = if head_lr {
            Some(HeadStream::with_candidates(weights, cols, nd, HeadView::Right, mirror)?)
        } else {
            None
        };
        Some((
            HeadStream::with_candidates(weights, cols, nd, HeadView::Left, left)?,
            mirror,
        ))
    } else {
        None
    };
    let mut rows = BandRows {
        source,
        width,
        first: 0,
        loaded: 0,
    };
    let mut report = Report {
        rows: ctx.height / PATCH_H,
        cols,
        bands: plan.len(),
        pixels: 2 * pixel_len,
        ..Report::default()
    };
    let (mut after_tokens, mut scratch_used) = (0, 0);
    for (i, band) in plan.iter().enumerate() {
        if i > 0 {
            // Rows the refinement still needs that the load drops go to its ring.
            readouts.keep_view_rows(&rows.view(left_px, right_px), band.start * PATCH_H, sink)?;
        }
        rows.load(band, left_px, right_px, sink)?;
        let last = i + 1 == plan.len();
        let left = GrayBand::new(left_px, width, band_px)?;
        let right = GrayBand::new(right_px, width, band_px)?;
        let passes = [
            (Stage::EncodePair, HeadView::Left, left, right),
            (Stage::EncodeMirror, HeadView::Right, right.mirrored(), left.mirrored()),
        ];
        for (stage, view, first, second) in passes.into_iter().take(if head_lr { 2 } else { 1 }) {
            sink.stage(stage);
            let encoder = &ctx.pipeline.encoder;
            let (pass, len) = encoder.pair_tokens_in_place(first, second, scratch, &mut NoProbe)?;
            report.encoder = report.encoder.max(pass.arena_used);
            let (tokens, rest) = split(scratch, len).ok_or(too_small)?;
            let tokens: &[i8] = bytemuck::cast_slice(tokens);
            if view == HeadView::Left {
                sink.pair_band(band, tokens);
            }
            let own_len = match streams.as_mut() {
                Some((left, mirror)) => {
                    let stream = match view {
                        HeadView::Left => left,
                        HeadView::Right => mirror.as_mut().ok_or(Error::MissingReadout { readout: "head+lr" })?,
                    };
                    let mut io = ctx.refine_io(rows.view(left_px, right_px), rest)?;
                    readouts.pass(stream, view, band, tokens, last, &mut io, sink)?;
                    scratch_used = scratch_used.max(io.scratch.used());
                    0
                }
                None => {
                    // One band: this pass's head stream after its tokens.
                    let (arena, rest) = split(rest, head_len).ok_or(too_small)?;
                    let mut stream = HeadStream::with_candidates(weights, cols, nd, view, arena)?;
                    let mut io = ctx.refine_io(rows.view(left_px, right_px), rest)?;
                    readouts.pass(&mut stream, view, band, tokens, last, &mut io, sink)?;
                    scratch_used = scratch_used.max(io.scratch.used());
                    head_len
                }
            };
            after_tokens = after_tokens.max(len + own_len);
        }
    }
    readouts.refine_done()?;
    report.streams = stream_len + readouts.check_used;
    report.refine = readouts.refine_used() + scratch_used;
    report.head_kept = readouts.check.as_ref().map_or(0, |check| check.kept);
    let fixed = report.pixels + stream_len + check_len + state_len;
    report.arena_used = fixed + report.encoder.max(after_tokens + scratch_used);
    Ok(report)
}

/// `arena` cut at `at`, or `None` when it is shorter.
fn split(arena: &mut [u8], at: usize) -> Option<(&mut [u8], &mut [u8])> {
    (at <= arena.len()).then(|| arena.split_at_mut(at))
}

/// What outlives a pass: the check's kept rows and mask (with `head_lr`) and the refinement.
struct Readouts<'a> {
    cols: usize,
    check: Option<HeadCheck<'a>>,
    check_used: usize,
    refine: Option<(RefineInput, RefineStage<'a>)>,
}

impl<'a> Readouts<'a> {
    fn new(ctx: &Context<'_, '_>, check: &'a mut [u8], state: &'a mut [u8], streaming: bool) -> Result<Self, Error> {
        let cols = ctx.cols;
        let (check, check_used) = if ctx.head_lr() {
            let (check, used) = HeadCheck::carve(check, cols, CHECK_ROWS, ctx.opts.lr_max_diff_q8)?;
            (Some(check), used)
        } else {
            (None, 0)
        };
        let refine = match ctx.refine {
            Some(r) => {
                let ring = if streaming {
                    refine_stage::ring_rows(r.reach(), r.input.lag())
                } else {
                    0
                };
                let stage = RefineStage::new(r.params, r.equalise, ctx.width, ctx.height, ring, state)?;
                Some((r.input, stage))
            }
            None => None,
        };
        Ok(Self {
            cols,
            check,
            check_used,
            refine,
        })
    }

    /// One pass's rows into `view`'s head `stream`, and its end after the last band's.
    #[allow(clippy::too_many_arguments)]
    fn pass(
        &mut self,
        stream: &mut HeadStream<'_, '_>,
        view: HeadView,
        band: Band,
        tokens: &[i8],
        last: bool,
        io: &mut RefineIo<'_>,
        sink: &mut impl Sink,
    ) -> Result<(), Error> {
        self.push_band(stream, view, band, tokens, io, sink)?;
        if last {
            self.step(stream, view, None, io, sink)?;
        }
        Ok(())
    }

    /// Feeds `view`'s head `stream` the token rows `band` keeps (`tokens`: the band's pair
    /// tokens of the pass for that view).
    fn push_band(
        &mut self,
        stream: &mut HeadStream<'_, '_>,
        view: HeadView,
        band: Band,
        tokens: &[i8],
        io: &mut RefineIo<'_>,
        sink: &mut impl Sink,
    ) -> Result<(), Error> {
        let row_len = self.cols * 2 * DIM;
        for row in band.keep_from..band.keep_to {
            let at = (row - band.start) * row_len;
            let Some(tokens) = tokens.get(at..at + row_len) else {
                return Err(Error::BufferSize {
                    what: "pair token band",
                    expected: (band.keep_to - band.start) * row_len,
                    found: tokens.len(),
                });
            };
            self.step(stream, view, Some(tokens), io, sink)?;
        }
        Ok(())
    }

    /// One row (or, `None`, the end) into `view`'s head `stream`; its output rows go to the
    /// sink, the check and the refinement.
    fn step(
        &mut self,
        stream: &mut HeadStream<'_, '_>,
        view: HeadView,
        tokens: Option<&[i8]>,
        io: &mut RefineIo<'_>,
        sink: &mut impl Sink,
    ) -> Result<(), Error> {
        sink.stage(match view {
            HeadView::Left => Stage::Head,
            HeadView::Right => Stage::HeadMirror,
        });
        match view {
            HeadView::Left => {
                let mut rows = HeadRows {
                    sink: &mut *sink,
                    check: self.check.as_mut(),
                    refine: Feed::of(&mut self.refine, io, RefineInput::Head, Stage::Head),
                };
                pair_step(stream, tokens, &mut rows)?;
            }
            HeadView::Right => {
                let Some(check) = self.check.as_mut() else {
                    return Ok(());
                };
                let mut rows = CheckedRows {
                    sink: &mut *sink,
                    check,
                    refine: Feed::of(&mut self.refine, io, RefineInput::HeadLr, Stage::HeadMirror),
                };
                pair_step(stream, tokens, &mut rows)?;
            }
        }
        self.refine.as_ref().map_or(Ok(()), |(_, stage)| stage.check())
    }

    /// Before a band load that drops the rows above `new_first`.
    fn keep_view_rows(&mut self, view: &BandView<'_>, new_first: usize, sink: &mut impl Sink) -> Result<(), Error> {
        let Some((_, stage)) = self.refine.as_mut() else {
            return Ok(());
        };
        sink.stage(Stage::Refine);
        stage.keep_before(view, new_first)
    }

    fn refine_used(&self) -> usize {
        self.refine.as_ref().map_or(0, |(_, stage)| stage.used())
    }

    fn refine_done(&self) -> Result<(), Error> {
        self.refine.as_ref().map_or(Ok(()), |(_, stage)| stage.done())
    }
}

/// One step of a native head stream: the next pair token row, or (`None`) the end.
fn pair_step(
    stream: &mut HeadStream<'_, '_>,
    tokens: Option<&[i8]>,
    rows: &mut impl head::HeadSink,
) -> Result<(), Error> {
    match tokens {
        Some(tokens) => stream.push_pair_row(tokens, rows),
        None => stream.finish(rows),
    }
}
