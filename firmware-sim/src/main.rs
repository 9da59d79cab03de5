//! BINO edge firmware for QEMU's Cortex-M55 (`mps3-an547`) and Cortex-M7 (`mps2-an500`) boards.
//!
//! Runs the embedded band pair through `bino_core::pipeline` on both pathways of the learned
//! preset, then the embedded whole frame through the fast preset's census run
//! (`pipeline::run_census`, in the front of the same arena: its own `census_arena_bytes`) and the
//! learned preset, and with the `frame320` feature (the Cortex-M55) both presets on the Alif E7's
//! 320x240 frame (`frame320.rs`, an arena of its own), from a static arena, their rows fed by the
//! camera path (`camera.rs`: a SysTick interrupt plays the sensor and fills line buffers,
//! a `heapless` queue hands them to the pipeline), logs each stage's arena use and stack peak,
//! each output's digest, the camera's lost rows and the obstacle summary with `defmt` over
//! semihosting, and exits 0 only if every digest equals the host's (baked in by `build.rs`), no
//! row was lost and the camera's overflow check reports its lost rows; non-zero otherwise or on
//! any error.
//!
//! Each stage starts with a call to its marker function `bino_mark_<stage>`, whose address the
//! QEMU instruction-count plugin (`qemu-plugin/`) watches; `bino_mark_end` starts work outside
//! the stages (digests, stack scans, logging), which the plugin counts apart.
#![no_std]
#![no_main]

mod camera;
#[cfg(feature = "frame320")]
mod frame320;
mod markers;
mod workload;

use core::mem::MaybeUninit;
use core::ptr::{addr_of, addr_of_mut};

use bino_core::pipeline::RowSource;
use bino_core::Error;
use camera::Camera;
// The critical-section implementation (single core) that defmt's logger needs.
use cortex_m as _;
use cortex_m_rt::entry;
use cortex_m_semihosting::debug::{exit, ExitStatus, EXIT_FAILURE, EXIT_SUCCESS};
use defmt_semihosting as _;
use markers::{bino_mark_end, mark};
use workload::{Hooks, Run, Stage, OUTPUTS};

pub(crate) mod expected {
    include!(concat!(env!("OUT_DIR"), "/expected.rs"));
}

/// The board this build is for.
#[cfg(board = "an547")]
const BOARD: &str = "mps3-an547 (Cortex-M55)";
#[cfg(board = "an500")]
const BOARD: &str = "mps2-an500 (Cortex-M7)";

/// Arena bytes, from the core's `const fn`.
const ARENA_BYTES: usize = workload::arena_bytes(expected::HEIGHT, expected::WIDTH);
/// The census run's arena (the front of the same one), from the core's `const fn`.
const CENSUS_ARENA_BYTES: usize = workload::census_arena_bytes(expected::FRAME_HEIGHT, expected::WIDTH);
const _: () = assert!(
    CENSUS_ARENA_BYTES <= ARENA_BYTES,
    "the census run's arena exceeds the static one"
);
/// The learned preset's frame run's arena (the front of the same one): the band's within the
/// refinement's two ring rows, whatever the frame's height.
const FRAME_ARENA_BYTES: usize = workload::frame_arena_bytes(expected::FRAME_HEIGHT, expected::WIDTH);
const _: () = assert!(
    FRAME_ARENA_BYTES <= ARENA_BYTES,
    "the learned frame's arena exceeds the static one"
);
/// Byte the arena is painted with before the run, so its high-water mark can be read back.
const ARENA_PAINT: u8 = 0xA5;
/// What cortex-m-rt's `paint-stack` writes over the stack before `main` (and this firmware
/// again below the stack pointer after each stage).
const STACK_PAINT: u32 = 0xCCCC_CCCC;

#[repr(C, align(16))]
pub(crate) struct Aligned<T>(T);

/// The weight blob, in the board's read-only flash-like region (see `memory/`).
#[link_section = ".weights"]
#[used]
static BLOB: Aligned<[u8; expected::BLOB_LEN]> = Aligned(*expected::BLOB_BYTES);

