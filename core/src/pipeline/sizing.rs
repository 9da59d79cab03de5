//! Arena sizing: the `const fn`s firmware sizes its static arena with, and the private sums
//! the driver and the streams cut the arena by (saturating, so an absurd size is never a small
//! wrong one).

use super::api::{Options, Passes, Pathway, Refine, RefineInput};
use super::head_check::{check_rows_bytes, fusion_bytes, HEAD_CHECK_ROWS};
use super::layout::{aligned, band_pixel_rows, max, sum};
use super::row_buffers::row_bytes;
use super::row_passes::scratch_bytes;
use super::{census_stage, refine_stage};
use crate::config::{CELL_W, DIM, PATCH_H};
use crate::model::head;
use crate::model::ids::HeadKind;
use crate::sgm::state_len;
#[cfg(doc)]
use {super::head_check::HeadCheck, super::Pipeline, crate::sgm::Penalties, crate::Error};

/// Arena bytes of the state the matching readouts carry from row to row for `cols` patch
/// columns: both views' SGM aggregates (vertical and diagonal) and, guided, their previous
/// rows' guides (saturating, like every sizing helper here). A row's own buffers are
/// [`row_bytes`].
pub(super) const fn matching_state_bytes(cols: usize, max_cols: usize, guided: bool) -> usize {
    let halves = state_len(cols, max_cols).saturating_mul(2).saturating_add(1); // one u16 row
    sum(&[
        halves.saturating_mul(4),                        // two SGM streams' aggregates
        if guided { cols.saturating_mul(2) } else { 0 }, // their previous rows' guides
    ])
}

