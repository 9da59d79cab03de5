//! Where a pipeline run's encoder passes come from: [`EncoderPasses`]. The [`Encoder`] computes
//! each pass when the run reaches it (every board, and the host by default); a host with several
//! cores can compute a run's passes ahead, one band per thread, and hand them in, as long as
//! they are the same bytes (`bino_host::int8::passes` checks the pixels of every pass it
//! serves and computes any it was not given).

use super::{Encoder, GrayBand, RunReport};
use crate::model::probe::NoProbe;
use crate::Error;

/// The encoder passes of a pipeline run. Each writes its output at the front of `arena` and
/// returns the pass's report and the output's length in bytes, exactly as the [`Encoder`]
/// method of the same name does: that is the contract, and the pipeline's outputs are the same
/// whichever implementation it is given.
pub trait EncoderPasses {
    /// Widest band the weights support, in pixels ([`Encoder::max_width`]).
    fn max_width(&self) -> usize;

    /// The descriptors of one view ([`Encoder::describe_in_place`]).
    fn describe_in_place(&self, view: GrayBand<'_>, arena: &mut [u8]) -> Result<(RunReport, usize), Error>;

    /// The native pathway's pair tokens ([`Encoder::pair_tokens_in_place`]).
    fn pair_tokens_in_place(
        &self,
        left: GrayBand<'_>,
        right: GrayBand<'_>,
        arena: &mut [u8],
    ) -> Result<(RunReport, usize), Error>;
}

impl EncoderPasses for Encoder<'_> {
    fn max_width(&self) -> usize {
        Encoder::max_width(self)
    }

    fn describe_in_place(&self, view: GrayBand<'_>, arena: &mut [u8]) -> Result<(RunReport, usize), Error> {
        Encoder::describe_in_place(self, view, arena, &mut NoProbe)
    }

    fn pair_tokens_in_place(
        &self,
        left: GrayBand<'_>,
        right: GrayBand<'_>,
        arena: &mut [u8],
    ) -> Result<(RunReport, usize), Error> {
        Encoder::pair_tokens_in_place(self, left, right, arena, &mut NoProbe)
    }
}