/// The arena: not zeroed at reset (`.uninit`), painted by `main`.
#[link_section = ".uninit.bino_arena"]
static mut ARENA: MaybeUninit<Aligned<[u8; ARENA_BYTES]>> = MaybeUninit::uninit();

extern "C" {
    static _stack_end: u32;
    static _stack_start: u32;
}

/// The stack region, `[bottom, top)`.
fn stack_bounds() -> (usize, usize) {
    // Only the linker symbols' addresses are taken.
    (addr_of!(_stack_end) as usize, addr_of!(_stack_start) as usize)
}

/// Bytes of stack used since the last [`repaint_stack`]: from the top down to the lowest word
/// that no longer holds the paint.
fn stack_peak() -> usize {
    let (bottom, top) = stack_bounds();
    let mut p = bottom;
    // SAFETY: p is a word-aligned address inside the stack region.
    while p < top && unsafe { core::ptr::read_volatile(p as *const u32) } == STACK_PAINT {
        p += 4;
    }
    top - p
}

/// Paints the free stack again, from the bottom to well below the stack pointer.
#[inline(never)]
fn repaint_stack() {
    let (bottom, _) = stack_bounds();
    let sp = cortex_m::register::msp::read() as usize;
    let end = sp.saturating_sub(256) & !3;
    // Masked: the camera's interrupt must not push a frame into the stack being painted.
    cortex_m::interrupt::free(|_| {
        let mut p = bottom;
        while p < end {
            // SAFETY: [bottom, sp - 256) is free stack below every live frame; nothing
            // interrupts inside this critical section.
            unsafe { core::ptr::write_volatile(p as *mut u32, STACK_PAINT) };
            p += 4;
        }
    });
}

/// Highest arena byte written since painting, plus one.
fn arena_high_water(arena: &[u8]) -> usize {
    arena.iter().rposition(|&b| b != ARENA_PAINT).map_or(0, |i| i + 1)
}

struct Firmware {
    current: Option<Stage>,
    /// Deepest stack use seen in each stage.
    stack: [usize; Stage::COUNT],
}

impl Firmware {
    /// Closes the current stage's stack measurement and starts a fresh one.
    fn close_stage(&mut self) {
        bino_mark_end();
        if let Some(stage) = self.current.take() {
            let peak = &mut self.stack[stage.index()];
            *peak = (*peak).max(stack_peak());
        }
        repaint_stack();
    }
}

impl Hooks for Firmware {
    fn enter(&mut self, stage: Stage) {
        self.close_stage();
        self.current = Some(stage);
        mark(stage);
    }

    fn pause(&mut self) {
        bino_mark_end();
    }

    fn resume(&mut self, stage: Stage) {
        mark(stage);
    }

    fn finish(&mut self) {
        self.close_stage();
    }
}

/// What the camera streams for one run: the views, their size and the row interval.
#[derive(Clone, Copy)]
pub(crate) struct Feed {
    left: &'static [u8],
    right: &'static [u8],
    width: usize,
    rows: usize,
    interval_insns: u32,
}

/// The band pair at the band's row interval.
const BAND: Feed = Feed {
    left: &expected::LEFT,
    right: &expected::RIGHT,
    width: expected::WIDTH,
    rows: expected::HEIGHT,
    interval_insns: camera::ROW_INTERVAL_INSNS,
};

/// What `run` reads, `None` for a run this build does not make.
fn feed(run: Run) -> Option<Feed> {
    let frame = |interval_insns| Feed {
        left: &expected::FRAME_LEFT,
        right: &expected::FRAME_RIGHT,
        width: expected::WIDTH,
        rows: expected::FRAME_HEIGHT,
        interval_insns,
    };
    match run {
        Run::Export | Run::Native => Some(BAND),
        // The fast preset at a sensor's pace; the learned one from a camera slow enough for it.
        Run::Census => Some(frame(camera::FRAME_ROW_INTERVAL_INSNS)),
        Run::Frame => Some(frame(camera::LEARNED_FRAME_ROW_INTERVAL_INSNS)),
        #[cfg(feature = "frame320")]
        Run::Census320 | Run::Frame320 => Some(frame320::feed(run)),
        #[cfg(not(feature = "frame320"))]
        Run::Census320 | Run::Frame320 => None,
    }
}

