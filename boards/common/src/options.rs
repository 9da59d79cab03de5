//! The readouts the boards run: the board preset (`bino_core::preset::OPTIONS`), which the QEMU
//! firmware's native run (`firmware-sim/src/workload.rs`) and `bino run --pathway native` compute
//! too: one encoder pass on (L, R), the native head with its left-right check read from the same
//! pass, fused with the census SGM, and the pixel refinement of that fuse-census+lr grid, on one
//! 48x160 band pair.

/// Band height in pixels (one encoder band: the arena below is the one-band size).
pub const BAND_HEIGHT: usize = 48;
/// Width of each view in pixels.
pub const BAND_WIDTH: usize = 160;

// The readouts and the refinement: the preset the QEMU firmware's native run uses too.
pub use bino_core::preset::{arena_bytes, OPTIONS, REFINE};

/// The boards' static arena for the 48x160 band pair (its size: docs/boards.md).
pub const ARENA_BYTES: usize = arena_bytes(BAND_HEIGHT, BAND_WIDTH);
