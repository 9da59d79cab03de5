//! The readouts the board apps (`boards/`) and the firmware (`firmware-sim`) run, in one place so
//! every target computes the same numbers: the `bino` CLI's defaults (16 candidates, SGM
//! penalties 96 / 192 (`sgm::DEFAULT_PENALTIES`), left-right tolerance one patch column, the
//! head with its own left-right check) and the pixel refinement of the readout the pipeline's
//! rule picks for them ([`RefineInput::for_options`](crate::pipeline::RefineInput::for_options)),
//! and (feature `depth`) the example board's calibration and sector count of the obstacle
//! summary.
//!
//! The board runs the native pathway ([`OPTIONS`]): one encoder pass per band on (L, R), the
//! native head with its left-right check read from the same pass, fused with the census SGM
//! (`fuse-census+lr`). [`EXPORT_OPTIONS`] is the export pathway (two passes per band, the
//! descriptors for every readout, `fuse-all+lr`: `bino run --pathway export`), which the
//! firmware runs too. [`CENSUS_REFINE`] is the fast, encoder-free readout (`census+lr`,
//! `bino run`'s default): no weights, an arena the size of [`census_arena_bytes`], the same
//! for a band and for a whole frame of that width.
//!
//! The arenas here are sized for the shipped weights, whose token rows are independent: the
//! encoder runs a few token rows a pass ([`Passes::TokenRows`](crate::pipeline::Passes)), its
//! scratch one pass's work. Weights that need whole-band passes need
//! [`Pipeline::arena_bytes`](crate::pipeline::Pipeline::arena_bytes).
//!
//! ```
//! use bino_core::preset::{arena_bytes, export_arena_bytes, EXPORT_REFINE, OPTIONS, REFINE};
//! use bino_core::pipeline::{Pathway, RefineInput};
//! assert_eq!(OPTIONS.pathway, Pathway::Native);
//! assert_eq!(REFINE.input, RefineInput::FusedCensusLr);
//! assert_eq!(EXPORT_REFINE.input, RefineInput::FusedAllLr);
//! // The 48x160 band pair of the budget.
//! assert_eq!(arena_bytes(48, 160), 408_212);
//! assert_eq!(export_arena_bytes(48, 160), 428_297);
//! // A whole frame: each band's heads start afresh after the band's outputs and the encoder's
//! // scratch is one token row's, so what carries from band to band fits beside it: a frame
//! // needs the band's arena and the refinement's two-row ring, whatever the height.
//! assert_eq!(export_arena_bytes(120, 160), 428_937);
//! assert_eq!(export_arena_bytes(120, 160), export_arena_bytes(480, 160));
//! assert!(export_arena_bytes(120, 160) - export_arena_bytes(48, 160) < 1024);
//! assert!(arena_bytes(120, 160) - arena_bytes(48, 160) < 1024);
//! // The fast preset: a 160x120 frame in a fraction of one learned band's arena.
//! use bino_core::preset::census_arena_bytes;
//! assert_eq!(census_arena_bytes(120, 160), census_arena_bytes(480, 160));
//! assert!(census_arena_bytes(120, 160) * 5 < arena_bytes(48, 160));
//! // On wider views the head searches further and the refinement wider, as the host's
//! // commands do at that width; at 160 px they are the presets above.
//! use bino_core::preset::{census_refine_for_width, options_for_width, refine_for_width, CENSUS_REFINE};
//! assert_eq!(options_for_width(160), OPTIONS);
//! assert_eq!(refine_for_width(160), REFINE);
//! assert_eq!(census_refine_for_width(160), CENSUS_REFINE);
//! assert_eq!(options_for_width(320).head_candidates, 16);
//! assert!(refine_for_width(320).params.search > REFINE.params.search);
//! ```

use crate::config::head_candidates;
use crate::pipeline::{self, Options, Passes, Pathway, Refine};

/// The board's readout options: the native pathway, the head (its trained 12 candidates: a
/// 160-px view's disparities stay below 44 px) with its left-right check read from the same
/// pass, left-right tolerance one patch column (Q8 256); 16 candidates and SGM penalties 96 /
/// 192 (`sgm::DEFAULT_PENALTIES`) for the descriptor readouts of [`EXPORT_OPTIONS`].
pub const OPTIONS: Options = Options {
    pathway: Pathway::Native,
    max_cols: 16,
    penalties: crate::sgm::DEFAULT_PENALTIES,
    lr_max_diff_q8: 256,
    head: true,
    head_lr: true,
    head_candidates: crate::config::HEAD_MAX_DISP,
};

