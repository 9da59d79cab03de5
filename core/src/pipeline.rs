//! The whole stereo pipeline in one caller-provided arena: image rows in, disparity rows out.
//!
//! Rows arrive top to bottom, as a sensor delivers them ([`RowSource`]), into a buffer of one
//! band (at most 48 rows) per view. Each band is encoded twice, on (L, L) and on (R, R) — the
//! descriptor pathway — and each token row it keeps (see [`crate::band`]) goes at once to
//! - the no-linkage readout: cosine WTA + parabola ([`crate::matching`]),
//! - streaming 4-path SGM on the same cosine costs ([`crate::sgm`]),
//! - the left-right check of both, from the reindexed cost row ([`crate::lr`]),
//! - the shared head, when asked for ([`crate::model::head`]);
//!
//! and, with [`Pipeline::run_refined`], one readout's token rows go on to the pixel
//! refinement ([`crate::refine`]), which emits pixel rows ([`Sink::refined`]).
//!
//! Memory depends on the band and the width, never on the image height. Arena layout, in
//! order: the two views' pixel band, the left descriptors of the band, then
//! - one band (images up to 48 rows): the encoder's scratch, reused after both passes for the
//!   right descriptors (written in place), the readout streams and the refinement's state and
//!   row scratch;
//! - several bands: the readout streams and the refinement's state (they carry state from band
//!   to band), then the encoder's scratch, which between passes holds the right descriptors and
//!   the refinement's row scratch.
//!
//! # The refinement
//! [`Refine`] names the readout whose token grid is refined ([`RefineInput`]; the rule of
//! [`Refine::for_options`]: head+lr when the run checks the head, else sgm+lr), the
//! parameters and whether the views' sharpness is equalised first (on in every preset). A `+lr`
//! input is the readout's row filled by its own left-right check ([`crate::lr::fill_rejected`],
//! as the host fills), so the pixel rows equal
//! [`crate::refine::sharpness::refine_map_equalised`] (or, without equalisation,
//! [`crate::refine::refine_map`]) on the filled token map. The stage reads the view rows from the
//! band buffer; only the head's rows, which trail the band by six token rows, need a small
//! ring of view rows with several bands (see `refine_stage.rs`). For a 48x160 band pair the
//! arena does not grow: the refinement fits beside the streams in the encoder's scratch.

use crate::arena::{Carver, ALIGN_SLACK};
use crate::band::{Band, BandPlan};
use crate::config::{check_view_size, BAND_TOKEN_ROWS, CELL_W, DIM, PATCH_H};
use crate::lr::{consistent_row, right_view_costs, wta_costs};
use crate::matching::{check_candidates, cost_row, inverse_norms, match_row};
use crate::model::encoder::{self, Encoder, GrayBand};
use crate::model::head::{self, HeadRow, HeadSink, HeadStream, HeadView, HeadWeights};
use crate::model::ids::{HeadKind, HEAD_CONVS};
use crate::model::probe::NoProbe;
use crate::refine::RefineParams;
use crate::sgm::{cell_guide, state_len, Penalties, SgmStream};
use crate::Error;

mod native;
mod refine_stage;

use refine_stage::{BandView, RefineIo, RefineStage, Scratch, HEAD_LAG};

/// Where the pipeline is; a [`Sink`] hears of every change (firmware marks stages with it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
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
    /// The pixel refinement of the rows one token row made computable (and the copy of view
    /// rows it still needs before a band load).
    Refine,
    /// Native pathway: the encoder on (L, R), the band's pair tokens.
    EncodePair,
    /// Native pathway with the head's left-right check: the encoder on the mirrored pair.
    EncodeMirror,
    /// Native pathway with the head's left-right check: the native head on the mirrored pair's
    /// tokens (the export pathway's mirrored head runs in [`Stage::Head`]).
    HeadMirror,
}

