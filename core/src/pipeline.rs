//! The whole stereo pipeline in one caller-provided arena: image rows in, disparity rows out.
//!
//! Rows arrive top to bottom, as a sensor delivers them ([`RowSource`]), into a buffer of one
//! band (at most 48 rows) per view. Each band is encoded twice, on (L, L) and on (R, R) — the
//! descriptor pathway — and each token row it keeps (see [`crate::band`]) goes at once to
//! - the no-linkage readout: cosine WTA + parabola ([`crate::matching`]),
//! - streaming 4-path SGM on the same cosine costs ([`crate::sgm`]),
//! - the left-right check of both, from the reindexed cost row ([`crate::lr`]),
//! - the shared head, when asked for ([`crate::model::head`]).
//!
//! Memory depends on the band and the width, never on the image height. Arena layout, in
//! order: the two views' pixel band, the left descriptors of the band, then
//! - one band (images up to 48 rows): the encoder's scratch, reused after both passes for the
//!   right descriptors (written in place) and the readout streams;
//! - several bands: the readout streams (they carry state from band to band), then the
//!   encoder's scratch.

use crate::arena::{Carver, ALIGN_SLACK};
use crate::band::{Band, BandPlan};
use crate::config::{check_view_size, BAND_TOKEN_ROWS, CELL_W, DIM, PATCH_H};
use crate::lr::{consistent_row, right_view_costs, wta_costs};
use crate::matching::{check_candidates, cost_row, inverse_norms, match_row};
use crate::model::encoder::{self, Encoder, GrayBand};
use crate::model::head::{self, HeadRow, HeadSink, HeadStream, HeadView, HeadWeights};
use crate::model::ids::HEAD_CONVS;
use crate::model::probe::NoProbe;
use crate::sgm::{state_len, Penalties, SgmStream};
use crate::Error;

/// Where the pipeline is; a [`Sink`] hears of every change (firmware marks stages with it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// Reading image rows into the band buffer.
    Rows,
    /// The encoder on (L, L): left descriptors of a band.
    EncodeLeft,
    /// The encoder on (R, R): right descriptors of a band.
    EncodeRight,
    /// Inverse norms, the cosine cost row and the no-linkage WTA of one token row.
    Match,
    /// SGM aggregation of one token row, left and right views.
    Sgm,
    /// Right-view WTA and the left-right check of both readouts.
    LeftRight,
    /// The shared head on one descriptor row.
    Head,
}

impl Stage {
    /// Every stage, in pipeline order.
    pub const ALL: [Stage; 7] = [
        Stage::Rows,
        Stage::EncodeLeft,
        Stage::EncodeRight,
        Stage::Match,
        Stage::Sgm,
        Stage::LeftRight,
        Stage::Head,
    ];

    /// A short lower-case name (reports, firmware logs).
    pub const fn name(self) -> &'static str {
        match self {
            Stage::Rows => "rows",
            Stage::EncodeLeft => "encode_left",
            Stage::EncodeRight => "encode_right",
            Stage::Match => "match",
            Stage::Sgm => "sgm",
            Stage::LeftRight => "left_right",
            Stage::Head => "head",
        }
    }
}

/// Delivers a rectified pair row by row, top to bottom.
pub trait RowSource {
    /// Width of both views in pixels.
    fn width(&self) -> usize;
    /// Height of both views in pixels.
    fn height(&self) -> usize;
    /// Writes the next row of each view (gray, `width` bytes) into `left` and `right`.
    fn next_row(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), Error>;
}

/// A pair already in memory (row-major gray pixels) as a [`RowSource`].
#[derive(Debug, Clone, Copy)]
pub struct SlicePair<'a> {
    left: &'a [u8],
    right: &'a [u8],
    width: usize,
    height: usize,
    next: usize,
}

