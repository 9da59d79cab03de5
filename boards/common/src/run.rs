//! One whole frame through the pipeline into a [`Summary`]: the learned preset, band after band
//! of the frame, or the fast preset, each with the options of the frame's width ([`Frame`]).

use bino_core::blob::Blob;
use bino_core::pipeline::{self, Pipeline, Report, RowSource};
use bino_core::Error;

use crate::options::Frame;
use crate::summary::{Clock, Summary};

/// The frame `source` delivers, by its size.
fn frame_of(source: &impl RowSource) -> Frame {
    Frame {
        width: source.width(),
        height: source.height(),
    }
}

/// The engine of a weight blob: header, CRC over the whole blob and tensor table checked once,
/// at boot.
pub fn load(blob: &[u8]) -> Result<Pipeline<'_>, Error> {
    Pipeline::new(Blob::parse(blob)?)
}

/// Runs the whole frame `source` delivers through every readout of the learned preset's options
/// and its refinement at the frame's width ([`Frame::options`], [`Frame::refine`]: at 160x120
/// the QEMU firmware's frame run), band after band, each band's head started afresh in the
/// encoder's scratch, in `arena` ([`Frame::arena_bytes`] at least), into `summary`, which it
/// finishes.
pub fn run_learned<C: Clock>(
    pipeline: &Pipeline<'_>,
    source: &mut impl RowSource,
    arena: &mut [u8],
    summary: &mut Summary<C>,
) -> Result<Report, Error> {
    let frame = frame_of(source);
    let report = pipeline.run_refined(source, &frame.options(), &frame.refine(), arena, summary);
    summary.finish();
    report
}

/// Runs the whole frame `source` delivers through the fast preset, the encoder-free census
/// readout refined to pixels at the frame's width ([`Frame::census_refine`],
/// `pipeline::run_census`: no weights), in `arena` ([`Frame::fast_arena_bytes`] at least), into
/// `summary`, which it finishes. Reads the rows as its token rows need them, so a camera's line
/// buffers keep up.
pub fn run_fast<C: Clock>(
    source: &mut impl RowSource,
    arena: &mut [u8],
    summary: &mut Summary<C>,
) -> Result<Report, Error> {
    let frame = frame_of(source);
    let report = pipeline::run_census(source, &frame.options(), Some(&frame.census_refine()), arena, summary);
    summary.finish();
    report
}

/// What a board runs on each frame from its camera.
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
    /// The arena it needs for a whole `frame`, bytes.
    pub const fn arena_bytes(&self, frame: Frame) -> usize {
        match self {
            Preset::Learned(_) => frame.arena_bytes(),
            Preset::Fast => frame.fast_arena_bytes(),
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
