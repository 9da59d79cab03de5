//! BINO edge firmware for QEMU's Cortex-M55 (`mps3-an547`) and Cortex-M7 (`mps2-an500`) boards.
//!
//! Runs the embedded band pair through `bino_core::pipeline` on both pathways of the learned
//! preset, then the embedded whole frame through the fast preset's census run
//! (`pipeline::run_census`, in the front of the same arena: its own `census_arena_bytes`), from a
//! static arena, their rows fed by the camera path (`camera.rs`: a SysTick interrupt plays the sensor and fills line buffers,
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
mod workload;

use core::mem::MaybeUninit;
use core::ptr::{addr_of, addr_of_mut};

use bino_core::pipeline::{self, RowSource};
use bino_core::Error;
use camera::Camera;
// The critical-section implementation (single core) that defmt's logger needs.
use cortex_m as _;
use cortex_m_rt::entry;
use cortex_m_semihosting::debug::{exit, EXIT_FAILURE, EXIT_SUCCESS};
use defmt_semihosting as _;
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
struct Aligned<T>(T);

/// The weight blob, in the board's read-only flash-like region (see `memory/`).
#[link_section = ".weights"]
#[used]
static BLOB: Aligned<[u8; expected::BLOB_LEN]> = Aligned(*expected::BLOB_BYTES);

/// The arena: not zeroed at reset (`.uninit`), painted by `main`.
#[link_section = ".uninit.bino_arena"]
static mut ARENA: MaybeUninit<Aligned<[u8; ARENA_BYTES]>> = MaybeUninit::uninit();

/// The stage the firmware is in (written by the markers, which also keeps them distinct).
static mut CURRENT: u32 = u32::MAX;

macro_rules! markers {
    ($($name:ident = $id:expr;)*) => {
        $(
            #[no_mangle]
            #[inline(never)]
            #[doc = "Marker the instruction-count plugin watches."]
            pub extern "C" fn $name() {
                // SAFETY: only the main thread writes CURRENT; the camera's interrupt never
                // touches it.
                unsafe { core::ptr::write_volatile(addr_of_mut!(CURRENT), $id) };
            }
        )*
    };
}

markers! {
    bino_mark_load = 0;
    bino_mark_rows = 1;
    bino_mark_encode_left = 2;
    bino_mark_encode_right = 3;
    bino_mark_match = 4;
    bino_mark_sgm = 5;
    bino_mark_left_right = 6;
    bino_mark_head = 7;
    bino_mark_refine = 8;
    bino_mark_encode_pair = 9;
    bino_mark_native_rows = 101;
    bino_mark_native_encode_left = 102;
    bino_mark_native_encode_right = 103;
    bino_mark_native_match = 104;
    bino_mark_native_sgm = 105;
    bino_mark_native_left_right = 106;
    bino_mark_native_head = 107;
    bino_mark_native_refine = 108;
    bino_mark_native_encode_pair = 109;
    bino_mark_census_rows = 201;
    bino_mark_census_sgm = 205;
    bino_mark_census_refine = 208;
    bino_mark_frame_rows = 301;
    bino_mark_frame_encode_left = 302;
    bino_mark_frame_encode_right = 303;
    bino_mark_frame_match = 304;
    bino_mark_frame_sgm = 305;
    bino_mark_frame_left_right = 306;
    bino_mark_frame_head = 307;
    bino_mark_frame_refine = 308;
    bino_mark_frame_encode_pair = 309;
    bino_mark_end = 0xFFFF;
}