impl Stage {
    /// Every stage, in pipeline order.
    pub const ALL: [Stage; 11] = [
        Stage::Rows,
        Stage::EncodeLeft,
        Stage::EncodeRight,
        Stage::Match,
        Stage::Sgm,
        Stage::LeftRight,
        Stage::Head,
        Stage::Refine,
        Stage::EncodePair,
        Stage::EncodeMirror,
        Stage::HeadMirror,
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
            Stage::Refine => "refine",
            Stage::EncodePair => "encode_pair",
            Stage::EncodeMirror => "encode_mirror",
            Stage::HeadMirror => "head_mirror",
        }
    }

    /// Whether the stage runs the encoder.
    pub const fn encodes(self) -> bool {
        matches!(
            self,
            Stage::EncodeLeft | Stage::EncodeRight | Stage::EncodePair | Stage::EncodeMirror
        )
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
        Error::check_len("view pixels", expected, left.len())?;
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
            Error::check_len("row buffer", src.len(), out.len())?;
            out.copy_from_slice(src);
        }
        self.next += 1;
        Ok(())
    }
}

/// How a band reaches the readouts: the export pathway (two encoder passes, on (L, L) and
/// (R, R), descriptor maps for every readout) or the native one (one pass on (L, R), its fused
/// grid read by the native head only).
pub type Pathway = HeadKind;

/// What the readouts use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Options {
    /// [`Pathway::Export`]: every readout (no-linkage WTA, SGM, their checks, the shared head
    /// when `head`). [`Pathway::Native`]: the native head alone (`head` is implied; `max_cols`
    /// and `penalties` are unused), with its check when `head_lr`, which costs a second encoder
    /// pass per band on the mirrored pair.
    pub pathway: Pathway,
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
    /// Disparity candidates of the head (either pathway), in patch columns (1 to
    /// [`HEAD_CANDIDATES_LIMIT`](crate::config::HEAD_CANDIDATES_LIMIT)):
    /// [`HEAD_MAX_DISP`](crate::config::HEAD_MAX_DISP), the count it was trained with, or more
    /// for wide views whose disparities reach further ([`HeadStream::with_candidates`]).
    pub head_candidates: usize,
}

/// The readout whose token grid the refinement reads, named as the host names readouts. A
/// `+lr` input is the readout's disparity with the cells its left-right check rejects filled
/// ([`crate::lr::fill_rejected`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RefineInput {
    /// No-linkage WTA.
    Nolink,
    /// No-linkage WTA, filled by its left-right check.
    NolinkLr,
    /// SGM.
    Sgm,
    /// SGM, filled by its left-right check.
    SgmLr,
    /// The shared head (needs [`Options::head`]).
    Head,
    /// The shared head, filled by its own left-right check (needs [`Options::head`] and
    /// [`Options::head_lr`]).
    HeadLr,
}

impl RefineInput {
    /// The rule: [`RefineInput::HeadLr`] when the run checks the head ([`Options::head`] and
    /// [`Options::head_lr`]), else [`RefineInput::SgmLr`] — the best readout each run has
    /// (README: head+lr at w160, sgm+lr the default of `bino run`).
    /// The native pathway has only its head: head+lr with the check, else head.
    pub const fn for_options(opts: &Options) -> Self {
        match opts.pathway {
            Pathway::Native if opts.head_lr => RefineInput::HeadLr,
            Pathway::Native => RefineInput::Head,
            Pathway::Export if opts.head && opts.head_lr => RefineInput::HeadLr,
            Pathway::Export => RefineInput::SgmLr,
        }
    }

    /// The host's name of the readout (`sgm+lr`, ...).
    pub const fn name(self) -> &'static str {
        match self {
            RefineInput::Nolink => "nolink",
            RefineInput::NolinkLr => "nolink+lr",
            RefineInput::Sgm => "sgm",
            RefineInput::SgmLr => "sgm+lr",
            RefineInput::Head => "head",
            RefineInput::HeadLr => "head+lr",
        }
    }

    /// Whether it is one of the head's.
    pub const fn uses_head(self) -> bool {
        matches!(self, RefineInput::Head | RefineInput::HeadLr)
    }

    /// Token rows its rows trail the band's kept rows by.
    const fn lag(self) -> usize {
        if self.uses_head() {
            HEAD_LAG
        } else {
            0
        }
    }
}

/// The pixel refinement as a pipeline stage: which readout it refines, with which parameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Refine {
    /// The readout whose token grid is refined.
    pub input: RefineInput,
    /// The refinement's parameters.
    pub params: RefineParams,
    /// Sharpness equalisation of the views before each row's census
    /// ([`crate::refine::sharpness`]): the refinement's gain survives one defocused view; the
    /// stage then reads [`crate::refine::sharpness::equalised_reach`] rows around each row.
    pub equalise: bool,
}