/// Arena bytes of the head's left-right check: the left rows kept, one mask row and the fused
/// readout's state ([`fusion_bytes`]), for a band's kept rows. The mirrored head reruns each
/// band on the left head's stream ([`band_head_bytes`]).
const fn head_check_bytes(cols: usize) -> usize {
    sum(&[
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

/// Arena bytes of the export pathway's resident readouts, what carries from row to row and
/// band to band: the SGMs' state, the census stage's when `head.census` (its ring as long as
/// the check's) and the head's check when `head.lr`; bounded by the width, never the height.
/// A row's buffers ([`row_bytes`]) and the head ([`band_head_bytes`]) are each band's.
pub(super) const fn resident_bytes(cols: usize, max_cols: usize, head: ReadoutShape) -> usize {
    let check = if head.lr { head_check_bytes(cols) } else { 0 };
    let census = if head.census {
        census_stage::resident_bytes(cols.saturating_mul(CELL_W), head.candidates, HEAD_CHECK_ROWS)
    } else {
        0
    };
    sum(&[matching_state_bytes(cols, max_cols, head.guided), check, census])
}

/// Arena bytes of a band's row buffers of the export pathway's readouts ([`row_bytes`] with
/// the census stage's row scratch when `head.census`).
pub(super) const fn readout_row_bytes(cols: usize, max_cols: usize, head: ReadoutShape) -> usize {
    let census = if head.census {
        Some((cols.saturating_mul(CELL_W), head.candidates))
    } else {
        None
    };
    row_bytes(cols, max_cols, head.guided, census)
}

/// Arena bytes of a band's export head stream (rounded up to [`REGION_ALIGN`]): started afresh
/// on each band's rows in the encoder's scratch after the band's right descriptors, it ends
/// with the band, the mirrored head of the check rerunning the band on it.
pub(super) const fn band_head_bytes(cols: usize, candidates: usize) -> usize {
    aligned(head::arena_bytes_with(HeadKind::Export, cols, candidates))
}

/// Arena bytes the pipeline needs for a `height x width` pair with `max_cols` candidates
/// (the head included). Firmware sizes its static arena with it. It depends on the band and
/// the width: one band's for images up to 48 rows, and for every taller one the same, a
/// little more (what carries from band to band beside the encoder's scratch).
///
/// Saturates at `usize::MAX` where the size does not fit a `usize` (absurd widths or candidate
/// counts): no arena is that large, so [`Pipeline::run`] rejects such a run as
/// [`Error::ArenaTooSmall`] (or earlier, as [`Error::TooWide`] / [`Error::Candidates`]); the
/// result is never a small wrong size.
pub const fn arena_bytes(height: usize, width: usize, max_cols: usize) -> usize {
    arena_bytes_of(
        height,
        width,
        max_cols,
        ReadoutShape::trained(false),
        None,
        Passes::Band,
    )
}

/// [`arena_bytes`] with the head's left-right check ([`Options::head_lr`]): the left rows
/// it keeps and the fused readout's (the mirrored head reruns each band on the head's stream).
pub const fn arena_bytes_head_lr(height: usize, width: usize, max_cols: usize) -> usize {
    arena_bytes_of(height, width, max_cols, ReadoutShape::trained(true), None, Passes::Band)
}

/// The arena bytes a run with `opts` needs: on the export pathway [`arena_bytes`] or
/// [`arena_bytes_head_lr`]; on the native one the pixel band, the check's rows and the
/// encoder's scratch, which holds the band's pair tokens and its head after each pass.
pub const fn arena_bytes_for(height: usize, width: usize, opts: &Options) -> usize {
    arena_bytes_with(height, width, opts, None, Passes::Band)
}

/// The arena bytes [`Pipeline::run_refined`] needs with `opts` and `refine`. For one band
/// (images up to 48 rows) it equals [`arena_bytes_for`] wherever the refinement fits in the
/// encoder's scratch beside the streams, as at 48x160; with several bands it adds the
/// refinement's state ([`refine_bytes`] less the row scratch, which the encoder's scratch
/// holds).
pub const fn arena_bytes_refined(height: usize, width: usize, opts: &Options, refine: &Refine) -> usize {
    arena_bytes_with(height, width, opts, Some(refine), Passes::Band)
}

/// The arena bytes of a run with `opts`, refined when `refine` is given, on either pathway, its
/// encoder passes by `passes`. The other sizes here are [`Passes::Band`]'s, which fit any
/// weights; weights whose token rows are independent run in the smaller
/// [`Passes::TokenRows`] size ([`Pipeline::arena_bytes`] answers for a blob).
pub const fn arena_bytes_with(
    height: usize,
    width: usize,
    opts: &Options,
    refine: Option<&Refine>,
    passes: Passes,
) -> usize {
    if let Some(r) = refine {
        if r.input.census_only() {
            return census_arena_bytes(height, width, opts, refine);
        }
    }
    match opts.pathway {
        Pathway::Export => {
            let head = ReadoutShape::of(opts, refine);
            arena_bytes_of(height, width, opts.max_cols, head, refine, passes)
        }
        Pathway::Native => native_arena_bytes(height, width, opts, refine, passes),
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

/// Bytes of the refinement's buffers in a run of a `height x width` pair, on either pathway:
/// its state kept across bands (two token rows; with several bands and a reach beyond the
/// band plan's margin a ring of view rows) and its row scratch (census codes and the output
/// row). 14,165 at 48x160 with the defaults (the equalisation's 13 smoothed rows included;
/// 12,085 without); 14,805 for a taller image at width 160 (the equalised reach's 2-row view
/// ring). Every readout's rows leave with the band that made them, the heads' included.
pub const fn refine_bytes(height: usize, width: usize, refine: &Refine) -> usize {
    let (state, scratch) = refine_parts(height, width, refine);
    state.saturating_add(scratch)
}

/// The refinement's (state, row scratch) bytes.
pub(super) const fn refine_parts(height: usize, width: usize, refine: &Refine) -> (usize, usize) {
    let ring = if height <= band_pixel_rows(height) {
        0
    } else {
        refine_stage::ring_rows(refine.reach(), 0)
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
    passes: Passes,
) -> usize {
    let band_rows = band_pixel_rows(height);
    let cols = width / CELL_W;
    let pixels = band_rows.saturating_mul(width).saturating_mul(2);
    let descriptors = (band_rows / PATCH_H).saturating_mul(cols).saturating_mul(DIM);
    let encoder = scratch_bytes(passes, band_rows, width, cols.saturating_mul(DIM));
    let (state, scratch) = match refine {
        Some(r) => refine_parts(height, width, r),
        None => (0, 0),
    };
    let resident = resident_region(cols, max_cols, head, state);
    let rows = readout_row_bytes(cols, max_cols, head);
    let band = sum(&[descriptors, band_head_bytes(cols, head.candidates), rows, scratch]);
    if height <= band_rows {
        sum(&[pixels, descriptors, max(encoder, band.saturating_add(resident))])
    } else {
        sum(&[pixels, descriptors, resident, max(encoder, band)])
    }
}

/// Arena bytes of the export pathway's resident region: [`resident_bytes`] and the
/// refinement's `state` after them, rounded up to [`REGION_ALIGN`] so that what follows (the
/// encoder's scratch, or with one band the head stream) starts aligned.
pub(super) const fn resident_region(cols: usize, max_cols: usize, head: ReadoutShape, state: usize) -> usize {
    aligned(resident_bytes(cols, max_cols, head).saturating_add(state))
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
pub(super) const fn native_arena_bytes(
    height: usize,
    width: usize,
    opts: &Options,
    refine: Option<&Refine>,
    passes: Passes,
) -> usize {
    let band_rows = band_pixel_rows(height);
    let cols = width / CELL_W;
    let pixels = band_rows.saturating_mul(width).saturating_mul(2);
    let row_len = cols.saturating_mul(2 * DIM);
    let tokens = (band_rows / PATCH_H).saturating_mul(row_len);
    let encoder = scratch_bytes(passes, band_rows, width, row_len);
    let head = aligned(head::arena_bytes_with(HeadKind::Native, cols, opts.head_candidates));
    let (state, scratch) = match refine {
        Some(r) => refine_parts(height, width, r),
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::MAX_HEIGHT;
    use crate::preset::{EXPORT_OPTIONS, EXPORT_REFINE};

    /// The export pathway's arena depends on the width, not the height: one band's, and for
    /// every taller image that plus what carries from band to band beside the encoder's scratch
    /// (the SGMs' state, the head's check, the census stage's state and rows, the refinement's
    /// state), each band's head and row buffers inside it; at 160 px within the 512 KiB target.
    #[test]
    fn the_export_arena_does_not_grow_with_the_height() {
        for input in [RefineInput::FusedAllLr, RefineInput::HeadLr, RefineInput::SgmLr] {
            let refine = Refine { input, ..EXPORT_REFINE };
            let size = |h: usize, w: usize| arena_bytes_with(h, w, &EXPORT_OPTIONS, Some(&refine), Passes::Band);
            for width in [32, 160, 320] {
                let (band, frame) = (size(48, width), size(52, width));
                let cols = width / CELL_W;
                let shape = ReadoutShape::of(&EXPORT_OPTIONS, Some(&refine));
                let state = refine_parts(52, width, &refine).0;
                let resident = resident_region(cols, EXPORT_OPTIONS.max_cols, shape, state);
                assert_eq!(frame, band + resident, "{} at {width}", input.name());
                for height in (52..=MAX_HEIGHT).step_by(4) {
                    assert_eq!(size(height, width), frame, "{} {width}x{height}", input.name());
                }
            }
            assert!(size(120, 160) <= 512 * 1024, "{}: {}", input.name(), size(120, 160));
        }
        // The default readout's 160 px frame: the band's and 26,464 B (the census stage 16.9 KB,
        // both SGMs' aggregates 5.1 KB, the check 3.5 KB, the refinement's state 0.9 KB).
        assert_eq!(
            arena_bytes_with(120, 160, &EXPORT_OPTIONS, Some(&EXPORT_REFINE), Passes::Band),
            486_918 + 26_464
        );
    }
}
