//! The pipeline's public types: its stages, where rows come from ([`RowSource`]), what a run
//! uses ([`Options`], [`Refine`]), where its output goes ([`Sink`]) and what it reports
//! ([`Report`]).

use super::layout::stage_reach;
use crate::band::Band;
use crate::lr::Fill;
use crate::model::encoder::{Encoder, GrayBand};
use crate::model::head::HeadRow;
use crate::model::ids::HeadKind;
use crate::model::probe::NoProbe;
use crate::refine::RefineParams;
use crate::sgm::Penalties;
use crate::Error;
#[cfg(doc)]
use {super::arena_bytes_head_lr, super::Pipeline, crate::model::head::HeadStream};

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
    /// SGM aggregation of one token row, left and right views: the descriptor SGM (export
    /// pathway) or the census SGM with its census codes and costs (native pathway).
    Sgm,
    /// Right-view WTA and the left-right check of both readouts.
    LeftRight,
    /// The head on one descriptor row (export pathway) or pair token row (native pathway),
    /// with its left-right check.
    Head,
    /// The pixel refinement of the rows one token row made computable (and the copy of view
    /// rows it still needs before a band load).
    Refine,
    /// Native pathway: the encoder on (L, R), the band's pair tokens.
    EncodePair,
}

impl Stage {
    /// Every stage, in pipeline order.
    pub const ALL: [Stage; 9] = [
        Stage::Rows,
        Stage::EncodeLeft,
        Stage::EncodeRight,
        Stage::Match,
        Stage::Sgm,
        Stage::LeftRight,
        Stage::Head,
        Stage::Refine,
        Stage::EncodePair,
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
        }
    }

    /// Whether the stage runs the encoder.
    pub const fn encodes(self) -> bool {
        matches!(self, Stage::EncodeLeft | Stage::EncodeRight | Stage::EncodePair)
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
            return Err(Error::EndOfRows {
                row: self.next,
                height: self.height,
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

/// How the encoder covers a band's token rows. Weights whose token rows do not depend on their
/// place in the band ([`Encoder::rows_independent`]) are encoded [`TOKEN_ROWS_PER_PASS`] token
/// rows at a time, each pass's output after the last, so the encoder's scratch holds one pass's
/// work beside the band's outputs instead of the whole band's; any other weights take one pass
/// per band. Both give the same bytes; only the arena differs
/// ([`arena_bytes_with`](super::arena_bytes_with)).
///
/// [`Encoder::rows_independent`]: crate::model::encoder::Encoder::rows_independent
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Passes {
    /// One pass per band: any weights.
    Band,
    /// [`TOKEN_ROWS_PER_PASS`] token rows a pass: weights whose token rows are independent.
    TokenRows,
}

/// Token rows a [`Passes::TokenRows`] pass encodes (the band's last pass may have fewer). Each
/// pass pays a fixed set-up (its weights' parameters decoded, its buffers zeroed: about 1.2M
/// instructions on the Cortex-M55, so a 48x160 band's passes cost 4 % more at one token row a
/// pass, 0.8 % at four); four rows a pass still leave the encoder's scratch smaller than what
/// the heads need after it at 160 and 320 px, so the arena is the same.
pub const TOKEN_ROWS_PER_PASS: usize = 4;

/// What the readouts use.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Options {
    /// [`Pathway::Export`]: every readout (no-linkage WTA, SGM, their checks, the shared head
    /// when `head`). [`Pathway::Native`]: the native head alone (`head` is implied; `max_cols`
    /// and `penalties` are unused), with its check when `head_lr`, read from the same pass (the
    /// right view's disparity from the head's own logits, [`crate::model::head::right_view_row`]).
    pub pathway: Pathway,
    /// Disparity candidates of the WTA and SGM readouts, in patch columns (1 to 64).
    pub max_cols: usize,
    /// SGM penalties (cost units: 4096 = cosine 1).
    pub penalties: Penalties,
    /// Left-right check tolerance, Q8 patch columns.
    pub lr_max_diff_q8: u16,
    /// Run the shared head too.
    pub head: bool,
    /// With `head`: the head's own left-right check ([`Sink::head_checked`]). On the export
    /// pathway each band's head reruns on the mirrored pair, on the same stream, so the arena
    /// is [`arena_bytes_head_lr`] (the left rows the check keeps); on the native pathway the
    /// right view is read from the left head's logits (two rows of arena). Ignored without
    /// `head`.
    pub head_lr: bool,
    /// Disparity candidates of the head (either pathway), in patch columns (1 to
    /// [`HEAD_CANDIDATES_LIMIT`](crate::config::HEAD_CANDIDATES_LIMIT)):
    /// [`HEAD_MAX_DISP`](crate::config::HEAD_MAX_DISP), the count it was trained with, or more
    /// for wide views whose disparities reach further ([`HeadStream::with_candidates`]).
    pub head_candidates: usize,
}

/// The readout whose token grid the refinement reads, named as the host names readouts. A
/// `+lr` input is the readout's disparity with the cells its left-right check rejects filled
/// ([`RefineInput::fill`]).
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
    /// The head and SGM fused by their own left-right checks ([`crate::lr::fuse_row`], the
    /// head's share [`crate::lr::fuse_head_weight`] of the view width), filled where both
    /// reject (export pathway; needs [`Options::head`] and [`Options::head_lr`]).
    FusedLr,
    /// The native head and the census SGM ([`crate::census`]) fused by their own left-right
    /// checks as [`RefineInput::FusedLr`] fuses the head and SGM, the head's share
    /// [`crate::census::FUSE_HEAD_WEIGHT`] (native pathway; needs [`Options::head_lr`]).
    FusedCensusLr,
    /// The shared head fused with the census SGM as in [`RefineInput::FusedCensusLr`], and
    /// that fused with the descriptor SGM as in [`RefineInput::FusedLr`], its share
    /// [`crate::census::FUSE_ALL_FIRST_WEIGHT`] (export pathway; needs [`Options::head`] and
    /// [`Options::head_lr`]).
    FusedAllLr,
    /// The census SGM of the views' pixels alone ([`crate::census`]): no encoder, no weights
    /// ([`crate::pipeline::run_census`]; either pathway's options).
    Census,
    /// The census SGM, filled by its own left-right check and uniqueness test.
    CensusLr,
}

impl RefineInput {
    /// The rule: the best readout each run has. On the export pathway
    /// [`RefineInput::FusedAllLr`] when the run checks the head ([`Options::head`] and
    /// [`Options::head_lr`]; the default of `bino run` is `fuse-all+lr+ref`), else
    /// [`RefineInput::SgmLr`]. On the native pathway with the head's check
    /// [`RefineInput::FusedCensusLr`] (the head fused with the census SGM), else head.
    pub const fn for_options(opts: &Options) -> Self {
        match opts.pathway {
            Pathway::Native if opts.head_lr => RefineInput::FusedCensusLr,
            Pathway::Native => RefineInput::Head,
            Pathway::Export if opts.head && opts.head_lr => RefineInput::FusedAllLr,
            Pathway::Export => RefineInput::SgmLr,
        }
    }

    /// How it fills the cells its check rejected: from the background where the census is in it
    /// (`census+lr`, `fuse-census+lr`, `fuse-all+lr`), else from the left.
    pub const fn fill(self) -> Fill {
        match self {
            RefineInput::CensusLr | RefineInput::FusedCensusLr | RefineInput::FusedAllLr => Fill::Background,
            _ => Fill::FromLeft,
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
            RefineInput::FusedLr => "fuse+lr",
            RefineInput::FusedCensusLr => "fuse-census+lr",
            RefineInput::FusedAllLr => "fuse-all+lr",
            RefineInput::Census => "census",
            RefineInput::CensusLr => "census+lr",
        }
    }

    /// Whether it reads the census SGM alone, so the run needs no encoder pass and no weights
    /// ([`crate::pipeline::run_census`]).
    pub const fn census_only(self) -> bool {
        matches!(self, RefineInput::Census | RefineInput::CensusLr)
    }

    /// Whether it reads the head.
    pub const fn uses_head(self) -> bool {
        matches!(
            self,
            RefineInput::Head
                | RefineInput::HeadLr
                | RefineInput::FusedLr
                | RefineInput::FusedCensusLr
                | RefineInput::FusedAllLr
        )
    }

    /// Whether it needs the head's left-right check ([`Options::head_lr`]).
    pub const fn needs_head_check(self) -> bool {
        matches!(
            self,
            RefineInput::HeadLr | RefineInput::FusedLr | RefineInput::FusedCensusLr | RefineInput::FusedAllLr
        )
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
        stage_reach(&self.params, self.equalise)
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

/// The head's left-right check of one token row: the right view's head disparity (export
/// pathway: the head on the mirrored pair; native pathway: read from the left head's logits)
/// and which left cells it confirms.
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

/// One token row of the fused readout (export pathway, with the head's check): the head and
/// SGM fused by their own left-right checks ([`crate::lr::fuse_row`]), before the fill.
#[derive(Debug, Clone, Copy)]
pub struct FusedRow<'r> {
    /// Token row.
    pub row: usize,
    /// Fused disparity per patch column, Q8 patch columns (rejected cells hold the head's).
    pub disparity_q8: &'r [u16],
    /// 1 where the head or SGM passes its check, else 0 (`fuse+lr` fills these cells).
    pub consistent: &'r [u8],
}

/// One token row of the census SGM ([`crate::pipeline::run_census`]), before any fill.
#[derive(Debug, Clone, Copy)]
pub struct CensusRow<'r> {
    /// Token row.
    pub row: usize,
    /// Census SGM disparity per patch column, Q8 patch columns.
    pub disparity_q8: &'r [u16],
    /// 1 where the cell passes the census check (left-right agreement and uniqueness), else 0
    /// (`census+lr` fills these cells).
    pub consistent: &'r [u8],
}

/// The encoder passes of a run, band by band, as the pipeline asks for them: the blob's int8
/// encoder ([`Pipeline::run`]), or a stand-in answering with the bytes that encoder gives for
/// the same band ([`Pipeline::run_encoded`]: a host refining several readouts of one pair
/// encodes the pair once and replays its passes).
pub trait BandEncoder {
    /// One view's band descriptors (an export-pathway pass, as
    /// [`Encoder::describe_in_place`]) at the front of `arena`: the arena's high-water and the
    /// descriptors' length in bytes.
    fn view_pass(&mut self, view: GrayBand<'_>, arena: &mut [u8]) -> Result<(usize, usize), Error>;

    /// The band's pair tokens (the native pathway's pass, as [`Encoder::pair_tokens_in_place`])
    /// at the front of `arena`: the arena's high-water and the tokens' length in bytes.
    fn pair_pass(&mut self, left: GrayBand<'_>, right: GrayBand<'_>, arena: &mut [u8])
        -> Result<(usize, usize), Error>;
}

impl BandEncoder for Encoder<'_> {
    fn view_pass(&mut self, view: GrayBand<'_>, arena: &mut [u8]) -> Result<(usize, usize), Error> {
        let (report, len) = self.describe_in_place(view, arena, &mut NoProbe)?;
        Ok((report.arena_used, len))
    }

    fn pair_pass(
        &mut self,
        left: GrayBand<'_>,
        right: GrayBand<'_>,
        arena: &mut [u8],
    ) -> Result<(usize, usize), Error> {
        let (report, len) = self.pair_tokens_in_place(left, right, arena, &mut NoProbe)?;
        Ok((report.arena_used, len))
    }
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
    fn matched(&mut self, row: &MatchedRow<'_>) {
        let _ = row;
    }
    /// One token row of the head, top to bottom (a few rows behind the matching).
    fn head(&mut self, row: HeadRow<'_>) {
        let _ = row;
    }
    /// With [`Options::head_lr`]: the head's left-right check of a row, after its
    /// [`Sink::head`] row.
    fn head_checked(&mut self, row: &HeadChecked<'_>) {
        let _ = row;
    }
    /// On the export pathway with [`Options::head_lr`]: the fused readout's row, after its
    /// [`Sink::head_checked`] row.
    fn fused(&mut self, row: &FusedRow<'_>) {
        let _ = row;
    }
    /// With [`crate::pipeline::run_census`]: one token row of the census SGM, top to bottom.
    fn census(&mut self, row: &CensusRow<'_>) {
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
    /// Arena bytes used in all (the high-water mark). The regions below do not simply add up:
    /// `pixels` and `descriptors` are held for the whole run, while `encoder`'s scratch is
    /// reused once the passes are over. On the export pathway over one band it then holds the
    /// right descriptors, the streams and the refinement, so
    /// `arena_used = pixels + descriptors + max(encoder, descriptors + streams + refine)`; over
    /// several bands what carries from band to band (the SGMs' state, the head's check, the
    /// refinement's state) sits beside the scratch, and each band's head stream, row buffers
    /// and refinement row scratch reuse it. The native pathway keeps no descriptor band
    /// (`descriptors` = 0) and its streams follow the pair tokens in the encoder's scratch.
    pub arena_used: usize,
    /// Region: the pixel band of both views (held throughout).
    pub pixels: usize,
    /// Region: one descriptor band (the left one, held from the first pass to the end; the
    /// right one lives in the encoder's scratch).
    pub descriptors: usize,
    /// Region: the encoder's scratch, high-water of one pass (reused after the passes, see
    /// [`Report::arena_used`]).
    pub encoder: usize,
    /// Region: the readout streams (matching, SGM, left-right, head).
    pub streams: usize,
    /// Region: the refinement's state and row scratch (0 without it).
    pub refine: usize,
    /// Cells whose WTA disparity passed the left-right check.
    pub wta_kept: usize,
    /// Cells whose SGM disparity passed the left-right check.
    pub sgm_kept: usize,
    /// Cells whose head disparity passed the head's left-right check ([`Options::head_lr`]).
    pub head_kept: usize,
    /// Cells the fused readout kept: the head or its second opinion passed its check (export
    /// pathway with [`Options::head_lr`]: the SGM; native pathway refining
    /// [`RefineInput::FusedCensusLr`]: the census SGM).
    pub fused_kept: usize,
    /// Cells whose census SGM disparity passed its check ([`crate::pipeline::run_census`]).
    pub census_kept: usize,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pair_in_memory_ends_with_end_of_rows() {
        let (left, right) = ([1u8; 8], [2u8; 8]);
        let mut pair = SlicePair::new(&left, &right, 4, 2).unwrap();
        let (mut l, mut r) = ([0u8; 4], [0u8; 4]);
        for _ in 0..2 {
            pair.next_row(&mut l, &mut r).unwrap();
        }
        assert_eq!((l, r), ([1; 4], [2; 4]));
        assert_eq!(
            pair.next_row(&mut l, &mut r),
            Err(Error::EndOfRows { row: 2, height: 2 })
        );
    }
}
