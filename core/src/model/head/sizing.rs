//! What a head stream takes: its arena bytes (per patch column, the rings of the six
//! convolutions' input rows, the projected rows and the logits; then fixed buffers) and the
//! disparity candidates it searches.

use super::super::ids::{HeadKind, HEAD_CONVS};
use crate::arena::ALIGN_SLACK;
use crate::config::{HEAD_CANDIDATES_LIMIT, HEAD_GROUPS, HEAD_HIDDEN, HEAD_MAX_DISP};
use crate::Error;

/// Kernel positions of a 3x3x3 convolution.
pub(super) const TAPS: usize = 27;
/// Descriptor cells projected together.
pub(super) const CELL_BLOCK: usize = 8;

pub(super) const fn max(a: usize, b: usize) -> usize {
    if a > b {
        a
    } else {
        b
    }
}

/// Input channels of convolution `layer`.
pub(super) const fn conv_inputs(layer: usize) -> usize {
    if layer == 0 {
        HEAD_GROUPS
    } else {
        HEAD_HIDDEN
    }
}

/// Output channels of convolution `layer`.
pub(super) const fn conv_outputs(layer: usize) -> usize {
    if layer == HEAD_CONVS - 1 {
        1
    } else {
        HEAD_HIDDEN
    }
}

/// Bytes of one ring row of convolution `layer`'s input, for `cols` patch columns and
/// `candidates` disparities.
pub(super) const fn ring_row(layer: usize, cols: usize, candidates: usize) -> usize {
    cols.saturating_mul(candidates * conv_inputs(layer))
}

/// Bytes per patch column of every ring (three rows per convolution).
pub(super) const fn ring_bytes_per_col(candidates: usize) -> usize {
    let mut bytes = 0;
    let mut layer = 0;
    while layer < HEAD_CONVS {
        bytes += 3 * candidates * conv_inputs(layer);
        layer += 1;
    }
    bytes
}

/// Checks a head stream's number of disparity candidates (1 to [`HEAD_CANDIDATES_LIMIT`]).
pub const fn check_candidates(candidates: usize) -> Result<(), Error> {
    if candidates == 0 || candidates > HEAD_CANDIDATES_LIMIT {
        Err(Error::Candidates {
            requested: candidates,
            max: HEAD_CANDIDATES_LIMIT,
        })
    } else {
        Ok(())
    }
}

/// Arena bytes of the export head's stream over `cols` patch columns (descriptor map width):
/// [`arena_bytes_for`] of [`HeadKind::Export`].
pub const fn arena_bytes(cols: usize) -> usize {
    arena_bytes_for(HeadKind::Export, cols)
}

/// Arena bytes of a `head` stream over `cols` patch columns with the default
/// [`HEAD_MAX_DISP`] candidates: [`arena_bytes_with`].
pub const fn arena_bytes_for(head: HeadKind, cols: usize) -> usize {
    arena_bytes_with(head, cols, HEAD_MAX_DISP)
}

/// Arena bytes of a `head` stream over `cols` patch columns searching `candidates`
/// disparities. Saturates at `usize::MAX` for widths no memory holds, so such a stream is
/// [`Error::ArenaTooSmall`]; a count [`check_candidates`] refuses is sized as the limit.
pub const fn arena_bytes_with(head: HeadKind, cols: usize, candidates: usize) -> usize {
    let d = if candidates > HEAD_CANDIDATES_LIMIT {
        HEAD_CANDIDATES_LIMIT
    } else {
        candidates
    };
    let proj = head.proj_dim();
    let acc = max(d * HEAD_HIDDEN, CELL_BLOCK * proj);
    let per_col = ring_bytes_per_col(d)
        + 2 * proj // projected left and right rows
        + d * 4 // output logits
        + 2 * 2; // disparity and confidence (u16)
    let fixed = CELL_BLOCK * head.input_dim() // normalised input cells
        + d * TAPS * HEAD_HIDDEN // one column's gathered kernel inputs
        + acc * 4
        + 2 * ALIGN_SLACK // accumulators and logits (i32, aligned)
        + 2; // disparity and confidence (u16, aligned)
    cols.saturating_mul(per_col).saturating_add(fixed)
}

/// Offset in the rings of convolution `layer`'s three input rows.
pub(super) fn ring_base(layer: usize, cols: usize, candidates: usize) -> usize {
    (0..layer).map(|l| 3 * ring_row(l, cols, candidates)).sum()
}

/// The ring slot of convolution `layer`'s input row `row` (empty if the rings are short).
pub(super) fn ring_slot_mut(rings: &mut [i8], cols: usize, candidates: usize, layer: usize, row: usize) -> &mut [i8] {
    let len = ring_row(layer, cols, candidates);
    let start = ring_base(layer, cols, candidates) + (row % 3) * len;
    rings.get_mut(start..start + len).unwrap_or(&mut [])
}
