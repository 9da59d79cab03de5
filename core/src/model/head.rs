//! The stereo heads in int8, streaming: descriptor rows in, disparity rows out.
//!
//! Two heads share everything after their projections ([`HeadKind`]): the export pathway's
//! shared head reads a descriptor row of each view and projects both with one LayerNorm +
//! projection; the native pathway's head reads one row of the pair's de-positioned fused grid
//! (`Encoder::pair_tokens`: per patch column the pair feature `u = [a, b]`, its two phase
//! tokens), normalises `u` once and projects it twice (`P_L`, `P_R`).
//!
//! Per descriptor row pair: LayerNorm and the shared projection of both views, the groupwise
//! correlation over the stream's disparity candidates (`HEAD_MAX_DISP` unless
//! [`HeadStream::with_candidates`] asks for more; row layout `[column][disparity][channel]`), then
//! six 3x3x3 convolutions over (row, disparity, column): a stem, four residual middle layers
//! (`x + relu(conv(x))`) and the output layer, whose logits go through an integer softmax to a
//! soft-argmin disparity and a confidence. Each convolution keeps a ring of the three input rows
//! its kernel spans, so memory depends on the width only; an output row leaves the head six rows
//! after its descriptors went in (one per convolution) and [`HeadStream::finish`] flushes the rest.
//!
//! # Files
//! `sizing.rs`: the arena a stream takes and its candidate count; `weights.rs`: [`HeadWeights`],
//! checked once; `stream.rs`: [`HeadStream`], rows in and out; `projection.rs`: LayerNorm,
//! projections and the correlation; `convolution.rs`: the 3x3x3 convolutions and their
//! epilogue ([`ConvEpilogue`]); `right_view.rs`: the right view's disparity from the left
//! head's logits ([`right_view_row`], the one-pass left-right check).

mod convolution;
mod projection;
mod right_view;
mod sizing;
mod stream;
mod weights;

pub use crate::kernels::dispatch::ConvEpilogue;
pub use right_view::right_view_row;
pub use sizing::{arena_bytes, arena_bytes_for, arena_bytes_with, check_candidates};
pub use stream::HeadStream;
pub use weights::HeadWeights;

#[cfg(doc)]
use super::ids::HeadKind;

/// Fraction bits of the disparity and confidence outputs.
pub const OUT_FRAC_BITS: u32 = 8;

/// Token rows above and below an output row that it reads (one per convolution): a stream fed
/// the rows `r - ROW_REACH ..= r + ROW_REACH` of a map gives row `r` exactly as a stream over
/// the whole map does, save where the map's own edges pad it.
pub const ROW_REACH: usize = super::ids::HEAD_CONVS;

/// A [`HeadSink`] that passes on only the rows of `keep`, numbered in the map: for a stream
/// started at map row `first` (its rows count from 0 there).
pub struct KeptRows<'s, S: HeadSink> {
    /// Where the rows go.
    pub inner: &'s mut S,
    /// The map row the stream's row 0 is.
    pub first: usize,
    /// The map rows passed on.
    pub keep: core::ops::Range<usize>,
}

impl<S: HeadSink> HeadSink for KeptRows<'_, S> {
    fn row(&mut self, row: HeadRow<'_>) {
        let row_in_map = self.first.saturating_add(row.row);
        if self.keep.contains(&row_in_map) {
            self.inner.row(HeadRow { row: row_in_map, ..row });
        }
    }
}

/// One output row of the head.
#[derive(Debug, Clone, Copy)]
pub struct HeadRow<'r> {
    /// Token row.
    pub row: usize,
    /// Soft-argmin disparity per patch column, in patch columns, Q8 (`/ 256`).
    pub disparity_q8: &'r [u16],
    /// Largest candidate probability per patch column, Q8 (`256` = certain).
    pub confidence_q8: &'r [u16],
    /// Output-layer accumulators (`cols x candidates`); `i32::MIN` marks candidates outside
    /// the right view. Real logit = accumulator x the blob's `META_HEAD_LOGIT_SCALE`.
    pub logits: &'r [i32],
    /// Disparity candidates per cell (the stream's count).
    pub candidates: usize,
}

/// Receives the head's rows in order.
pub trait HeadSink {
    /// Called once per token row, top to bottom.
    fn row(&mut self, row: HeadRow<'_>);
}

/// Which view's disparity a head stream reads out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeadView {
    /// The left view's: the head on (left, right), as trained.
    Left,
    /// The right view's: the head on the mirrored pair (mirror(right), mirror(left)), its
    /// output mirrored back, so cell `q` of an output row is right cell `q`. The left-right
    /// check of the head compares the two. The export head takes the same (left, right)
    /// descriptor rows and mirrors them itself (each row's cells in reverse order); the native
    /// head takes the rows of the encoder's pass on the mirrored pair.
    Right,
}

#[cfg(test)]
mod tests;
