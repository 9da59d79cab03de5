//! The readouts the boards run: those of the QEMU firmware (`firmware-sim/src/workload.rs`)
//! and of `bino run` — head with its left-right check, SGM, and the pixel refinement of the
//! head+lr grid — on one 48x160 band pair.

use bino_core::pipeline::{self, Options, Refine};
use bino_core::sgm::Penalties;

/// Band height in pixels (one encoder band: the arena below is the one-band size).
pub const BAND_HEIGHT: usize = 48;
/// Width of each view in pixels.
pub const BAND_WIDTH: usize = 160;

/// Readout options: 16 candidates, SGM penalties 8 / 32, left-right tolerance one patch
/// column, the head with its own left-right check.
pub const OPTIONS: Options = Options {
    max_cols: 16,
    penalties: Penalties { p1: 8, p2: 32 },
    lr_max_diff_q8: 256,
    head: true,
    head_lr: true,
};

/// The pixel refinement of the readout the pipeline's rule picks for [`OPTIONS`] (head+lr).
pub const REFINE: Refine = Refine::for_options(&OPTIONS);

/// Arena bytes for a `height x width` band pair with these readouts.
pub const fn arena_bytes(height: usize, width: usize) -> usize {
    pipeline::arena_bytes_refined(height, width, &OPTIONS, &REFINE)
}

/// The boards' static arena: 486,918 bytes for the 48x160 band pair.
pub const ARENA_BYTES: usize = arena_bytes(BAND_HEIGHT, BAND_WIDTH);