/// The board's pixel refinement: the default parameters on the readout the pipeline's rule
/// picks for [`OPTIONS`] (fuse-census+lr: the native head and the census SGM
/// ([`crate::census`]) fused by their own left-right checks).
pub const REFINE: Refine = Refine::for_options(&OPTIONS);

/// Arena bytes a `height x width` band pair needs with [`OPTIONS`] and [`REFINE`].
pub const fn arena_bytes(height: usize, width: usize) -> usize {
    pipeline::arena_bytes_with(height, width, &OPTIONS, Some(&REFINE), Passes::TokenRows)
}

/// [`OPTIONS`] on the export pathway: both encoder passes, (L, L) and (R, R), the descriptor
/// readouts, the shared head and its check on the mirrored pair.
pub const EXPORT_OPTIONS: Options = Options {
    pathway: Pathway::Export,
    ..OPTIONS
};

/// The pixel refinement of the export pathway's readout (fuse-all+lr: the shared head fused with
/// the census SGM, then with the descriptor SGM, by their own left-right checks).
pub const EXPORT_REFINE: Refine = Refine::for_options(&EXPORT_OPTIONS);

/// Arena bytes a `height x width` band pair needs with [`EXPORT_OPTIONS`] and [`EXPORT_REFINE`].
pub const fn export_arena_bytes(height: usize, width: usize) -> usize {
    pipeline::arena_bytes_with(height, width, &EXPORT_OPTIONS, Some(&EXPORT_REFINE), Passes::TokenRows)
}

/// The fast preset's refinement: the census SGM with its own check (`census+lr`, refined), run
/// with [`OPTIONS`]'s search range and tolerance by [`pipeline::run_census`]: no encoder, no
/// weights.
pub const CENSUS_REFINE: Refine = Refine::of(pipeline::RefineInput::CensusLr);

/// Arena bytes a `height x width` pair needs with [`OPTIONS`] and [`CENSUS_REFINE`]; the same for
/// every height above one band.
pub const fn census_arena_bytes(height: usize, width: usize) -> usize {
    pipeline::census_arena_bytes(height, width, &OPTIONS, Some(&CENSUS_REFINE))
}

/// [`OPTIONS`] on views `width` px wide: the head (and the census SGM of either preset)
/// searching [`head_candidates`] of that width, the host's commands' rule (`bino run
/// --profile native` on views that wide); [`OPTIONS`] itself up to 240 px.
pub const fn options_for_width(width: usize) -> Options {
    Options {
        head_candidates: head_candidates(width),
        ..OPTIONS
    }
}

/// [`REFINE`] on views `width` px wide: its search radius following the width
/// ([`Refine::for_width`], the host's commands' rule); [`REFINE`] itself below 200 px.
pub const fn refine_for_width(width: usize) -> Refine {
    Refine::for_width(REFINE.input, width)
}

/// [`CENSUS_REFINE`] on views `width` px wide, as [`refine_for_width`].
pub const fn census_refine_for_width(width: usize) -> Refine {
    Refine::for_width(CENSUS_REFINE.input, width)
}

/// Arena bytes the learned preset needs on a whole `height x width` frame with the options and
/// the refinement of that width ([`options_for_width`], [`refine_for_width`]); [`arena_bytes`]
/// below 200 px.
pub const fn arena_bytes_for_width(height: usize, width: usize) -> usize {
    let (opts, refine) = (options_for_width(width), refine_for_width(width));
    pipeline::arena_bytes_with(height, width, &opts, Some(&refine), Passes::TokenRows)
}

/// Arena bytes the fast preset needs on a `height x width` frame with the options and the
/// refinement of that width; [`census_arena_bytes`] below 200 px.
pub const fn census_arena_bytes_for_width(height: usize, width: usize) -> usize {
    pipeline::census_arena_bytes(
        height,
        width,
        &options_for_width(width),
        Some(&census_refine_for_width(width)),
    )
}

/// Column sectors of the obstacle summary.
#[cfg(feature = "depth")]
pub const SECTORS: usize = 8;

/// The example stereo board: a 640-px-wide sensor read at the band's profile width (160 px:
/// scale 4), f = 500 px (a 65 degree field of view), principal point at the centre, 60 mm
/// baseline. A real board replaces it with its own calibration.
#[cfg(feature = "depth")]
pub const CALIBRATION: crate::depth::Calibration = crate::depth::Calibration {
    focal_px: 500.0,
    principal_x_px: 320.0,
    baseline_mm: 60.0,
    sensor_width_px: 640,
};
