//! Arena sizing: the `const fn`s firmware sizes its static arena with, and the private sums
//! the driver and the streams cut the arena by (saturating, so an absurd size is never a small
//! wrong one).

use super::api::{Options, Pathway, Refine, RefineInput};
use super::head_check::{check_rows_bytes, fusion_bytes, HEAD_CHECK_ROWS};
use super::layout::{aligned, band_pixel_rows, max, sum};
use super::{census_stage, refine_stage};
use crate::arena::ALIGN_SLACK;
use crate::config::{CELL_W, DIM, PATCH_H};
use crate::model::encoder;
use crate::model::head;
use crate::model::ids::HeadKind;
use crate::sgm::state_len;
#[cfg(doc)]
use {super::head_check::HeadCheck, super::Pipeline, crate::sgm::Penalties, crate::Error};

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
        Pathway::Native => native_arena_bytes(height, width, opts, refine),
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
        Some(r) => refine_parts(height, width, r, false),
        None => (0, 0),
    };
    sum(&[pixels, census, state, scratch])
}

/// Bytes of the refinement's buffers in a run of a `height x width` pair on `pathway`: its
/// state kept across bands (two token rows; with several bands a ring of view rows where the
/// readout's rows trail the band: the export pathway's head readouts) and its row scratch
/// (census codes and the output row). 14,085 at 48x160 with the defaults (the equalisation's 13 smoothed rows
/// included; 12,005 without); 22,405 for a taller image at width 160 refining the export
/// pathway's head readout (the 26-row view ring).
pub const fn refine_bytes(height: usize, width: usize, pathway: Pathway, refine: &Refine) -> usize {
    let (state, scratch) = refine_parts(height, width, refine, trails_band(pathway));
    state.saturating_add(scratch)
}

/// Whether a pathway's refined rows trail the band that made them into the next one: the
/// export pathway's head streams run across bands ([`RefineInput::lag`]); the native head
/// ends with each band, and the census and matching readouts never trail.
pub(super) const fn trails_band(pathway: Pathway) -> bool {
    matches!(pathway, Pathway::Export)
}

/// The refinement's (state, row scratch) bytes; `trails`: whether its readout's rows trail
/// the band ([`trails_band`]).
pub(super) const fn refine_parts(height: usize, width: usize, refine: &Refine, trails: bool) -> (usize, usize) {
    let ring = if height <= band_pixel_rows(height) {
        0
    } else {
        refine_stage::ring_rows(refine.reach(), if trails { refine.input.lag() } else { 0 })
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
        Some(r) => refine_parts(height, width, r, true),
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

/// Arena bytes of the check's right-view row and mask row (0 without the check), rounded up
/// to [`REGION_ALIGN`].
pub(super) const fn native_check_bytes(cols: usize, head_lr: bool) -> usize {
    if head_lr {
        aligned(check_rows_bytes(cols, 1))
    } else {
        0
    }
}

/// Arena bytes of a native run of a `height x width` pair (saturating, like every sizing helper).
///
/// Each band's head stream lives in the encoder's scratch after the pass's tokens and ends
/// with the band, so only the check's rows, the census stage and the refinement's state sit
/// outside it: the size depends on the band and the width, and on the height only through the
/// refinement's ring (one band or several).
pub(super) const fn native_arena_bytes(height: usize, width: usize, opts: &Options, refine: Option<&Refine>) -> usize {
    let band_rows = band_pixel_rows(height);
    let cols = width / CELL_W;
    let pixels = band_rows.saturating_mul(width).saturating_mul(2);
    let tokens = (band_rows / PATCH_H).saturating_mul(cols).saturating_mul(2 * DIM);
    let encoder = encoder::arena_bytes(band_rows, width);
    let head = aligned(head::arena_bytes_with(HeadKind::Native, cols, opts.head_candidates));
    let (state, scratch) = match refine {
        Some(r) => refine_parts(height, width, r, false),
        None => (0, 0),
    };
    let state = aligned(state);
    let check = native_check_bytes(cols, opts.head_lr).saturating_add(native_census_bytes(width, opts, refine));
    let after = sum(&[tokens, head, scratch]);
    sum(&[pixels, check, state, max(encoder, after)])
}

/// Arena bytes of the census stage, rounded up to [`REGION_ALIGN`]: only when the refinement
/// reads the fused readout ([`RefineInput::FusedCensusLr`]).
pub(super) const fn native_census_bytes(width: usize, opts: &Options, refine: Option<&Refine>) -> usize {
    match refine {
        Some(r) if matches!(r.input, RefineInput::FusedCensusLr) => aligned(census_stage::bytes(
            width,
            opts.head_candidates,
            census_stage::RING_ROWS,
        )),
        _ => 0,
    }
}