impl Refine {
    /// Whether the shipped refinement equalises the views' sharpness (chosen on the validation
    /// pairs: it halves the refinement's epe rise under one defocused view at no clean cost).
    pub const EQUALISE: bool = true;

    /// The shipped refinement of `input` at the presets' and the firmware's 160 px:
    /// [`RefineParams::DEFAULT`] with the sharpness equalisation (the host's commands use
    /// [`Refine::for_width`], equal to this below 200 px).
    pub const fn of(input: RefineInput) -> Self {
        Self {
            input,
            params: RefineParams::DEFAULT,
            equalise: Self::EQUALISE,
        }
    }

    /// The shipped refinement of `input` on views `width` pixels wide: [`Refine::of`] with
    /// [`RefineParams::for_width`] (the host's commands; at 48x160, the presets' and the
    /// firmware's width, the same as [`Refine::of`]).
    pub const fn for_width(input: RefineInput, width: usize) -> Self {
        Self {
            params: RefineParams::for_width(width),
            ..Self::of(input)
        }
    }

    /// The shipped refinement ([`Refine::of`]) of the readout [`RefineInput::for_options`]
    /// picks.
    pub const fn for_options(opts: &Options) -> Self {
        Self::of(RefineInput::for_options(opts))
    }

    /// View rows above and below a pixel row the stage reads.
    pub const fn reach(&self) -> usize {
        refine_stage::stage_reach(&self.params, self.equalise)
    }
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
    /// Native pathway: the pair token codes of a band (`band.rows x cols x [even, odd] x DIM`,
    /// as `Encoder::pair_tokens`), after the pass on (L, R).
    fn pair_band(&mut self, band: Band, tokens: &[i8]) {
        let _ = (band, tokens);
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
    /// With [`Pipeline::run_refined`]: pixel row `row` of the refined disparity (`width`
    /// values, Q8 px), top to bottom, every row once.
    fn refined(&mut self, row: usize, disparity_q8: &[u16]) {
        let _ = (row, disparity_q8);
    }
}

/// What a run used and kept.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
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
    /// Of which: the refinement's state and row scratch (0 without it).
    pub refine: usize,
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
const fn matching_bytes(cols: usize, max_cols: usize, guided: bool) -> usize {
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
        if guided { cols.saturating_mul(4) } else { 0 },                 // SGM guides: rows and previous rows
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
const fn head_check_bytes(cols: usize, candidates: usize, streaming: bool) -> usize {
    let mirror = if streaming {
        head::arena_bytes_with(HeadKind::Export, cols, candidates)
    } else {
        0
    };
    sum(&[mirror, check_rows_bytes(cols, HEAD_CHECK_ROWS)])
}

/// Arena bytes of a [`HeadCheck`] keeping `rows` rows of `cols` left disparities (u16,
/// aligned) and its mask row.
const fn check_rows_bytes(cols: usize, rows: usize) -> usize {
    sum(&[cols.saturating_mul(rows).saturating_mul(2).saturating_add(1), cols])
}

/// What sizes an export-pathway run's readout streams: the head's disparity candidates,
/// whether it is checked ([`Options::head_lr`]), and whether the SGM is guided
/// ([`Penalties::edge`]: two guide rows and two previous ones).
#[derive(Clone, Copy)]
struct ReadoutShape {
    candidates: usize,
    lr: bool,
    guided: bool,
}

impl ReadoutShape {
    const fn of(opts: &Options) -> Self {
        ReadoutShape {
            candidates: opts.head_candidates,
            lr: opts.head && opts.head_lr,
            guided: opts.penalties.guided(),
        }
    }

    /// The default head ([`HEAD_MAX_DISP`](crate::config::HEAD_MAX_DISP) candidates).
    const fn trained(lr: bool) -> Self {
        ReadoutShape {
            candidates: crate::config::HEAD_MAX_DISP,
            lr,
            guided: false,
        }
    }
}

/// Arena bytes of the readout streams (with the head, and its check when `head.lr`; the check
/// needs a second head stream only when `streaming` several bands).
const fn stream_bytes(cols: usize, max_cols: usize, head: ReadoutShape, streaming: bool) -> usize {
    let check = if head.lr {
        head_check_bytes(cols, head.candidates, streaming)
    } else {
        0
    };
    let stream = head::arena_bytes_with(HeadKind::Export, cols, head.candidates);
    sum(&[matching_bytes(cols, max_cols, head.guided), stream, check])
}

/// Arena bytes the pipeline needs for a `height x width` pair with `max_cols` candidates
/// (the head included). Firmware sizes its static arena with it.
///
/// Saturates at `usize::MAX` where the size does not fit a `usize` (absurd widths or candidate
/// counts): no arena is that large, so [`Pipeline::run`] rejects such a run as
/// [`Error::ArenaTooSmall`] (or earlier, as [`Error::TooWide`] / [`Error::Candidates`]); the
/// result is never a small wrong size.
pub const fn arena_bytes(height: usize, width: usize, max_cols: usize) -> usize {
    arena_bytes_of(height, width, max_cols, ReadoutShape::trained(false), None)
}

/// [`arena_bytes`] with the head's left-right check ([`Options::head_lr`]): a second head
/// stream.
pub const fn arena_bytes_head_lr(height: usize, width: usize, max_cols: usize) -> usize {
    arena_bytes_of(height, width, max_cols, ReadoutShape::trained(true), None)
}

/// The arena bytes a run with `opts` needs: on the export pathway [`arena_bytes`] or
/// [`arena_bytes_head_lr`]; on the native one the pixel band, the native head (two with its
/// check) and the encoder's scratch, which holds the band's pair tokens after each pass.
pub const fn arena_bytes_for(height: usize, width: usize, opts: &Options) -> usize {
    arena_bytes_run(height, width, opts, None)
}

/// The arena bytes [`Pipeline::run_refined`] needs with `opts` and `refine`. For one band
/// (images up to 48 rows) it equals [`arena_bytes_for`] wherever the refinement fits in the
/// encoder's scratch beside the streams, as at 48x160; with several bands it adds
/// [`refine_bytes`].
pub const fn arena_bytes_refined(height: usize, width: usize, opts: &Options, refine: &Refine) -> usize {
    arena_bytes_run(height, width, opts, Some(refine))
}

/// The arena bytes of a run with `opts`, refined when `refine` is given, on either pathway.
const fn arena_bytes_run(height: usize, width: usize, opts: &Options, refine: Option<&Refine>) -> usize {
    match opts.pathway {
        Pathway::Export => arena_bytes_of(height, width, opts.max_cols, ReadoutShape::of(opts), refine),
        Pathway::Native => native::arena_bytes(height, width, opts, refine),
    }
}

/// Bytes of the refinement's buffers in a run of a `height x width` pair: its state kept
/// across bands (two token rows; with several bands and a head input a ring of view rows) and
/// its row scratch (census codes and the output row). 14,085 at 48x160 with the defaults (the
/// equalisation's 13 smoothed rows included; 12,005 without); 22,405 for a taller image at width
/// 160 refining a head readout (the 26-row view ring).
pub const fn refine_bytes(height: usize, width: usize, refine: &Refine) -> usize {
    let (state, scratch) = refine_parts(height, width, refine);
    state.saturating_add(scratch)
}

/// The refinement's (state, row scratch) bytes.
const fn refine_parts(height: usize, width: usize, refine: &Refine) -> (usize, usize) {
    let ring = if height <= band_pixel_rows(height) {
        0
    } else {
        refine_stage::ring_rows(refine.reach(), refine.input.lag())
    };
    (
        refine_stage::state_bytes(width, ring),
        refine_stage::scratch_bytes(width, &refine.params, refine.equalise),
    )
}

const fn arena_bytes_of(
    height: usize,
    width: usize,
    max_cols: usize,
    head: ReadoutShape,
    refine: Option<&Refine>,
) -> usize {
    let band_rows = band_pixel_rows(height);
    let cols = width / CELL_W;
    let pixels = band_rows.saturating_mul(width).saturating_mul(2);
    let descriptors = (band_rows / PATCH_H).saturating_mul(cols).saturating_mul(DIM);
    let encoder = encoder::arena_bytes(band_rows, width);
    let (state, scratch) = match refine {
        Some(r) => refine_parts(height, width, r),
        None => (0, 0),
    };
    if height <= band_rows {
        let streams = stream_bytes(cols, max_cols, head, false);
        let after = sum(&[descriptors, streams, state, scratch]);
        sum(&[pixels, descriptors, max(encoder, after)])
    } else {
        let streams = stream_bytes(cols, max_cols, head, true);
        sum(&[
            pixels,
            descriptors,
            streams,
            state,
            max(encoder, descriptors.saturating_add(scratch)),
        ])
    }
}

/// The int8 encoder and (optionally) the heads of both pathways over one weight blob.
#[derive(Clone, Copy)]
pub struct Pipeline<'w> {
    encoder: Encoder<'w>,
    head: Option<HeadWeights<'w>>,
    native: Option<HeadWeights<'w>>,
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
    /// without the head (or, for [`RefineInput::HeadLr`], without its check),
    /// [`Error::OutOfRange`] for bad [`RefineParams`].
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
            report.head_kept = streams.head_kept();
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
            report.head_kept = streams.head_kept();
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
struct Context<'p, 'w> {
    pipeline: &'p Pipeline<'w>,
    head: Option<HeadWeights<'w>>,
    opts: &'p Options,
    refine: Option<&'p Refine>,
    cols: usize,
    width: usize,
    height: usize,
    band_px: usize,
}

impl Context<'_, '_> {
    /// Whether this run checks the head left against right.
    fn head_lr(&self) -> bool {
        self.head.is_some() && self.opts.head_lr
    }

    /// The head's shape in the arena (sized even without a head: see [`arena_bytes_for`]).
    fn head_shape(&self) -> ReadoutShape {
        ReadoutShape {
            candidates: self.opts.head_candidates,
            lr: self.head_lr(),
            guided: self.opts.penalties.guided(),
        }
    }

    /// The refinement's view of the band buffer and its row scratch, cut from `arena` (none
    /// without the refinement).
    fn refine_io<'b>(&self, view: BandView<'b>, arena: &'b mut [u8]) -> Result<RefineIo<'b>, Error> {
        let scratch = match self.refine {
            Some(r) => Scratch::new(arena, self.width, self.height, &r.params, r.equalise)?,
            None => Scratch::none(),
        };
        Ok(RefineIo { view, scratch })
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
    /// The rows the buffers `left` and `right` hold now.
    fn view<'b>(&self, left: &'b [u8], right: &'b [u8]) -> BandView<'b> {
        BandView {
            first: self.first,
            rows: self.loaded - self.first,
            width: self.width,
            left,
            right,
        }
    }

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

/// The refinement fed from inside a head stream's callback.
struct Feed<'k, 'a, 'b> {
    stage: &'k mut RefineStage<'a>,
    io: &'k mut RefineIo<'b>,
    /// The head stage to return to.
    back: Stage,
}

impl Feed<'_, '_, '_> {
    /// The refinement's input `want`, when it is the run's, fed from head stage `back`.
    fn of<'k, 'a, 'b>(
        refine: &'k mut Option<(RefineInput, RefineStage<'a>)>,
        io: &'k mut RefineIo<'b>,
        want: RefineInput,
        back: Stage,
    ) -> Option<Feed<'k, 'a, 'b>> {
        match refine {
            Some((input, stage)) if *input == want => Some(Feed { stage, io, back }),
            _ => None,
        }
    }

    /// Pushes a head row (errors kept for [`RefineStage::check`]), back in the head stage after.
    fn push(&mut self, row: usize, disparity_q8: &[u16], mask: Option<&[u8]>, sink: &mut impl Sink) {
        sink.stage(Stage::Refine);
        self.stage.push_or_keep(row, disparity_q8, mask, self.io, sink);
        sink.stage(self.back);
    }
}

