//! Arena sizing: the `const fn`s firmware sizes its static arena with, and the private sums
//! the driver and the streams cut the arena by (saturating, so an absurd size is never a small
//! wrong one).

use super::api::{Options, Pathway, Refine, RefineInput};
use super::{census_stage, native, refine_stage};
use crate::arena::ALIGN_SLACK;
use crate::config::{BAND_TOKEN_ROWS, CELL_W, DIM, PATCH_H};
use crate::model::encoder;
use crate::model::head;
use crate::model::ids::{HeadKind, HEAD_CONVS};
use crate::sgm::state_len;
#[cfg(doc)]
use {super::head_check::HeadCheck, super::Pipeline, crate::sgm::Penalties, crate::Error};

pub(super) const fn max(a: usize, b: usize) -> usize {
    if a > b {
        a
    } else {
        b
    }
}

/// Pixel rows of the band buffer for an image of `height` rows.
pub(super) const fn band_pixel_rows(height: usize) -> usize {
    let token_rows = height / PATCH_H;
    let rows = if token_rows < BAND_TOKEN_ROWS {
        token_rows
    } else {
        BAND_TOKEN_ROWS
    };
    rows * PATCH_H
}

/// Arena bytes of the matching, SGM and left-right state for `cols` patch columns
/// (saturating, like every sizing helper here).
pub(super) const fn matching_bytes(cols: usize, max_cols: usize, guided: bool) -> usize {
    let volume_row = state_len(cols, max_cols);
    let words = cols.saturating_mul(4).saturating_add(ALIGN_SLACK); // one u32 row
    let halves = volume_row.saturating_mul(2).saturating_add(1); // one u16 cost row
    let sums = volume_row.saturating_mul(4).saturating_add(ALIGN_SLACK); // one u32 cost row
    let disparity = cols.saturating_mul(2).saturating_add(1); // one u16 disparity row
    sum(&[
        words.saturating_mul(2),                                         // inverse norms, left and right
        halves.saturating_mul(2),                                        // cost rows, left and right view
        halves.saturating_mul(2).saturating_add(sums).saturating_mul(2), // two SGM streams
        disparity.saturating_mul(4),                                     // WTA and SGM rows, both views
        cols.saturating_mul(2),                                          // left-right masks
        if guided { cols.saturating_mul(4) } else { 0 },                 // SGM guides: rows and previous rows
    ])
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

/// Rows of left head disparities kept for the check: a whole band (one band: the mirrored
/// head runs after the left one, on the same arena), or more than the mirrored head trails
/// the left one by when both stream side by side (several bands: one row per convolution).
pub(super) const HEAD_CHECK_ROWS: usize = max(BAND_TOKEN_ROWS, HEAD_CONVS + 1);

/// Arena bytes of the head's left-right check: the left rows kept, one mask row, the fused
/// readout's state ([`fusion_bytes`]), and for several bands (`streaming`) the mirrored head's
/// own stream.
const fn head_check_bytes(cols: usize, candidates: usize, streaming: bool) -> usize {
    let mirror = if streaming {
        head::arena_bytes_with(HeadKind::Export, cols, candidates)
    } else {
        0
    };
    sum(&[
        mirror,
        check_rows_bytes(cols, HEAD_CHECK_ROWS),
        fusion_bytes(cols, HEAD_CHECK_ROWS),
    ])
}

/// Arena bytes of the fused readout's state beside a [`HeadCheck`] of `rows` rows: as many rows
/// of the left head's confidence and of SGM disparities (u16, aligned each) and the SGM's masks,
/// and the fused row (u16, aligned) and its mask.
pub(super) const fn fusion_bytes(cols: usize, rows: usize) -> usize {
    let cells = cols.saturating_mul(rows);
    sum(&[
        cells.saturating_mul(2).saturating_add(1),
        cells.saturating_mul(2).saturating_add(1),
        cells,
        cols.saturating_mul(2).saturating_add(1),
        cols,
    ])
}

/// Arena bytes of a [`HeadCheck`] keeping `rows` rows of `cols` left disparities (u16,
/// aligned) and its mask row.
pub(super) const fn check_rows_bytes(cols: usize, rows: usize) -> usize {
    sum(&[cols.saturating_mul(rows).saturating_mul(2).saturating_add(1), cols])
}

/// What sizes an export-pathway run's readout streams: the head's disparity candidates,
/// whether it is checked ([`Options::head_lr`]), whether the SGM is guided
/// ([`Penalties::edge`]: two guide rows and two previous ones), and whether the census SGM
/// runs beside it (the refinement reads [`RefineInput::FusedAllLr`]).
#[derive(Clone, Copy)]
pub(super) struct ReadoutShape {
    pub(super) candidates: usize,
    pub(super) lr: bool,
    pub(super) guided: bool,
    pub(super) census: bool,
}

impl ReadoutShape {
    pub(super) const fn of(opts: &Options, refine: Option<&Refine>) -> Self {
        let lr = opts.head && opts.head_lr;
        ReadoutShape {
            candidates: opts.head_candidates,
            lr,
            guided: opts.penalties.guided(),
            census: lr && uses_census(refine),
        }
    }

    /// The default head ([`HEAD_MAX_DISP`](crate::config::HEAD_MAX_DISP) candidates).
    const fn trained(lr: bool) -> Self {
        ReadoutShape {
            candidates: crate::config::HEAD_MAX_DISP,
            lr,
            guided: false,
            census: false,
        }
    }
}

/// Whether the refinement reads the export pathway's census fusion.
const fn uses_census(refine: Option<&Refine>) -> bool {
    matches!(
        refine,
        Some(Refine {
            input: RefineInput::FusedAllLr,
            ..
        })
    )
}

/// Arena bytes of the readout streams (with the head, and its check when `head.lr`; the check
/// needs a second head stream only when `streaming` several bands; the census stage when
/// `head.census`, its ring as long as the check's).
pub(super) const fn stream_bytes(cols: usize, max_cols: usize, head: ReadoutShape, streaming: bool) -> usize {
    let check = if head.lr {
        head_check_bytes(cols, head.candidates, streaming)
    } else {
        0
    };
    let census = if head.census {
        census_stage::bytes(cols.saturating_mul(CELL_W), head.candidates, HEAD_CHECK_ROWS)
    } else {
        0
    };
    let stream = head::arena_bytes_with(HeadKind::Export, cols, head.candidates);
    sum(&[matching_bytes(cols, max_cols, head.guided), stream, check, census])
}

/// Arena bytes the pipeline needs for a `height x width` pair with `max_cols` candidates
/// (the head included). Firmware sizes its static arena with it.
///
/// Saturates at `usize::MAX` where the size does not fit a `usize` (absurd widths or candidate
/// counts): no arena is that large, so [`Pipeline::run`] rejects such a run as
/// [`Error::ArenaTooSmall`] (or earlier, as [`Error::TooWide`] / [`Error::Candidates`]); the
/// result is never a small wrong size.
pub const fn arena_bytes(height: usize, width: usize, max_cols: usize) -> usize {
    arena_bytes_of(height, width, max_cols, ReadoutShape::trained(false), None)
}

/// [`arena_bytes`] with the head's left-right check ([`Options::head_lr`]): a second head
/// stream.
pub const fn arena_bytes_head_lr(height: usize, width: usize, max_cols: usize) -> usize {
    arena_bytes_of(height, width, max_cols, ReadoutShape::trained(true), None)
}

/// The arena bytes a run with `opts` needs: on the export pathway [`arena_bytes`] or
/// [`arena_bytes_head_lr`]; on the native one the pixel band, the native head (two with its
/// check) and the encoder's scratch, which holds the band's pair tokens after each pass.
pub const fn arena_bytes_for(height: usize, width: usize, opts: &Options) -> usize {
    arena_bytes_run(height, width, opts, None)
}

/// The arena bytes [`Pipeline::run_refined`] needs with `opts` and `refine`. For one band
/// (images up to 48 rows) it equals [`arena_bytes_for`] wherever the refinement fits in the
/// encoder's scratch beside the streams, as at 48x160; with several bands it adds
/// [`refine_bytes`].
pub const fn arena_bytes_refined(height: usize, width: usize, opts: &Options, refine: &Refine) -> usize {
    arena_bytes_run(height, width, opts, Some(refine))
}

/// The arena bytes of a run with `opts`, refined when `refine` is given, on either pathway.
pub(super) const fn arena_bytes_run(height: usize, width: usize, opts: &Options, refine: Option<&Refine>) -> usize {
    if let Some(r) = refine {
        if r.input.census_only() {
            return census_arena_bytes(height, width, opts, refine);
        }
    }
    match opts.pathway {
        Pathway::Export => arena_bytes_of(height, width, opts.max_cols, ReadoutShape::of(opts, refine), refine),
        Pathway::Native => native::arena_bytes(height, width, opts, refine),
    }
}

/// Census rows the encoder-free run keeps: each goes on (sink, refinement) as soon as it is
/// computed.
pub(super) const CENSUS_RING_ROWS: usize = 1;

/// Arena bytes of [`run_census`](super::run_census) for a `height x width` pair with `opts` (the
/// census searches `4 x opts.head_candidates` pixel disparities,
/// [`crate::census::disparities`]), refined when `refine` is given: the pixel band, the census
/// stage and the refinement, no encoder. Depends on the band and the width, never on the
/// height.
pub const fn census_arena_bytes(height: usize, width: usize, opts: &Options, refine: Option<&Refine>) -> usize {
    let pixels = band_pixel_rows(height).saturating_mul(width).saturating_mul(2);
    let census = census_stage::bytes(width, opts.head_candidates, CENSUS_RING_ROWS);
    let (state, scratch) = match refine {
        Some(r) => refine_parts(height, width, r),
        None => (0, 0),
    };
    sum(&[pixels, census, state, scratch])
}

/// Bytes of the refinement's buffers in a run of a `height x width` pair: its state kept
/// across bands (two token rows; with several bands and a head input a ring of view rows) and
/// its row scratch (census codes and the output row). 14,085 at 48x160 with the defaults (the
/// equalisation's 13 smoothed rows included; 12,005 without); 22,405 for a taller image at width
/// 160 refining a head readout (the 26-row view ring).
pub const fn refine_bytes(height: usize, width: usize, refine: &Refine) -> usize {
    let (state, scratch) = refine_parts(height, width, refine);
    state.saturating_add(scratch)
}

/// The refinement's (state, row scratch) bytes.
pub(super) const fn refine_parts(height: usize, width: usize, refine: &Refine) -> (usize, usize) {
    let ring = if height <= band_pixel_rows(height) {
        0
    } else {
        refine_stage::ring_rows(refine.reach(), refine.input.lag())
    };
    (
        refine_stage::state_bytes(width, ring),
        refine_stage::scratch_bytes(width, &refine.params, refine.equalise),
    )
}

const fn arena_bytes_of(
    height: usize,
    width: usize,
    max_cols: usize,
    head: ReadoutShape,
    refine: Option<&Refine>,
) -> usize {
    let band_rows = band_pixel_rows(height);
    let cols = width / CELL_W;
    let pixels = band_rows.saturating_mul(width).saturating_mul(2);
    let descriptors = (band_rows / PATCH_H).saturating_mul(cols).saturating_mul(DIM);
    let encoder = encoder::arena_bytes(band_rows, width);
    let (state, scratch) = match refine {
        Some(r) => refine_parts(height, width, r),
        None => (0, 0),
    };
    if height <= band_rows {
        let streams = stream_bytes(cols, max_cols, head, false);
        let after = sum(&[descriptors, streams, state, scratch]);
        sum(&[pixels, descriptors, max(encoder, after)])
    } else {
        let streams = stream_bytes(cols, max_cols, head, true);
        sum(&[
            pixels,
            descriptors,
            streams,
            state,
            max(encoder, descriptors.saturating_add(scratch)),
        ])
    }
}