/// The host's digests and arena high-water of `run` (`build.rs`).
fn expected_of(run: Run) -> (&'static [u32; OUTPUTS.len()], usize) {
    match run {
        Run::Export => (&expected::EXPORT_DIGESTS, expected::EXPORT_ARENA_USED),
        Run::Native => (&expected::NATIVE_DIGESTS, expected::NATIVE_ARENA_USED),
        Run::Census => (&expected::CENSUS_DIGESTS, expected::CENSUS_ARENA_USED),
        Run::Frame => (&expected::FRAME_DIGESTS, expected::FRAME_ARENA_USED),
        #[cfg(feature = "frame320")]
        Run::Census320 => (&expected::CENSUS320_DIGESTS, expected::CENSUS320_ARENA_USED),
        #[cfg(feature = "frame320")]
        Run::Frame320 => (&expected::FRAME320_DIGESTS, expected::FRAME320_ARENA_USED),
        // Never run without the feature.
        #[cfg(not(feature = "frame320"))]
        Run::Census320 | Run::Frame320 => (&[0; OUTPUTS.len()], usize::MAX),
    }
}

/// One run's outcome, whether the camera delivered every row, and the arena's painted
/// high-water.
struct Done {
    outcome: Result<workload::Outcome, Error>,
    rows_ok: bool,
    painted: usize,
}

/// Runs `run` on `feed` from the camera, in the front of `arena` its `const fn` gives it
/// (painted anew), logging the camera path.
fn run_fed(run: Run, feed: Feed, blob: &[u8], camera: &mut Camera, arena: &mut [u8], fw: &mut Firmware) -> Done {
    camera.load(feed.left, feed.right, feed.width, feed.rows, feed.interval_insns);
    let bytes = workload::run_arena_bytes(run, feed.rows, feed.width);
    let arena = arena.get_mut(..bytes).unwrap_or_default();
    arena.fill(ARENA_PAINT);
    let outcome = workload::run(blob, run, camera, arena, fw);
    let rows_ok = report_camera(run, camera, feed);
    Done {
        outcome,
        rows_ok,
        painted: arena_high_water(arena),
    }
}

