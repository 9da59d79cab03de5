//! The readouts the boards run, each on a whole frame of the board's size ([`Frame`]): the
//! learned preset (`bino_core::preset::OPTIONS` and `REFINE` at the frame's width), which the
//! QEMU firmware's frame run (`firmware-sim/src/workload.rs`, `Run::Frame`, at 160x120) and
//! `bino run --profile native --pathway native` compute too: per band of the frame one encoder
//! pass on (L, R), the native head with its left-right check read from the same pass, fused with
//! the census SGM, and the pixel refinement of that fuse-census+lr grid; and the fast preset
//! (`bino_core::preset::CENSUS_REFINE` at the frame's width, the boards' default build), which
//! the QEMU firmware's census run and `bino run --profile native`'s default compute too: the
//! census SGM with its check, refined, no weights. On wider frames the head and the census SGM
//! search further and the refinement wider, as the host's commands do at that width
//! (`bino_core::preset::options_for_width`).

use bino_core::pipeline::{Options, Refine};
use bino_core::preset;

// The readouts and the refinement at 160 px: the presets the QEMU firmware's runs use too.
pub use bino_core::preset::{CENSUS_REFINE, OPTIONS, REFINE};

/// The size of a board's whole stereo frame, and the readouts' options and arenas at it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Frame {
    /// Width of each view in pixels.
    pub width: usize,
    /// Rows of the frame (streamed through the pipeline's bands).
    pub height: usize,
}

impl Frame {
    /// Gray pixels of one view.
    pub const fn pixels(self) -> usize {
        self.width * self.height
    }

    /// The learned and the fast preset's readout options at this width.
    pub const fn options(self) -> Options {
        preset::options_for_width(self.width)
    }

    /// The learned preset's refinement at this width.
    pub const fn refine(self) -> Refine {
        preset::refine_for_width(self.width)
    }

    /// The fast preset's refinement at this width.
    pub const fn census_refine(self) -> Refine {
        preset::census_refine_for_width(self.width)
    }

    /// The learned preset's static arena for the whole frame (each band's head starts afresh
    /// in the encoder's scratch, so it does not grow with the height beyond a few bands).
    pub const fn arena_bytes(self) -> usize {
        preset::arena_bytes_for_width(self.height, self.width)
    }

    /// The fast preset's static arena for the whole frame (the same for any height).
    pub const fn fast_arena_bytes(self) -> usize {
        preset::census_arena_bytes_for_width(self.height, self.width)
    }
}

/// The STM32H743's frame, QQVGA 160x120: its 512 KiB AXI SRAM holds the learned preset's arena
/// beside the DCMI's line buffers (docs/boards.md, Memory).
pub const STM32H7: Frame = Frame {
    width: 160,
    height: 120,
};

/// The Alif E7's frame, QVGA 320x240: its 4 MiB SRAM0 holds the learned preset's arena at that
/// width beside the whole side-by-side frame.
pub const ALIF_E7: Frame = Frame {
    width: 320,
    height: 240,
};
