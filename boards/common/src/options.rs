//! The readouts the boards run: those of the QEMU firmware (`firmware-sim/src/workload.rs`)
//! and of `bino run` — head with its left-right check, SGM, and the pixel refinement of the
//! fuse+lr grid (the head and SGM fused by their checks) — on one 48x160 band pair.

/// Band height in pixels (one encoder band: the arena below is the one-band size).
pub const BAND_HEIGHT: usize = 48;
/// Width of each view in pixels.
pub const BAND_WIDTH: usize = 160;

// The readouts and the refinement: the preset the QEMU firmware runs too.
pub use bino_core::preset::{arena_bytes, OPTIONS, REFINE};

/// The boards' static arena: 486,918 bytes for the 48x160 band pair.
pub const ARENA_BYTES: usize = arena_bytes(BAND_HEIGHT, BAND_WIDTH);
