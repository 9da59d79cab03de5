//! The pipeline's leaf: saturating arithmetic for the arena sizes, the band buffer's rows, the
//! head's lag, the band plan's cut margin, the refinement's reach and the regions' alignment.
//! It imports no other module of the pipeline; every other module may import it.

use crate::config::{BAND_STRIDE_TOKEN_ROWS, BAND_TOKEN_ROWS, PATCH_H};
use crate::model::ids::HEAD_CONVS;
use crate::refine::sharpness::equalised_reach;
use crate::refine::RefineParams;

/// The larger of `a` and `b` (a `const fn`).
pub(super) const fn max(a: usize, b: usize) -> usize {
    if a > b {
        a
    } else {
        b
    }
}

/// Saturating sum (a `const fn` cannot use `Iterator::sum`).
pub(super) const fn sum(terms: &[usize]) -> usize {
    let mut total = 0usize;
    let mut i = 0;
    while i < terms.len() {
        total = total.saturating_add(terms[i]);
        i += 1;
    }
    total
}

/// Pixel rows of the band buffer for an image of `height` rows: the height of every band the
/// encoder sees (at most [`crate::config::BAND_ROWS`]).
pub const fn band_pixel_rows(height: usize) -> usize {
    let token_rows = height / PATCH_H;
    let rows = if token_rows < BAND_TOKEN_ROWS {
        token_rows
    } else {
        BAND_TOKEN_ROWS
    };
    rows * PATCH_H
}

/// Token rows the head's output trails its input by (one per convolution).
pub(super) const HEAD_LAG: usize = HEAD_CONVS;

/// Token rows a band's kept rows stay clear of the next band's first row: the plan cuts in the
/// middle of an overlap of at least `BAND_TOKEN_ROWS - BAND_STRIDE_TOKEN_ROWS` rows.
pub(super) const CUT_MARGIN: usize = (BAND_TOKEN_ROWS - BAND_STRIDE_TOKEN_ROWS) / 2;

/// View rows above and below a pixel row the stage reads: the refinement's reach, or the
/// equalisation's ([`equalised_reach`]).
pub(super) const fn stage_reach(params: &RefineParams, equalise: bool) -> usize {
    if equalise {
        equalised_reach(params)
    } else {
        params.reach()
    }
}

/// Alignment of every region's start: the encoder's scratch starts where the export pathway's
/// does, on a 16-byte boundary, so the assembly kernels' aligned paths apply (the M7's DSP
/// GEMMs fall back to the portable kernels on unaligned rows, half again as many instructions
/// for the whole pass).
pub(super) const REGION_ALIGN: usize = 16;

/// `bytes` rounded up to [`REGION_ALIGN`] (saturating).
pub(super) const fn aligned(bytes: usize) -> usize {
    match bytes.checked_add(REGION_ALIGN - 1) {
        Some(n) => n / REGION_ALIGN * REGION_ALIGN,
        None => usize::MAX,
    }
}