impl<'a> SlicePair<'a> {
    /// A pair of `width x height` views; both must hold exactly that many pixels.
    pub fn new(left: &'a [u8], right: &'a [u8], width: usize, height: usize) -> Result<Self, Error> {
        if left.len() != right.len() {
            return Err(Error::PairMismatch);
        }
        let expected = width.saturating_mul(height);
        if left.len() != expected {
            return Err(Error::BufferSize {
                what: "view pixels",
                expected,
                found: left.len(),
            });
        }
        Ok(Self {
            left,
            right,
            width,
            height,
            next: 0,
        })
    }
}

impl RowSource for SlicePair<'_> {
    fn width(&self) -> usize {
        self.width
    }

    fn height(&self) -> usize {
        self.height
    }

    fn next_row(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), Error> {
        let range = self.next * self.width..(self.next + 1) * self.width;
        let (Some(l), Some(r)) = (self.left.get(range.clone()), self.right.get(range)) else {
            return Err(Error::BufferSize {
                what: "view rows",
                expected: self.height,
                found: self.next,
            });
        };
        for (out, src) in [(left, l), (right, r)] {
            if out.len() != src.len() {
                return Err(Error::BufferSize {
                    what: "row buffer",
                    expected: src.len(),
                    found: out.len(),
                });
            }
            out.copy_from_slice(src);
        }
        self.next += 1;
        Ok(())
    }
}

/// What the readouts use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Options {
    /// Disparity candidates of the WTA and SGM readouts, in patch columns (1 to 64).
    pub max_cols: usize,
    /// SGM penalties (cost units: 4096 = cosine 1).
    pub penalties: Penalties,
    /// Left-right check tolerance, Q8 patch columns.
    pub lr_max_diff_q8: u16,
    /// Run the shared head too.
    pub head: bool,
    /// With `head`: run it on the mirrored pair as well, for the head's own left-right check
    /// ([`Sink::head_checked`]); a second head stream, so the arena is
    /// [`arena_bytes_head_lr`]. Ignored without `head`.
    pub head_lr: bool,
}

/// One token row of the matching readouts.
#[derive(Debug, Clone, Copy)]
pub struct MatchedRow<'r> {
    /// Token row of the image.
    pub row: usize,
    /// No-linkage disparity per patch column, Q8 patch columns.
    pub wta_q8: &'r [u16],
    /// SGM disparity per patch column, Q8 patch columns.
    pub sgm_q8: &'r [u16],
    /// 1 where the WTA disparity passes the left-right check, else 0.
    pub wta_consistent: &'r [u8],
    /// 1 where the SGM disparity passes the left-right check, else 0.
    pub sgm_consistent: &'r [u8],
}

/// The head's left-right check of one token row: the right view's head disparity (the head on
/// the mirrored pair) and which left cells it confirms.
#[derive(Debug, Clone, Copy)]
pub struct HeadChecked<'r> {
    /// Token row.
    pub row: usize,
    /// The right view's head disparity per patch column, Q8 patch columns.
    pub right_q8: &'r [u16],
    /// 1 where the left head disparity (the [`Sink::head`] row of the same index) passes the
    /// left-right check, else 0.
    pub consistent: &'r [u8],
}