/// Forwards the left head's rows to the pipeline's sink, keeping their disparities for the
/// check when there is one, and to the refinement when it reads the head unchecked.
struct HeadRows<'k, 'a, 'b, K> {
    sink: &'k mut K,
    check: Option<&'k mut HeadCheck<'a>>,
    refine: Option<Feed<'k, 'a, 'b>>,
}

impl<K: Sink> HeadSink for HeadRows<'_, '_, '_, K> {
    fn row(&mut self, row: HeadRow<'_>) {
        if let Some(check) = self.check.as_deref_mut() {
            check.keep_left(row.row, row.disparity_q8);
        }
        let (index, disparity) = (row.row, row.disparity_q8);
        self.sink.head(row);
        if let Some(feed) = self.refine.as_mut() {
            feed.push(index, disparity, None, self.sink);
        }
    }
}

/// The head's left-right check: the left rows kept for it, its mask row, what it kept.
struct HeadCheck<'a> {
    cols: usize,
    /// Rows of `left_rows`.
    rows: usize,
    lr_max_diff_q8: u16,
    /// `rows` rows of left disparities, row `r` in slot `r % rows` (export pathway,
    /// [`HEAD_CHECK_ROWS`]; one band: every row of it, so the mirrored head can run afterwards).
    left_rows: &'a mut [u16],
    mask: &'a mut [u8],
    kept: usize,
}