#[entry]
fn main() -> ! {
    // SAFETY: main runs once and makes the only reference to ARENA; painting it first makes
    // every byte initialised.
    let arena = unsafe {
        let arena = addr_of_mut!(ARENA).cast::<u8>();
        core::ptr::write_bytes(arena, ARENA_PAINT, ARENA_BYTES);
        core::slice::from_raw_parts_mut(arena, ARENA_BYTES)
    };
    let (stack_bottom, stack_top) = stack_bounds();
    defmt::println!(
        "bino board={=str} band={=usize}x{=usize} arena_bytes={=usize} blob_bytes={=usize} stack_bytes={=usize}",
        BOARD,
        expected::HEIGHT,
        expected::WIDTH,
        ARENA_BYTES,
        expected::BLOB_LEN,
        stack_top - stack_bottom
    );
    let Some(syst) = cortex_m::Peripherals::take().map(|p| p.SYST) else {
        fail("peripherals-taken");
    };
    defmt::println!(
        "bino census frame={=usize}x{=usize} arena_bytes={=usize}",
        expected::FRAME_HEIGHT,
        expected::WIDTH,
        CENSUS_ARENA_BYTES
    );
    defmt::println!(
        "bino learned_frame={=usize}x{=usize} learned_arena_bytes={=usize}",
        expected::FRAME_HEIGHT,
        expected::WIDTH,
        FRAME_ARENA_BYTES
    );
    #[cfg(feature = "frame320")]
    frame320::log_header();
    // The E7 frame's runs have their own arena and line buffers, in the board's larger SRAM.
    #[cfg(feature = "frame320")]
    let (e7_arena, e7_lines) = frame320::arena_and_line_buffers();
    #[cfg(not(feature = "frame320"))]
    let (e7_arena, e7_lines): (&mut [u8], &'static mut [u8]) = (&mut [], &mut []);
    let Some(mut camera) = Camera::new(syst, e7_lines) else {
        fail("camera-set-up-twice");
    };
    let mut fw = Firmware {
        current: None,
        stack: [0; Stage::COUNT],
    };
    // SAFETY: BLOB is immutable; reading its address through a volatile load keeps the
    // optimiser from folding the blob's contents into the code.
    let blob: &[u8] = unsafe { &*core::ptr::read_volatile(&addr_of!(BLOB.0)) };
    // Each run in turn: the band pair on each pathway, then the frames, in the front of the
    // arena (only as much as each run's `const fn` says), painted anew.
    let mut done: [Option<Done>; Run::ALL.len()] = [const { None }; Run::ALL.len()];
    for (slot, run) in done.iter_mut().zip(Run::ALL) {
        let Some(feed) = feed(run) else { continue };
        let arena = if run.on_e7_frame() { &mut *e7_arena } else { &mut *arena };
        *slot = Some(run_fed(run, feed, blob, &mut camera, arena, &mut fw));
    }
    let mut reports = [None; Run::ALL.len()];
    for ((report, d), run) in reports.iter_mut().zip(&done).zip(Run::ALL) {
        match d.as_ref().map(|d| &d.outcome) {
            Some(Ok(o)) => *report = Some(o.report),
            Some(Err(e)) => {
                defmt::println!("bino result=error pathway={=str} error={}", run.name(), e);
                exit_with(EXIT_FAILURE);
            }
            None => {}
        }
    }
    let at = |run: Run| Run::ALL.iter().position(|&r| r == run).and_then(|i| reports[i]);
    let per_stage = workload::arena_per_stage(at);
    for (i, (&arena_in_use, &stack)) in per_stage.iter().zip(&fw.stack).enumerate() {
        let stage = Stage::at(i);
        // A build without the E7 frame reports none of its stages.
        if stage.run().is_some_and(|r| feed(r).is_none()) {
            continue;
        }
        defmt::println!(
            "bino stage={=str} arena_in_use={=usize} stack_peak={=usize}",
            stage.name(),
            arena_in_use,
            stack
        );
    }
    let (mut all_ok, mut rows_ok, mut outputs) = (true, true, 0);
    for (d, run) in done.iter().zip(Run::ALL) {
        let Some(Done {
            outcome: Ok(outcome),
            rows_ok: delivered,
            painted,
        }) = d
        else {
            continue;
        };
        let (digests, arena_used) = expected_of(run);
        let ok = check_outcome(run, outcome, digests, arena_used, *painted);
        #[cfg(feature = "frame320")]
        let ok = ok & frame320::check_bino_run(run, outcome);
        all_ok &= ok;
        rows_ok &= *delivered;
        outputs += workload::outputs(run).len();
    }
    let overflow_ok = overflow_check(&mut camera);
    let code = if all_ok && rows_ok && overflow_ok {
        defmt::println!("bino result=pass outputs={=usize}", outputs);
        EXIT_SUCCESS
    } else {
        defmt::println!(
            "bino result=fail outputs_ok={=bool} rows_ok={=bool} overflow_check_ok={=bool}",
            all_ok,
            rows_ok,
            overflow_ok
        );
        EXIT_FAILURE
    };
    exit_with(code)
}

/// Logs the error and exits non-zero.
fn fail(error: &str) -> ! {
    defmt::println!("bino result=error error={=str}", error);
    exit_with(EXIT_FAILURE)
}

/// Ends the QEMU run with `code` (semihosting); never returns.
fn exit_with(code: ExitStatus) -> ! {
    exit(code);
    #[allow(clippy::empty_loop)]
    loop {}
}

/// Logs `run`'s digests against the host's, its sectors and arena; `true` when every digest
/// matches and the arena's high-water is the host's.
#[inline(never)]
fn check_outcome(
    run: Run,
    outcome: &workload::Outcome,
    want: &[u32; OUTPUTS.len()],
    arena_used: usize,
    painted: usize,
) -> bool {
    let name = run.name();
    let mut mismatches = 0;
    for &slot in workload::outputs(run) {
        let (got, want) = (outcome.digests[slot], want[slot]);
        mismatches += usize::from(got != want);
        defmt::println!(
            "bino pathway={=str} output={=str} digest={=u32:08x} expected={=u32:08x} match={=bool}",
            name,
            OUTPUTS[slot],
            got,
            want,
            got == want
        );
    }
    for (i, sector) in outcome.sectors.sectors().iter().enumerate() {
        defmt::println!("bino pathway={=str} sector={=usize} {}", name, i, sector);
    }
    if let Some((i, mm)) = outcome.sectors.nearest() {
        defmt::println!(
            "bino pathway={=str} nearest_sector={=usize} nearest_mm={=u32}",
            name,
            i,
            mm
        );
    }
    let r = &outcome.report;
    let arena_ok = r.arena_used == arena_used && painted <= r.arena_used;
    defmt::println!(
        "bino pathway={=str} arena_used={=usize} expected={=usize} painted_high_water={=usize} pixels={=usize} descriptors={=usize} encoder={=usize} streams={=usize} refine={=usize} wta_kept={=usize} sgm_kept={=usize} head_kept={=usize} census_kept={=usize}",
        name,
        r.arena_used,
        arena_used,
        painted,
        r.pixels,
        r.descriptors,
        r.encoder,
        r.streams,
        r.refine,
        r.wta_kept,
        r.sgm_kept,
        r.head_kept,
        r.census_kept
    );
    mismatches == 0 && arena_ok
}

/// Logs the camera path of `run` on `feed` (the inputs of the sustainable row rate that
/// report.py derives from the instruction counts); `true` when every row arrived and none was
/// lost.
#[inline(never)]
fn report_camera(run: Run, camera: &Camera, feed: Feed) -> bool {
    let stats = camera.stats();
    defmt::println!(
        "bino camera pathway={=str} frame_rows={=usize} line_buffers={=usize} row_interval_insns={=u32} delivered={=usize} lost={=usize} queue_high_water={=usize}",
        run.name(),
        feed.rows,
        camera::LINES,
        feed.interval_insns,
        stats.delivered,
        stats.lost,
        stats.queue_high_water
    );
    stats.lost == 0 && stats.delivered == feed.rows
}

/// The camera's overflow path, checked on the target after the run (outside the stage
/// counts): the sensor exposes a frame `EXTRA` rows longer than the line buffers with nobody
/// reading, so those rows are lost; the queued rows still come out in order, and the next
/// request is [`Error::RowsLost`] with the count. The frame's length, not timing, fixes the
/// count, so it holds with or without QEMU's `-icount`.
#[inline(never)]
fn overflow_check(camera: &mut Camera) -> bool {
    const EXTRA: usize = 3;
    let band = BAND;
    camera.load(
        band.left,
        band.right,
        band.width,
        camera::LINES + EXTRA,
        band.interval_insns,
    );
    camera.start();
    camera.wait_stopped();
    let lost = camera.stats().lost;
    let (mut left, mut right) = ([0u8; expected::WIDTH], [0u8; expected::WIDTH]);
    let mut queued_ok = 0;
    for _ in 0..camera::LINES {
        queued_ok += usize::from(camera.next_row(&mut left, &mut right).is_ok());
    }
    let after = camera.next_row(&mut left, &mut right);
    let ok = lost == EXTRA
        && queued_ok == camera::LINES
        && after
            == Err(Error::RowsLost {
                row: camera::LINES,
                lost: EXTRA,
            });
    match after {
        Err(e) => defmt::println!(
            "bino camera_overflow_check exposed={=usize} lost={=usize} queued_rows_read={=usize} next_row={} ok={=bool}",
            camera::LINES + EXTRA,
            lost,
            queued_ok,
            e,
            ok
        ),
        Ok(()) => defmt::println!(
            "bino camera_overflow_check exposed={=usize} lost={=usize} queued_rows_read={=usize} next_row=ok ok={=bool}",
            camera::LINES + EXTRA,
            lost,
            queued_ok,
            ok
        ),
    }
    ok
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    defmt::println!("bino result=panic {}", defmt::Display2Format(info));
    exit_with(EXIT_FAILURE)
}