/// Receives what the pipeline produces, in order.
pub trait Sink {
    /// The pipeline enters `stage`.
    fn stage(&mut self, stage: Stage) {
        let _ = stage;
    }
    /// Both descriptor maps of a band (`band.rows x cols x DIM` codes each), after encoding.
    fn band(&mut self, band: Band, left: &[i8], right: &[i8]) {
        let _ = (band, left, right);
    }
    /// One token row of the WTA and SGM readouts, top to bottom.
    fn matched(&mut self, row: &MatchedRow<'_>);
    /// One token row of the head, top to bottom (a few rows behind the matching).
    fn head(&mut self, row: HeadRow<'_>) {
        let _ = row;
    }
    /// With [`Options::head_lr`]: the head's left-right check of a row, after its
    /// [`Sink::head`] row.
    fn head_checked(&mut self, row: &HeadChecked<'_>) {
        let _ = row;
    }
}

/// What a run used and kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Report {
    /// Token rows of the image.
    pub rows: usize,
    /// Patch columns.
    pub cols: usize,
    /// Bands encoded.
    pub bands: usize,
    /// Arena bytes used in all (the high-water mark).
    pub arena_used: usize,
    /// Of which: the pixel band of both views.
    pub pixels: usize,
    /// Of which: one descriptor band (the left one; the right one lives in the encoder's
    /// scratch).
    pub descriptors: usize,
    /// Of which: the encoder's scratch, high-water of one pass.
    pub encoder: usize,
    /// Of which: the readout streams (matching, SGM, left-right, head).
    pub streams: usize,
    /// Cells whose WTA disparity passed the left-right check.
    pub wta_kept: usize,
    /// Cells whose SGM disparity passed the left-right check.
    pub sgm_kept: usize,
    /// Cells whose head disparity passed the head's left-right check ([`Options::head_lr`]).
    pub head_kept: usize,
}

const fn max(a: usize, b: usize) -> usize {
    if a > b {
        a
    } else {
        b
    }
}

/// Pixel rows of the band buffer for an image of `height` rows.
const fn band_pixel_rows(height: usize) -> usize {
    let token_rows = height / PATCH_H;
    let rows = if token_rows < BAND_TOKEN_ROWS {
        token_rows
    } else {
        BAND_TOKEN_ROWS
    };
    rows * PATCH_H
}

/// Arena bytes of the matching, SGM and left-right state for `cols` patch columns
/// (saturating, like every sizing helper here).
const fn matching_bytes(cols: usize, max_cols: usize) -> usize {
    let volume_row = state_len(cols, max_cols);
    let words = cols.saturating_mul(4).saturating_add(ALIGN_SLACK); // one u32 row
    let halves = volume_row.saturating_mul(2).saturating_add(1); // one u16 cost row
    let sums = volume_row.saturating_mul(4).saturating_add(ALIGN_SLACK); // one u32 cost row
    let disparity = cols.saturating_mul(2).saturating_add(1); // one u16 disparity row
    sum(&[
        words.saturating_mul(2),                                         // inverse norms, left and right
        halves.saturating_mul(2),                                        // cost rows, left and right view
        halves.saturating_mul(2).saturating_add(sums).saturating_mul(2), // two SGM streams
        disparity.saturating_mul(4),                                     // WTA and SGM rows, both views
        cols.saturating_mul(2),                                          // left-right masks
    ])
}

/// Saturating sum (a `const fn` cannot use `Iterator::sum`).
const fn sum(terms: &[usize]) -> usize {
    let mut total = 0usize;
    let mut i = 0;
    while i < terms.len() {
        total = total.saturating_add(terms[i]);
        i += 1;
    }
    total
}

/// Rows of left head disparities kept for the check: a whole band (one band: the mirrored
/// head runs after the left one, on the same arena), or more than the mirrored head trails
/// the left one by when both stream side by side (several bands: one row per convolution).
const HEAD_CHECK_ROWS: usize = max(BAND_TOKEN_ROWS, HEAD_CONVS + 1);

/// Arena bytes of the head's left-right check: the left rows kept, one mask row, and for
/// several bands (`streaming`) the mirrored head's own stream.
const fn head_check_bytes(cols: usize, streaming: bool) -> usize {
    let mirror = if streaming { head::arena_bytes(cols) } else { 0 };
    sum(&[mirror, cols.saturating_mul(2 * HEAD_CHECK_ROWS).saturating_add(1), cols])
}

/// Arena bytes of the readout streams (with the head, and its check when `head_lr`; the check
/// needs a second head stream only when `streaming` several bands).
const fn stream_bytes(cols: usize, max_cols: usize, head_lr: bool, streaming: bool) -> usize {
    let check = if head_lr { head_check_bytes(cols, streaming) } else { 0 };
    sum(&[matching_bytes(cols, max_cols), head::arena_bytes(cols), check])
}