fn mark(stage: Stage) {
    use pipeline::Stage as P;
    match stage {
        Stage::Load => bino_mark_load(),
        Stage::Pipeline(P::Rows) => bino_mark_rows(),
        Stage::Pipeline(P::EncodeLeft) => bino_mark_encode_left(),
        Stage::Pipeline(P::EncodeRight) => bino_mark_encode_right(),
        Stage::Pipeline(P::Match) => bino_mark_match(),
        Stage::Pipeline(P::Sgm) => bino_mark_sgm(),
        Stage::Pipeline(P::LeftRight) => bino_mark_left_right(),
        Stage::Pipeline(P::Head) => bino_mark_head(),
        Stage::Pipeline(P::Refine) => bino_mark_refine(),
        Stage::Pipeline(P::EncodePair) => bino_mark_encode_pair(),
        Stage::Native(P::Rows) => bino_mark_native_rows(),
        Stage::Native(P::EncodeLeft) => bino_mark_native_encode_left(),
        Stage::Native(P::EncodeRight) => bino_mark_native_encode_right(),
        Stage::Native(P::Match) => bino_mark_native_match(),
        Stage::Native(P::Sgm) => bino_mark_native_sgm(),
        Stage::Native(P::LeftRight) => bino_mark_native_left_right(),
        Stage::Native(P::Head) => bino_mark_native_head(),
        Stage::Native(P::Refine) => bino_mark_native_refine(),
        Stage::Native(P::EncodePair) => bino_mark_native_encode_pair(),
        Stage::Census(P::Rows) => bino_mark_census_rows(),
        Stage::Census(P::Refine) => bino_mark_census_refine(),
        // run_census enters no other stage; were it to, it would count as the SGM's.
        Stage::Census(_) => bino_mark_census_sgm(),
        Stage::Frame(P::Rows) => bino_mark_frame_rows(),
        Stage::Frame(P::EncodeLeft) => bino_mark_frame_encode_left(),
        Stage::Frame(P::EncodeRight) => bino_mark_frame_encode_right(),
        Stage::Frame(P::Match) => bino_mark_frame_match(),
        Stage::Frame(P::Sgm) => bino_mark_frame_sgm(),
        Stage::Frame(P::LeftRight) => bino_mark_frame_left_right(),
        Stage::Frame(P::Head) => bino_mark_frame_head(),
        Stage::Frame(P::Refine) => bino_mark_frame_refine(),
        Stage::Frame(P::EncodePair) => bino_mark_frame_encode_pair(),
    }
}

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
        defmt::println!("bino result=error error=peripherals-taken");
        exit(EXIT_FAILURE);
        #[allow(clippy::empty_loop)]
        loop {}
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
    let Some(mut camera) = Camera::new(syst, &expected::LEFT, &expected::RIGHT, expected::HEIGHT) else {
        defmt::println!("bino result=error error=camera-set-up-twice");
        exit(EXIT_FAILURE);
        #[allow(clippy::empty_loop)]
        loop {}
    };
    let mut fw = Firmware {
        current: None,
        stack: [0; Stage::COUNT],
    };
    // SAFETY: BLOB is immutable; reading its address through a volatile load keeps the
    // optimiser from folding the blob's contents into the code.
    let blob: &[u8] = unsafe { &*core::ptr::read_volatile(&addr_of!(BLOB.0)) };
    let export = workload::run(blob, Run::Export, &mut camera, arena, &mut fw);
    let export_rows_ok = report_camera(Run::Export, &camera);
    let export_painted = arena_high_water(arena);
    // The native run: the same band again from the camera, in the same arena, painted anew.
    arena.fill(ARENA_PAINT);
    camera.rewind(expected::HEIGHT);
    let native = workload::run(blob, Run::Native, &mut camera, arena, &mut fw);
    let native_rows_ok = report_camera(Run::Native, &camera);
    let native_painted = arena_high_water(arena);
    // The fast preset: the whole frame from the camera, at a sensor's pace, in the front of the
    // arena (only as much as its `const fn` says), painted anew.
    let census_arena = arena.get_mut(..CENSUS_ARENA_BYTES).unwrap_or_default();
    census_arena.fill(ARENA_PAINT);
    camera.load(
        &expected::FRAME_LEFT,
        &expected::FRAME_RIGHT,
        expected::FRAME_HEIGHT,
        camera::FRAME_ROW_INTERVAL_INSNS,
    );
    let census = workload::run(blob, Run::Census, &mut camera, census_arena, &mut fw);
    let census_rows_ok = report_camera(Run::Census, &camera);
    let census_painted = arena_high_water(census_arena);
    // The learned preset on the same frame, band after band, from a camera slow enough for it.
    let frame_arena = arena.get_mut(..FRAME_ARENA_BYTES).unwrap_or_default();
    frame_arena.fill(ARENA_PAINT);
    camera.load(
        &expected::FRAME_LEFT,
        &expected::FRAME_RIGHT,
        expected::FRAME_HEIGHT,
        camera::LEARNED_FRAME_ROW_INTERVAL_INSNS,
    );
    let frame = workload::run(blob, Run::Frame, &mut camera, frame_arena, &mut fw);
    let frame_rows_ok = report_camera(Run::Frame, &camera);
    let frame_painted = arena_high_water(frame_arena);
    let code = match (export, native, census, frame) {
        (Ok(export), Ok(native), Ok(census), Ok(frame)) => {
            let per_stage = workload::arena_per_stage(&export.report, &native.report, &census.report, &frame.report);
            for (i, (&arena_in_use, &stack)) in per_stage.iter().zip(&fw.stack).enumerate() {
                defmt::println!(
                    "bino stage={=str} arena_in_use={=usize} stack_peak={=usize}",
                    Stage::at(i).name(),
                    arena_in_use,
                    stack
                );
            }
            let export_ok = check_outcome(
                Run::Export,
                &export,
                &expected::DIGESTS,
                expected::ARENA_USED,
                export_painted,
            );
            let native_ok = check_outcome(
                Run::Native,
                &native,
                &expected::NATIVE_DIGESTS,
                expected::NATIVE_ARENA_USED,
                native_painted,
            );
            let census_ok = check_outcome(
                Run::Census,
                &census,
                &expected::CENSUS_DIGESTS,
                expected::CENSUS_ARENA_USED,
                census_painted,
            );
            let frame_ok = check_outcome(
                Run::Frame,
                &frame,
                &expected::FRAME_DIGESTS,
                expected::FRAME_ARENA_USED,
                frame_painted,
            );
            let rows_ok = export_rows_ok && native_rows_ok && census_rows_ok && frame_rows_ok;
            let overflow_ok = overflow_check(&mut camera);
            let outputs: usize = Run::ALL.iter().map(|&r| workload::outputs(r).len()).sum();
            if export_ok && native_ok && census_ok && frame_ok && rows_ok && overflow_ok {
                defmt::println!("bino result=pass outputs={=usize}", outputs);
                EXIT_SUCCESS
            } else {
                defmt::println!(
                    "bino result=fail export_ok={=bool} native_ok={=bool} census_ok={=bool} frame_ok={=bool} rows_ok={=bool} overflow_check_ok={=bool}",
                    export_ok,
                    native_ok,
                    census_ok,
                    frame_ok,
                    rows_ok,
                    overflow_ok
                );
                EXIT_FAILURE
            }
        }
        (Err(e), _, _, _) | (_, Err(e), _, _) | (_, _, Err(e), _) | (_, _, _, Err(e)) => {
            defmt::println!("bino result=error error={}", e);
            EXIT_FAILURE
        }
    };
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

