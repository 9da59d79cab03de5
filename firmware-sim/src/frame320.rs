//! The Alif E7's whole 320x240 frame on the Cortex-M55 (feature `frame320`,
//! `scripts/firmware.sh --frame320`): both presets with the options and the refinement of that
//! width (`bino_core::preset::options_for_width`: 16 head candidates, +-4 px refinement), as
//! `bino run` and the board run them, rows from the camera path. Their arena is a static of its
//! own in the AN547's 4 MiB SRAM (`memory/an547.x`: the learned preset's ~943 KiB do not fit
//! the DTCM beside the band pair's), the views sit in the flash-like QSPI region, and each
//! preset's refined rows must have the digest `bino run` gives for the frame
//! (`measured/host-frame-320x240.json`, baked in by `build.rs`).

use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;

use crate::workload::{self, Outcome, Run, OUTPUTS};
use crate::{camera, expected, Aligned, Feed, ARENA_PAINT};

/// The learned preset's arena on the frame (`preset::arena_bytes_for_width`); the fast
/// preset's is its front.
const ARENA_BYTES: usize =
    workload::run_arena_bytes(Run::Frame320, expected::FRAME320_HEIGHT, expected::FRAME320_WIDTH);
/// The fast preset's arena on the frame (`preset::census_arena_bytes_for_width`).
const CENSUS_ARENA_BYTES: usize =
    workload::run_arena_bytes(Run::Census320, expected::FRAME320_HEIGHT, expected::FRAME320_WIDTH);
const _: () = assert!(
    CENSUS_ARENA_BYTES <= ARENA_BYTES,
    "the fast preset's E7 arena exceeds the learned one's"
);

/// The camera's line buffers for the frame's rows (`camera::line_bytes`).
const LINE_BYTES: usize = camera::line_bytes(expected::FRAME320_WIDTH);

/// The arena of both runs, then the line buffers: not zeroed at reset, painted by
/// [`arena_and_line_buffers`].
#[link_section = ".frame320_arena"]
static mut ARENA: MaybeUninit<Aligned<[u8; ARENA_BYTES + LINE_BYTES]>> = MaybeUninit::uninit();

/// The arena and the line buffers, painted; main calls it once.
pub fn arena_and_line_buffers() -> (&'static mut [u8], &'static mut [u8]) {
    // SAFETY: main calls this once, so these are the only references to ARENA; painting it
    // first makes every byte initialised.
    let all = unsafe {
        let all = addr_of_mut!(ARENA).cast::<u8>();
        core::ptr::write_bytes(all, ARENA_PAINT, ARENA_BYTES + LINE_BYTES);
        core::slice::from_raw_parts_mut(all, ARENA_BYTES + LINE_BYTES)
    };
    all.split_at_mut(ARENA_BYTES)
}

/// Logs the frame and both runs' arenas.
pub fn log_header() {
    defmt::println!(
        "bino e7_frame={=usize}x{=usize} census320_arena_bytes={=usize} frame320_arena_bytes={=usize}",
        expected::FRAME320_HEIGHT,
        expected::FRAME320_WIDTH,
        CENSUS_ARENA_BYTES,
        ARENA_BYTES
    );
}

/// What `run` (one on the E7 frame) reads: the frame, at its preset's row interval.
pub fn feed(run: Run) -> Feed {
    Feed {
        left: &expected::FRAME320_LEFT,
        right: &expected::FRAME320_RIGHT,
        width: expected::FRAME320_WIDTH,
        rows: expected::FRAME320_HEIGHT,
        interval_insns: match run {
            Run::Census320 => camera::FRAME320_ROW_INTERVAL_INSNS,
            _ => camera::LEARNED_FRAME320_ROW_INTERVAL_INSNS,
        },
    }
}

/// For a run on the E7's frame: logs its refined digest beside `bino run`'s for the same frame
/// and preset; `true` when they are equal (or for any other run).
pub fn check_bino_run(run: Run, outcome: &Outcome) -> bool {
    let want = match run {
        Run::Census320 => expected::CENSUS320_BINO_RUN_REFINED,
        Run::Frame320 => expected::FRAME320_BINO_RUN_REFINED,
        _ => return true,
    };
    let refined = OUTPUTS.iter().position(|&n| n == "refined").unwrap_or(0);
    let got = outcome.digests[refined];
    defmt::println!(
        "bino pathway={=str} refined={=u32:08x} bino_run_refined={=u32:08x} bino_run_match={=bool}",
        run.name(),
        got,
        want,
        got == want
    );
    got == want
}