/// Arena bytes the pipeline needs for a `height x width` pair with `max_cols` candidates
/// (the head included). Firmware sizes its static arena with it.
///
/// Saturates at `usize::MAX` where the size does not fit a `usize` (absurd widths or candidate
/// counts): no arena is that large, so [`Pipeline::run`] rejects such a run as
/// [`Error::ArenaTooSmall`] (or earlier, as [`Error::TooWide`] / [`Error::Candidates`]); the
/// result is never a small wrong size.
pub const fn arena_bytes(height: usize, width: usize, max_cols: usize) -> usize {
    arena_bytes_of(height, width, max_cols, false)
}

/// [`arena_bytes`] with the head's left-right check ([`Options::head_lr`]): a second head
/// stream.
pub const fn arena_bytes_head_lr(height: usize, width: usize, max_cols: usize) -> usize {
    arena_bytes_of(height, width, max_cols, true)
}

/// The arena bytes a run with `opts` needs ([`arena_bytes`] or [`arena_bytes_head_lr`]).
pub const fn arena_bytes_for(height: usize, width: usize, opts: &Options) -> usize {
    arena_bytes_of(height, width, opts.max_cols, opts.head && opts.head_lr)
}

const fn arena_bytes_of(height: usize, width: usize, max_cols: usize, head_lr: bool) -> usize {
    let band_rows = band_pixel_rows(height);
    let cols = width / CELL_W;
    let pixels = band_rows.saturating_mul(width).saturating_mul(2);
    let descriptors = (band_rows / PATCH_H).saturating_mul(cols).saturating_mul(DIM);
    let encoder = encoder::arena_bytes(band_rows, width);
    if height <= band_rows {
        let streams = stream_bytes(cols, max_cols, head_lr, false);
        sum(&[pixels, descriptors, max(encoder, descriptors.saturating_add(streams))])
    } else {
        let streams = stream_bytes(cols, max_cols, head_lr, true);
        sum(&[pixels, descriptors, streams, encoder])
    }
}

/// The int8 encoder and (optionally) head over one weight blob.
#[derive(Clone, Copy)]
pub struct Pipeline<'w> {
    encoder: Encoder<'w>,
    head: Option<HeadWeights<'w>>,
}

impl<'w> Pipeline<'w> {
    /// The pipeline of a blob; `head` is `None` when the blob has no head tensors.
    pub fn new(blob: crate::blob::Blob<'w>) -> Result<Self, Error> {
        Ok(Self {
            encoder: Encoder::new(blob)?,
            head: HeadWeights::new(blob).ok(),
        })
    }

    /// Whether the blob carries the shared head.
    pub fn has_head(&self) -> bool {
        self.head.is_some()
    }