/// Logs the camera path of `run` (the inputs of the sustainable row rate that report.py
/// derives from the instruction counts); `true` when every row arrived and none was lost.
#[inline(never)]
fn report_camera(run: Run, camera: &Camera) -> bool {
    let stats = camera.stats();
    let (rows, interval) = match run {
        Run::Census => (expected::FRAME_HEIGHT, camera::FRAME_ROW_INTERVAL_INSNS),
        Run::Frame => (expected::FRAME_HEIGHT, camera::LEARNED_FRAME_ROW_INTERVAL_INSNS),
        Run::Export | Run::Native => (expected::HEIGHT, camera::ROW_INTERVAL_INSNS),
    };
    defmt::println!(
        "bino camera pathway={=str} frame_rows={=usize} line_buffers={=usize} row_interval_insns={=u32} delivered={=usize} lost={=usize} queue_high_water={=usize}",
        run.name(),
        rows,
        camera::LINES,
        interval,
        stats.delivered,
        stats.lost,
        stats.queue_high_water
    );
    stats.lost == 0 && stats.delivered == rows
}

/// The camera's overflow path, checked on the target after the run (outside the stage
/// counts): the sensor exposes a frame `EXTRA` rows longer than the line buffers with nobody
/// reading, so those rows are lost; the queued rows still come out in order, and the next
/// request is [`Error::RowsLost`] with the count. The frame's length, not timing, fixes the
/// count, so it holds with or without QEMU's `-icount`.
#[inline(never)]
fn overflow_check(camera: &mut Camera) -> bool {
    const EXTRA: usize = 3;
    camera.rewind(camera::LINES + EXTRA);
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
    exit(EXIT_FAILURE);
    #[allow(clippy::empty_loop)]
    loop {}
}
