//! The readouts the firmware (`firmware-sim`) and the board apps (`boards/`) run, in one place so
//! every target computes the same numbers: the `bino` CLI's defaults (16 candidates, SGM
//! penalties 96 / 192 (`sgm::DEFAULT_PENALTIES`), left-right tolerance one patch column, the head with its own left-right
//! check), the pixel refinement of the fused grid (the head and SGM fused by their checks,
//! `fuse+lr`, the default of `bino run`), and (feature `depth`) the example board's
//! calibration and sector count of the obstacle summary.
//!
//! ```
//! use bino_core::preset::{arena_bytes, OPTIONS, REFINE};
//! use bino_core::pipeline::RefineInput;
//! assert_eq!(REFINE.input, RefineInput::FusedLr);
//! assert!(OPTIONS.head && OPTIONS.head_lr);
//! // The 48x160 band pair of the budget: 486,918 bytes.
//! assert_eq!(arena_bytes(48, 160), 486_918);
//! // The native pathway (one encoder pass on (L, R), the head's check read from the same pass,
//! // the census SGM beside it) needs less.
//! assert_eq!(bino_core::preset::native_arena_bytes(48, 160), 466_598);
//! ```

use crate::pipeline::{self, Options, Pathway, Refine};

/// Readout options: 16 candidates, SGM penalties 96 / 192 (`sgm::DEFAULT_PENALTIES`), left-right tolerance one patch
/// column (Q8 256), the head (its trained 12 candidates: a 160-px view's disparities stay
/// below 44 px) with its own left-right check.
pub const OPTIONS: Options = Options {
    pathway: Pathway::Export,
    max_cols: 16,
    penalties: crate::sgm::DEFAULT_PENALTIES,
    lr_max_diff_q8: 256,
    head: true,
    head_lr: true,
    head_candidates: crate::config::HEAD_MAX_DISP,
};

/// The pixel refinement: the default parameters on the readout the pipeline's rule picks for
/// [`OPTIONS`] (fuse+lr: the head and SGM fused by their own left-right checks).
pub const REFINE: Refine = Refine::for_options(&OPTIONS);

/// Arena bytes a `height x width` band pair needs with [`OPTIONS`] and [`REFINE`].
pub const fn arena_bytes(height: usize, width: usize) -> usize {
    pipeline::arena_bytes_refined(height, width, &OPTIONS, &REFINE)
}

/// [`OPTIONS`] on the native pathway: one encoder pass on (L, R) and the native head, with its
/// left-right check read from the same pass (the right view from the head's own logits),
/// fused with the census SGM ([`crate::census`]).
pub const NATIVE_OPTIONS: Options = Options {
    pathway: Pathway::Native,
    ..OPTIONS
};

/// The pixel refinement of the native pathway's fused grid (fuse-census+lr: the native head and
/// the census SGM fused by their own left-right checks).
pub const NATIVE_REFINE: Refine = Refine::for_options(&NATIVE_OPTIONS);

/// Arena bytes a `height x width` band pair needs with [`NATIVE_OPTIONS`] and [`NATIVE_REFINE`].
pub const fn native_arena_bytes(height: usize, width: usize) -> usize {
    pipeline::arena_bytes_refined(height, width, &NATIVE_OPTIONS, &NATIVE_REFINE)
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
