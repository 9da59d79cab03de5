//! One whole frame through the pipeline into a [`Summary`]: the learned preset, band after band
//! of the frame, or the fast preset.

use bino_core::blob::Blob;
use bino_core::pipeline::{self, Pipeline, Report, RowSource};
use bino_core::Error;

use crate::options::{ARENA_BYTES, CENSUS_REFINE, FAST_ARENA_BYTES, OPTIONS, REFINE};
use crate::summary::{Clock, Summary};

/// The engine of a weight blob: header, CRC over the whole blob and tensor table checked once,
/// at boot.
pub fn load(blob: &[u8]) -> Result<Pipeline<'_>, Error> {
    Pipeline::new(Blob::parse(blob)?)
}

/// Runs the whole frame `source` delivers through every readout of [`OPTIONS`] and the
/// refinement [`REFINE`] (the learned preset: the QEMU firmware's frame run), band after band,
/// each band's head started afresh in the encoder's scratch, in `arena` ([`ARENA_BYTES`] bytes
/// at least for a 160x120 frame), into `summary`, which it finishes.
pub fn run_learned<C: Clock>(
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
pub fn run_fast<C: Clock>(
    source: &mut impl RowSource,
    arena: &mut [u8],
    summary: &mut Summary<C>,
) -> Result<Report, Error> {
    let report = pipeline::run_census(source, &OPTIONS, Some(&CENSUS_REFINE), arena, summary);
    summary.finish();
    report
}

/// What a board runs on each frame from its camera
/// ([`FRAME_HEIGHT`](crate::options::FRAME_HEIGHT) rows).
// The engine's tables make the learned variant large; no heap to box it in, and a board builds
// one preset once, at boot.
#[allow(clippy::large_enum_variant)]
pub enum Preset<'b> {
    /// The learned preset (the blob's engine).
    Learned(Pipeline<'b>),
    /// The fast preset, no weights.
    Fast,
}

impl Preset<'_> {
    /// The arena it needs for a 160x120 frame, bytes.
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

    /// One run ([`run_learned`] or [`run_fast`]) on the frame `source` delivers.
    pub fn run<C: Clock>(
        &self,
        source: &mut impl RowSource,
        arena: &mut [u8],
        summary: &mut Summary<C>,
    ) -> Result<Report, Error> {
        match self {
            Preset::Learned(pipeline) => run_learned(pipeline, source, arena, summary),
            Preset::Fast => run_fast(source, arena, summary),
        }
    }
}
