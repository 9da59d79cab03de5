//! The driver: [`Pipeline`] checks a run and hands it to its pathway: the export one
//! (`export.rs`), the native one (`native.rs`) or, for a census input, the encoder-free run
//! (`census_run.rs`).

use super::api::{BandEncoder, Options, Passes, Pathway, Refine, RefineInput, Report, RowSource, Sink};
use super::context::Context;
use super::layout::band_pixel_rows;
use super::row_passes::RowPasses;
use super::sizing::arena_bytes_with;
use super::{export, native};
use crate::band::BandPlan;
use crate::config::check_view_size;
use crate::matching::check_candidates;
use crate::model::encoder::Encoder;
use crate::model::head::{self, HeadWeights};
use crate::model::ids::HeadKind;
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
    /// How the encoder covers a band, decided once from the blob ([`Pipeline::passes`]).
    passes: Passes,
}

impl<'w> Pipeline<'w> {
    /// The pipeline of a blob; a head the blob does not carry (or carries incomplete) is left
    /// out, and a run that needs it is an error naming its first missing tensor.
    pub fn new(blob: crate::blob::Blob<'w>) -> Result<Self, Error> {
        let encoder = Encoder::new(blob)?;
        let passes = match encoder.rows_independent() {
            true => Passes::TokenRows,
            false => Passes::Band,
        };
        Ok(Self {
            encoder,
            head: HeadWeights::for_kind(blob, HeadKind::Export).ok(),
            native: HeadWeights::for_kind(blob, HeadKind::Native).ok(),
            passes,
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

    /// How this blob's encoder covers a band: [`Passes::TokenRows`] when its token rows are
    /// independent ([`Encoder::rows_independent`]), else [`Passes::Band`].
    pub fn passes(&self) -> Passes {
        self.passes
    }

    /// The arena bytes a run of this blob with `opts` (refined when `refine` is given) needs on
    /// a `height x width` pair: [`arena_bytes_with`] for its [`Pipeline::passes`].
    pub fn arena_bytes(&self, height: usize, width: usize, opts: &Options, refine: Option<&Refine>) -> usize {
        arena_bytes_with(height, width, opts, refine, self.passes())
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
        let mut encoder = self.encoder;
        self.run_encoded(source, opts, None, &mut encoder, arena, sink)
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
        let mut encoder = self.encoder;
        self.run_encoded(source, opts, Some(refine), &mut encoder, arena, sink)
    }

    /// [`Pipeline::run`] (`refine` none) or [`Pipeline::run_refined`] with each band's encoder
    /// passes by `encoder`, which must answer as the blob's encoder would (a host replays the
    /// passes of an earlier run of the same pair; a pass of the wrong length is an error). The
    /// head's weights are the blob's.
    pub fn run_encoded(
        &self,
        source: &mut impl RowSource,
        opts: &Options,
        refine: Option<&Refine>,
        encoder: &mut impl BandEncoder,
        arena: &mut [u8],
        sink: &mut impl Sink,
    ) -> Result<Report, Error> {
        self.run_with(source, opts, refine, encoder, arena, sink)
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
        encoder: &mut impl BandEncoder,
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
                // Census inputs went to the encoder-free run above.
                _ => native,
            };
            if missing {
                return Err(Error::MissingReadout {
                    readout: r.input.name(),
                });
            }
        }
        let passes = self.passes();
        crate::arena::check_size(arena, arena_bytes_with(height, width, opts, refine, passes))?;
        let plan = BandPlan::new(token_rows)?;
        let band_px = band_pixel_rows(height);
        let ctx = Context {
            head,
            opts,
            refine,
            cols,
            width,
            height,
            band_px,
            passes,
        };
        let mut encoder = RowPasses { encoder, passes };
        if native {
            return native::run(&ctx, &mut encoder, source, &plan, arena, sink);
        }
        export::run(&ctx, &mut encoder, source, &plan, arena, sink)
    }
}

/// A tensor id of `pathway`'s head (its input LayerNorm), for the error of a head asked of a
/// blob without one.
fn head_id(pathway: Pathway) -> crate::blob::TensorId {
    crate::model::ids::id(crate::model::ids::kind::LAYERNORM, pathway.layernorm())
}