    /// Runs the pair `source` delivers through every readout, in `arena`.
    pub fn run(
        &self,
        source: &mut impl RowSource,
        opts: &Options,
        arena: &mut [u8],
        sink: &mut impl Sink,
    ) -> Result<Report, Error> {
        let (width, height) = (source.width(), source.height());
        let (token_rows, cols) = check_view_size(height, width)?;
        if width > self.encoder.max_width() {
            return Err(Error::TooWide {
                width,
                max: self.encoder.max_width(),
            });
        }
        check_candidates(opts.max_cols)?;
        let head = match (opts.head, self.head) {
            (true, Some(w)) => Some(w),
            (true, None) => return Err(Error::Blob(crate::blob::BlobError::MissingTensor { id: head_id() })),
            (false, _) => None,
        };
        let needed = arena_bytes_for(height, width, opts);
        if arena.len() < needed {
            return Err(Error::ArenaTooSmall {
                needed,
                available: arena.len(),
            });
        }
        let plan = BandPlan::new(token_rows)?;
        let band_px = band_pixel_rows(height);
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
        let ctx = Context {
            pipeline: self,
            head,
            opts,
            cols,
            width,
            band_px,
        };
        if plan.len() == 1 {
            let band = plan.get(0).ok_or(Error::EmptyImage)?;
            rows.load(band, left_px, right_px, sink)?;
            let (encoder_used, right_desc, rest) = ctx.encode(left_px, right_px, desc_left, scratch, sink)?;
            sink.band(band, desc_left, right_desc);
            let mut streams = Streams::new(&ctx, rest, false)?;
            streams.push_band(band, desc_left, right_desc, sink)?;
            streams.finish(sink)?;
            // The whole map is here: the mirrored head reruns the band on the left head's arena.
            streams.check_head_band(band, desc_left, right_desc, sink)?;
            report.encoder = encoder_used;
            report.streams = streams.used;
            (report.wta_kept, report.sgm_kept) = (streams.wta_kept, streams.sgm_kept);
            report.head_kept = streams.head_kept();
            report.arena_used = report.pixels + desc_len + max(encoder_used, desc_len + streams.used);
        } else {
            let stream_len = stream_bytes(cols, opts.max_cols, ctx.head_lr(), true);
            let (stream_arena, scratch) = scratch.split_at_mut(stream_len);
            let mut streams = Streams::new(&ctx, stream_arena, true)?;
            for band in plan.iter() {
                rows.load(band, left_px, right_px, sink)?;
                let (encoder_used, right_desc, _) = ctx.encode(left_px, right_px, desc_left, scratch, sink)?;
                sink.band(band, desc_left, right_desc);
                streams.push_band(band, desc_left, right_desc, sink)?;
                report.encoder = report.encoder.max(encoder_used);
            }
            streams.finish(sink)?;
            report.streams = streams.used;
            (report.wta_kept, report.sgm_kept) = (streams.wta_kept, streams.sgm_kept);
            report.head_kept = streams.head_kept();
            report.arena_used = report.pixels + desc_len + stream_len + report.encoder;
        }
        Ok(report)
    }
}

/// Any head tensor id, for the error of a head asked of a blob without one.
fn head_id() -> crate::blob::TensorId {
    crate::model::ids::id(crate::model::ids::kind::LAYERNORM, crate::model::ids::HEAD_LAYERNORM)
}

/// What the stages of one run share.
struct Context<'p, 'w> {
    pipeline: &'p Pipeline<'w>,
    head: Option<HeadWeights<'w>>,
    opts: &'p Options,
    cols: usize,
    width: usize,
    band_px: usize,
}

impl Context<'_, '_> {
    /// Whether this run checks the head left against right.
    fn head_lr(&self) -> bool {
        self.head.is_some() && self.opts.head_lr
    }

    /// Both encoder passes over the band in the pixel buffers: the left descriptors are copied
    /// to `desc_left`, the right ones stay at the front of `scratch`. Returns the encoder's
    /// high-water, the right descriptors and the rest of `scratch`.
    fn encode<'s>(
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
        if codes.len() != desc_left.len() {
            return Err(Error::BufferSize {
                what: "descriptor band",
                expected: desc_left.len(),
                found: codes.len(),
            });
        }
        desc_left.copy_from_slice(codes);
        sink.stage(Stage::EncodeRight);
        let view = GrayBand::new(right_px, self.width, self.band_px)?;
        let (right_report, len) = encoder.describe_in_place(view, scratch, &mut NoProbe)?;
        let (right, rest) = scratch.split_at_mut(len);
        let used = left_report.arena_used.max(right_report.arena_used);
        Ok((used, bytemuck::cast_slice(right), rest))
    }
}

/// The band buffer, filled from a [`RowSource`] as bands advance.
struct BandRows<'s, S> {
    source: &'s mut S,
    width: usize,
    /// Image row held in buffer row 0.
    first: usize,
    /// Image rows read so far.
    loaded: usize,
}