impl<'a> HeadCheck<'a> {
    /// A check keeping `rows` rows of `cols` left disparities, cut from the front of `arena`
    /// ([`check_rows_bytes`]); returns it and the bytes it took.
    fn carve(arena: &'a mut [u8], cols: usize, rows: usize, lr_max_diff_q8: u16) -> Result<(Self, usize), Error> {
        let mut carver = Carver::new(arena, check_rows_bytes(cols, rows))?;
        let check = HeadCheck {
            cols,
            rows,
            lr_max_diff_q8,
            left_rows: carver.u16s(cols.saturating_mul(rows))?,
            mask: carver.u8s(cols)?,
            kept: 0,
        };
        Ok((check, carver.used()))
    }

    fn slot(&mut self, row: usize) -> Option<&mut [u16]> {
        let at = (row % self.rows.max(1)) * self.cols;
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

/// Checks the mirrored head's rows against the left rows kept for them; feeds the refinement
/// the filled left row when it reads head+lr.
struct CheckedRows<'k, 'a, 'b, K> {
    sink: &'k mut K,
    check: &'k mut HeadCheck<'a>,
    refine: Option<Feed<'k, 'a, 'b>>,
}

impl<K: Sink> HeadSink for CheckedRows<'_, '_, '_, K> {
    fn row(&mut self, row: HeadRow<'_>) {
        let check = &mut *self.check;
        let tolerance = check.lr_max_diff_q8;
        let at = (row.row % check.rows.max(1)) * check.cols;
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
        if let Some(feed) = self.refine.as_mut() {
            feed.push(row.row, left, Some(check.mask), self.sink);
        }
    }
}

