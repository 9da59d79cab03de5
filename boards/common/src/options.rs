//! The readouts the boards run: the learned preset (`bino_core::preset::OPTIONS`), which the QEMU
//! firmware's native run (`firmware-sim/src/workload.rs`) and `bino run --pathway native` compute
//! too: one encoder pass on (L, R), the native head with its left-right check read from the same
//! pass, fused with the census SGM, and the pixel refinement of that fuse-census+lr grid, on one
//! 48x160 band pair; and the fast preset (`bino_core::preset::CENSUS_REFINE`, the boards' `fast`
//! feature), which the QEMU firmware's census run and `bino run`'s default compute too: the census
//! SGM with its check, refined, on a whole 160x120 frame, no weights.

/// Band height in pixels (one encoder band: the arena below is the one-band size).
pub const BAND_HEIGHT: usize = 48;
/// Width of each view in pixels.
pub const BAND_WIDTH: usize = 160;

/// Rows of the fast preset's frame (QQVGA: 160x120 in the pipeline's bands).
pub const FRAME_HEIGHT: usize = 120;

// The readouts and the refinement: the presets the QEMU firmware's runs use too.
pub use bino_core::preset::{arena_bytes, census_arena_bytes, CENSUS_REFINE, OPTIONS, REFINE};

/// The boards' static arena for the learned preset's 48x160 band pair (its size: docs/boards.md).
pub const ARENA_BYTES: usize = arena_bytes(BAND_HEIGHT, BAND_WIDTH);

/// The boards' static arena for the fast preset's 160x120 frame (the same for any height).
pub const FAST_ARENA_BYTES: usize = census_arena_bytes(FRAME_HEIGHT, BAND_WIDTH);
