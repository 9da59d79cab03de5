//! One band pair through the pipeline into a [`Summary`].

use bino_core::blob::Blob;
use bino_core::pipeline::{Pipeline, Report, RowSource};
use bino_core::Error;

use crate::options::{OPTIONS, REFINE};
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