impl<S: RowSource> BandRows<'_, S> {
    /// Makes the buffers hold `band`'s pixel rows: keeps the overlap with the previous band,
    /// reads the rest.
    fn load(&mut self, band: Band, left: &mut [u8], right: &mut [u8], sink: &mut impl Sink) -> Result<(), Error> {
        sink.stage(Stage::Rows);
        let (start, end) = (band.start * PATCH_H, (band.start + band.rows) * PATCH_H);
        let w = self.width;
        if start > self.first {
            let drop = (start - self.first).min(self.loaded - self.first);
            let keep = self.loaded - self.first - drop;
            for view in [&mut *left, &mut *right] {
                view.copy_within(drop * w..(drop + keep) * w, 0);
            }
            self.first = start;
        }
        while self.loaded < end {
            let at = (self.loaded - self.first) * w;
            let (Some(l), Some(r)) = (left.get_mut(at..at + w), right.get_mut(at..at + w)) else {
                return Err(Error::BufferSize {
                    what: "band buffer",
                    expected: end - self.first,
                    found: left.len() / w.max(1),
                });
            };
            self.source.next_row(l, r)?;
            self.loaded += 1;
        }
        Ok(())
    }
}

/// Forwards the left head's rows to the pipeline's sink, keeping their disparities for the
/// check when there is one.
struct HeadRows<'k, 'c, 'a, K> {
    sink: &'k mut K,
    check: Option<&'c mut HeadCheck<'a>>,
}

impl<K: Sink> HeadSink for HeadRows<'_, '_, '_, K> {
    fn row(&mut self, row: HeadRow<'_>) {
        if let Some(check) = self.check.as_deref_mut() {
            check.keep_left(row.row, row.disparity_q8);
        }
        self.sink.head(row);
    }
}

/// The head's left-right check: the left rows kept for it, its mask row, what it kept.
struct HeadCheck<'a> {
    cols: usize,
    lr_max_diff_q8: u16,
    /// [`HEAD_CHECK_ROWS`] rows of left disparities, row `r` in slot `r % HEAD_CHECK_ROWS`
    /// (one band: every row of it, so the mirrored head can run afterwards).
    left_rows: &'a mut [u16],
    mask: &'a mut [u8],
    kept: usize,
}

impl HeadCheck<'_> {
    fn slot(&mut self, row: usize) -> Option<&mut [u16]> {
        let at = (row % HEAD_CHECK_ROWS) * self.cols;
        self.left_rows.get_mut(at..at + self.cols)
    }

    fn keep_left(&mut self, row: usize, disparity_q8: &[u16]) {
        if let Some(slot) = self.slot(row) {
            if slot.len() == disparity_q8.len() {
                slot.copy_from_slice(disparity_q8);
            }
        }
    }
}

/// Checks the mirrored head's rows against the left rows kept for them.
struct CheckedRows<'k, 'c, 'a, K> {
    sink: &'k mut K,
    check: &'c mut HeadCheck<'a>,
}

impl<K: Sink> HeadSink for CheckedRows<'_, '_, '_, K> {
    fn row(&mut self, row: HeadRow<'_>) {
        let check = &mut *self.check;
        let tolerance = check.lr_max_diff_q8;
        let at = (row.row % HEAD_CHECK_ROWS) * check.cols;
        let Some(left) = check.left_rows.get(at..at + check.cols) else {
            return;
        };
        // Equal lengths by construction (both streams are `cols` wide); a mismatch emits nothing.
        let Ok(kept) = consistent_row(left, row.disparity_q8, tolerance, check.mask) else {
            return;
        };
        check.kept += kept;
        self.sink.head_checked(&HeadChecked {
            row: row.row,
            right_q8: row.disparity_q8,
            consistent: check.mask,
        });
    }
}