/// The readouts' state: one token row of buffers plus SGM's and the head's carried state.
struct Streams<'a, 'w> {
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
    /// With the refinement: the readout it reads and its state.
    refine: Option<(RefineInput, RefineStage<'a>)>,
    used: usize,
    wta_kept: usize,
    sgm_kept: usize,
}

impl<'a, 'w> Streams<'a, 'w> {
    /// The streams of a run; `streaming`: several bands, so the head's check (if any) streams
    /// a mirrored head beside the left one instead of rerunning the band after it.
    fn new(ctx: &Context<'_, 'w>, arena: &'a mut [u8], streaming: bool) -> Result<Self, Error> {
        let (cols, max_cols) = (ctx.cols, ctx.opts.max_cols);
        let streams = stream_bytes(cols, max_cols, ctx.head_shape(), streaming);
        let (arena, refine_arena) = arena.split_at_mut(streams.min(arena.len()));
        let refine = match ctx.refine {
            Some(r) => {
                let (state, _) = refine_parts(ctx.height, ctx.width, r);
                let ring = if streaming {
                    refine_stage::ring_rows(r.reach(), r.input.lag())
                } else {
                    0
                };
                let available = streams.saturating_add(refine_arena.len());
                let arena = refine_arena.get_mut(..state).ok_or(Error::ArenaTooSmall {
                    needed: streams.saturating_add(state),
                    available,
                })?;
                Some((
                    r.input,
                    RefineStage::new(r.params, r.equalise, ctx.width, ctx.height, ring, arena)?,
                ))
            }
            None => None,
        };
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
                    let (check, check_used) = HeadCheck::carve(rest, cols, HEAD_CHECK_ROWS, ctx.opts.lr_max_diff_q8)?;
                    used += check_used;
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
            refine,
            used,
            wta_kept: 0,
            sgm_kept: 0,
        })
    }

    /// Arena bytes of the refinement's state (0 without it).
    fn refine_used(&self) -> usize {
        self.refine.as_ref().map_or(0, |(_, stage)| stage.used())
    }

    /// Before a band load that drops the rows above `new_first`.
    fn keep_view_rows(&mut self, view: &BandView<'_>, new_first: usize, sink: &mut impl Sink) -> Result<(), Error> {
        let Some((_, stage)) = self.refine.as_mut() else {
            return Ok(());
        };
        sink.stage(Stage::Refine);
        stage.keep_before(view, new_first)
    }

    /// After the last row: the refinement emitted every pixel row and kept no error.
    fn refine_done(&self) -> Result<(), Error> {
        self.refine.as_ref().map_or(Ok(()), |(_, stage)| stage.done())
    }

    /// Errors a head callback kept.
    fn refine_check(&self) -> Result<(), Error> {
        self.refine.as_ref().map_or(Ok(()), |(_, stage)| stage.check())
    }

    /// Cells the head's left-right check kept (0 without it).
    fn head_kept(&self) -> usize {
        self.check.as_ref().map_or(0, |(_, check)| check.kept)
    }

    /// Feeds the rows `band` keeps.
    fn push_band(
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
        sink.matched(&MatchedRow {
            row,
            wta_q8: self.wta,
            sgm_q8: self.sgm_out,
            wta_consistent: self.wta_mask,
            sgm_consistent: self.sgm_mask,
        });
        if let Some((input, stage)) = self.refine.as_mut() {
            let matched = match *input {
                RefineInput::Nolink => Some((&*self.wta, None)),
                RefineInput::NolinkLr => Some((&*self.wta, Some(&*self.wta_mask))),
                RefineInput::Sgm => Some((&*self.sgm_out, None)),
                RefineInput::SgmLr => Some((&*self.sgm_out, Some(&*self.sgm_mask))),
                RefineInput::Head | RefineInput::HeadLr => None,
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
                    refine: Feed::of(&mut self.refine, io, RefineInput::Head, Stage::Head),
                };
                head_step(head, input, &mut rows)?;
                if let Some(mirror) = mirror {
                    let mut rows = CheckedRows {
                        sink: &mut *sink,
                        check,
                        refine: Feed::of(&mut self.refine, io, RefineInput::HeadLr, Stage::Head),
                    };
                    head_step(mirror, input, &mut rows)?;
                }
            }
            None => {
                let mut rows = HeadRows {
                    sink: &mut *sink,
                    check: None,
                    refine: Feed::of(&mut self.refine, io, RefineInput::Head, Stage::Head),
                };
                head_step(head, input, &mut rows)?;
            }
        }
        self.refine_check()
    }

    fn finish(&mut self, io: &mut RefineIo<'_>, sink: &mut impl Sink) -> Result<(), Error> {
        self.head_rows(None, io, sink)
    }

    /// One band, after [`Streams::finish`]: the mirrored head over the band's rows on the left
    /// head's arena, checked against the left rows it kept (a no-op unless the check is on and
    /// not already streamed).
    fn check_head_band(
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
            refine: Feed::of(&mut self.refine, io, RefineInput::HeadLr, Stage::Head),
        };
        for row in band.keep_from..band.keep_to {
            let (l, r) = kept_row(band, row, self.cols, left, right)?;
            head.push_row(l, r, &mut rows)?;
        }
        head.finish(&mut rows)?;
        self.refine_check()
    }
}

/// One step of a head stream: the next descriptor row, or (`None`) the end of the input.
fn head_step(
    stream: &mut HeadStream<'_, '_>,
    input: Option<(&[i8], &[i8])>,
    rows: &mut impl HeadSink,
) -> Result<(), Error> {
    match input {
        Some((left, right)) => stream.push_row(left, right, rows),
        None => stream.finish(rows),
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
