//! The readouts the boards run, each on a whole 160x120 frame: the learned preset
//! (`bino_core::preset::OPTIONS` and `REFINE`), which the QEMU firmware's frame run
//! (`firmware-sim/src/workload.rs`, `Run::Frame`) and `bino run --pathway native` compute too: per
//! band of the frame one encoder pass on (L, R), the native head with its left-right check read
//! from the same pass, fused with the census SGM, and the pixel refinement of that fuse-census+lr
//! grid; and the fast preset (`bino_core::preset::CENSUS_REFINE`, the boards' `fast` feature),
//! which the QEMU firmware's census run and `bino run`'s default compute too: the census SGM with
//! its check, refined, no weights.

/// Rows of a frame (QQVGA: 160x120, streamed through the pipeline's bands).
pub const FRAME_HEIGHT: usize = 120;
/// Width of each view of a frame in pixels.
pub const FRAME_WIDTH: usize = 160;

// The readouts and the refinement: the presets the QEMU firmware's runs use too.
pub use bino_core::preset::{arena_bytes, census_arena_bytes, CENSUS_REFINE, OPTIONS, REFINE};

/// The boards' static arena for the learned preset's 160x120 frame (its size: docs/boards.md).
pub const ARENA_BYTES: usize = arena_bytes(FRAME_HEIGHT, FRAME_WIDTH);

/// The boards' static arena for the fast preset's 160x120 frame (the same for any height).
pub const FAST_ARENA_BYTES: usize = census_arena_bytes(FRAME_HEIGHT, FRAME_WIDTH);