/// The readouts' state: one token row of buffers plus SGM's and the head's carried state.
struct Streams<'a, 'w> {
    cols: usize,
    max_cols: usize,
    lr_max_diff_q8: u16,
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
    head: Option<HeadStream<'a, 'w>>,
    /// With `head_lr`: the mirrored head and the check.
    check: Option<(Option<HeadStream<'a, 'w>>, HeadCheck<'a>)>,
    used: usize,
    wta_kept: usize,
    sgm_kept: usize,
}

impl<'a, 'w> Streams<'a, 'w> {
    /// The streams of a run; `streaming`: several bands, so the head's check (if any) streams
    /// a mirrored head beside the left one instead of rerunning the band after it.
    fn new(ctx: &Context<'_, 'w>, arena: &'a mut [u8], streaming: bool) -> Result<Self, Error> {
        let (cols, max_cols) = (ctx.cols, ctx.opts.max_cols);
        let volume_row = state_len(cols, max_cols);
        let matching = matching_bytes(cols, max_cols);
        let (matching_arena, head_arena) = arena.split_at_mut(matching.min(arena.len()));
        let mut carver = Carver::new(matching_arena, matching)?;
        let inv_left = carver.u32s(cols)?;
        let inv_right = carver.u32s(cols)?;
        let cost = carver.u16s(volume_row)?;
        let cost_right = carver.u16s(volume_row)?;
        let sgm = SgmStream::new(
            cols,
            max_cols,
            ctx.opts.penalties,
            carver.u16s(volume_row)?,
            carver.u16s(volume_row)?,
            carver.u32s(volume_row)?,
        )?;
        let sgm_right = SgmStream::new(
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
        let mut used = carver.used();
        let (head, check) = match ctx.head {
            Some(w) => {
                let (left_arena, check_arena) = head_arena.split_at_mut(head::arena_bytes(cols).min(head_arena.len()));
                let stream = HeadStream::new(w, cols, left_arena)?;
                used = matching + stream.arena_used();
                let check = if ctx.head_lr() {
                    let (mirror, rest) = if streaming {
                        let len = head::arena_bytes(cols).min(check_arena.len());
                        let (mirror_arena, rest) = check_arena.split_at_mut(len);
                        let mirror = HeadStream::for_view(w, cols, HeadView::Right, mirror_arena)?;
                        used += mirror.arena_used();
                        (Some(mirror), rest)
                    } else {
                        (None, check_arena)
                    };
                    let mut carver = Carver::new(rest, head_check_bytes(cols, false))?;
                    let check = HeadCheck {
                        cols,
                        lr_max_diff_q8: ctx.opts.lr_max_diff_q8,
                        left_rows: carver.u16s(cols * HEAD_CHECK_ROWS)?,
                        mask: carver.u8s(cols)?,
                        kept: 0,
                    };
                    used += carver.used();
                    Some((mirror, check))
                } else {
                    None
                };
                (Some(stream), check)
            }
            None => (None, None),
        };
        Ok(Self {
            cols,
            max_cols,
            lr_max_diff_q8: ctx.opts.lr_max_diff_q8,
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
            head,
            check,
            used,
            wta_kept: 0,
            sgm_kept: 0,
        })
    }

    /// Cells the head's left-right check kept (0 without it).
    fn head_kept(&self) -> usize {
        self.check.as_ref().map_or(0, |(_, check)| check.kept)
    }

    /// Feeds the rows `band` keeps.
    fn push_band(&mut self, band: Band, left: &[i8], right: &[i8], sink: &mut impl Sink) -> Result<(), Error> {
        for row in band.keep_from..band.keep_to {
            let (l, r) = kept_row(band, row, self.cols, left, right)?;
            self.push_row(row, l, r, sink)?;
        }
        Ok(())
    }

    fn push_row(&mut self, row: usize, left: &[i8], right: &[i8], sink: &mut impl Sink) -> Result<(), Error> {
        let mc = self.max_cols;
        sink.stage(Stage::Match);
        inverse_norms(left, self.inv_left)?;
        inverse_norms(right, self.inv_right)?;
        match_row(left, right, self.inv_right, mc, self.wta)?;
        cost_row(left, right, self.inv_left, self.inv_right, mc, self.cost)?;
        right_view_costs(self.cost, mc, self.cost_right)?;
        sink.stage(Stage::Sgm);
        self.sgm.push_row(self.cost, self.sgm_out)?;
        self.sgm_right.push_row(self.cost_right, self.sgm_right_out)?;
        sink.stage(Stage::LeftRight);
        wta_costs(self.cost_right, mc, self.wta_right)?;
        self.wta_kept += consistent_row(self.wta, self.wta_right, self.lr_max_diff_q8, self.wta_mask)?;
        self.sgm_kept += consistent_row(self.sgm_out, self.sgm_right_out, self.lr_max_diff_q8, self.sgm_mask)?;
        sink.matched(&MatchedRow {
            row,
            wta_q8: self.wta,
            sgm_q8: self.sgm_out,
            wta_consistent: self.wta_mask,
            sgm_consistent: self.sgm_mask,
        });
        if let Some(head) = self.head.as_mut() {
            sink.stage(Stage::Head);
            match self.check.as_mut() {
                Some((mirror, check)) => {
                    head.push_row(
                        left,
                        right,
                        &mut HeadRows {
                            sink,
                            check: Some(check),
                        },
                    )?;
                    if let Some(mirror) = mirror {
                        mirror.push_row(left, right, &mut CheckedRows { sink, check })?;
                    }
                }
                None => head.push_row(left, right, &mut HeadRows { sink, check: None })?,
            }
        }
        Ok(())
    }

    fn finish(&mut self, sink: &mut impl Sink) -> Result<(), Error> {
        if let Some(head) = self.head.as_mut() {
            sink.stage(Stage::Head);
            match self.check.as_mut() {
                Some((mirror, check)) => {
                    head.finish(&mut HeadRows {
                        sink,
                        check: Some(check),
                    })?;
                    if let Some(mirror) = mirror {
                        mirror.finish(&mut CheckedRows { sink, check })?;
                    }
                }
                None => head.finish(&mut HeadRows { sink, check: None })?,
            }
        }
        Ok(())
    }

    /// One band, after [`Streams::finish`]: the mirrored head over the band's rows on the left
    /// head's arena, checked against the left rows it kept (a no-op unless the check is on and
    /// not already streamed).
    fn check_head_band(&mut self, band: Band, left: &[i8], right: &[i8], sink: &mut impl Sink) -> Result<(), Error> {
        let (Some(head), Some((None, check))) = (self.head.as_mut(), self.check.as_mut()) else {
            return Ok(());
        };
        sink.stage(Stage::Head);
        head.restart(HeadView::Right);
        for row in band.keep_from..band.keep_to {
            let (l, r) = kept_row(band, row, self.cols, left, right)?;
            head.push_row(l, r, &mut CheckedRows { sink, check })?;
        }
        head.finish(&mut CheckedRows { sink, check })
    }
}

/// Token row `row` of both descriptor maps of `band` (`cols x DIM` codes each).
fn kept_row<'d>(
    band: Band,
    row: usize,
    cols: usize,
    left: &'d [i8],
    right: &'d [i8],
) -> Result<(&'d [i8], &'d [i8]), Error> {
    let row_len = cols * DIM;
    let at = (row - band.start) * row_len;
    match (left.get(at..at + row_len), right.get(at..at + row_len)) {
        (Some(l), Some(r)) => Ok((l, r)),
        _ => Err(Error::BufferSize {
            what: "descriptor band",
            expected: (band.keep_to - band.start) * row_len,
            found: left.len().min(right.len()),
        }),
    }
}
