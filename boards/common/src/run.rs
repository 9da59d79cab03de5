//! One band pair (the learned preset) or one whole frame (the fast preset) through the pipeline
//! into a [`Summary`].

use bino_core::blob::Blob;
use bino_core::pipeline::{self, Pipeline, Report, RowSource};
use bino_core::Error;

use crate::options::{ARENA_BYTES, BAND_HEIGHT, CENSUS_REFINE, FAST_ARENA_BYTES, FRAME_HEIGHT, OPTIONS, REFINE};
use crate::summary::{Clock, Summary};

/// The engine of a weight blob: header, CRC over the whole blob and tensor table checked once,
/// at boot.
pub fn load(blob: &[u8]) -> Result<Pipeline<'_>, Error> {
    Pipeline::new(Blob::parse(blob)?)
}

/// Runs the band pair `source` delivers through every readout of [`OPTIONS`] and the
/// refinement [`REFINE`] in `arena` ([`crate::options::arena_bytes`] bytes at least), into
/// `summary`, which it finishes.
pub fn run_band<C: Clock>(
    pipeline: &Pipeline<'_>,
    source: &mut impl RowSource,
    arena: &mut [u8],
    summary: &mut Summary<C>,
) -> Result<Report, Error> {
    let report = pipeline.run_refined(source, &OPTIONS, &REFINE, arena, summary);
    summary.finish();
    report
}

/// Runs the whole frame `source` delivers through the fast preset, the encoder-free census
/// readout refined to pixels ([`CENSUS_REFINE`], `pipeline::run_census`: no weights), in
/// `arena` ([`FAST_ARENA_BYTES`] bytes at least, for any height), into `summary`, which it
/// finishes. Reads the rows as its token rows need them, so a camera's line buffers keep up.
pub fn run_frame<C: Clock>(
    source: &mut impl RowSource,
    arena: &mut [u8],
    summary: &mut Summary<C>,
) -> Result<Report, Error> {
    let report = pipeline::run_census(source, &OPTIONS, Some(&CENSUS_REFINE), arena, summary);
    summary.finish();
    report
}

/// What a board runs on each frame from its camera.
// The engine's tables make the learned variant large; no heap to box it in, and a board builds
// one preset once, at boot.
#[allow(clippy::large_enum_variant)]
pub enum Preset<'b> {
    /// The learned preset on one band of [`BAND_HEIGHT`] rows (the blob's engine).
    Learned(Pipeline<'b>),
    /// The fast preset on a whole frame of [`FRAME_HEIGHT`] rows, no weights.
    Fast,
}

impl Preset<'_> {
    /// Rows of what one run reads: one band, or one whole frame.
    pub fn height(&self) -> usize {
        match self {
            Preset::Learned(_) => BAND_HEIGHT,
            Preset::Fast => FRAME_HEIGHT,
        }
    }

    /// The arena it needs, bytes.
    pub fn arena_bytes(&self) -> usize {
        match self {
            Preset::Learned(_) => ARENA_BYTES,
            Preset::Fast => FAST_ARENA_BYTES,
        }
    }

    /// `learned` or `fast`.
    pub fn name(&self) -> &'static str {
        match self {
            Preset::Learned(_) => "learned",
            Preset::Fast => "fast",
        }
    }

    /// One run ([`run_band`] or [`run_frame`]) on the rows `source` delivers.
    pub fn run<C: Clock>(
        &self,
        source: &mut impl RowSource,
        arena: &mut [u8],
        summary: &mut Summary<C>,
    ) -> Result<Report, Error> {
        match self {
            Preset::Learned(pipeline) => run_band(pipeline, source, arena, summary),
            Preset::Fast => run_frame(source, arena, summary),
        }
    }
}
