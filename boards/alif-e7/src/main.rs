//! BINO edge on an Alif Ensemble E7 (Cortex-M55 HP core, 400 MHz, Helium): the int8 weight
//! blob in MRAM (run in place), the pipeline's arena in SRAM0, the stack in the HP core's DTCM.
//!
//! We found no HAL or PAC for the Ensemble family on crates.io (2026-12-01; see the README,
//! "Real boards"), so this is `cortex-m-rt` and the core's own peripherals only (caches, DWT,
//! SysTick); the camera interfaces (CPI, MIPI CSI-2) are not driven. The rows come from the
//! embedded 320x240 test frame (`bino_board::options::ALIF_E7`), copied at boot side by side
//! into a frame buffer in SRAM0 beside the arena, where a camera's DMA would write its frame,
//! and read from there line by line (`SideBySide`): the board runs its preset on the whole
//! frame, over and over, prints the sector summary and the cycles of every stage over
//! defmt-RTT, and reports whether it reproduced the host's result bit for bit.
//!
//! By default the preset is the fast one (`census+lr+ref`, no encoder, no weights linked), the
//! more accurate and the cheaper one on every real labeled set measured, in its own arena; with
//! the `learned` feature the learned preset (the blob in MRAM), band after band.
#![no_std]
#![no_main]

use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;

use bino_board::clock;
use bino_board::options::{Frame, ALIF_E7};
use bino_board::run::Preset;
use bino_board::side_by_side::{interleave, SideBySide};
use cortex_m_rt::{entry, exception};
use defmt_rtt as _;

mod expected {
    include!(concat!(env!("OUT_DIR"), "/expected.rs"));
}

/// The board's frame: 320x240.
const FRAME: Frame = ALIF_E7;

/// The HP core's nominal clock (its maximum); only the printed milliseconds assume it, the
/// cycles are counted.
const CORE_HZ: u32 = 400_000_000;

#[repr(C, align(32))]
struct Aligned<T>(T);

#[cfg(feature = "learned")]
mod preset {
    //! The learned preset: its weights.

    use super::Aligned;
    use bino_board::run::{load, Preset};
    use bino_core::Error;

    /// The learned preset's arena for the whole frame, bytes.
    pub const ARENA_LEN: usize = super::FRAME.arena_bytes();

    pub const BLOB_LEN: usize = include_bytes!("../../../weights/bino_int8_native.bin").len();

    /// The int8 weight blob, in MRAM (`.weights`, see `memory.x`).
    #[link_section = ".weights"]
    #[used]
    static BLOB: Aligned<[u8; BLOB_LEN]> = Aligned(*include_bytes!("../../../weights/bino_int8_native.bin"));

    /// The learned preset on the blob's engine (checked once, here).
    pub fn load_preset() -> Result<Preset<'static>, Error> {
        // black_box: the blob's bytes must be read from MRAM, never folded into the code.
        load(core::hint::black_box(&BLOB.0)).map(Preset::Learned)
    }
}

#[cfg(not(feature = "learned"))]
mod preset {
    //! The fast preset: no weights.

    use bino_board::run::Preset;
    use bino_core::Error;

    /// The fast preset's arena for the whole frame, bytes.
    pub const ARENA_LEN: usize = super::FRAME.fast_arena_bytes();

    pub const BLOB_LEN: usize = 0;

    /// The fast preset.
    pub fn load_preset() -> Result<Preset<'static>, Error> {
        Ok(Preset::Fast)
    }
}

use preset::ARENA_LEN;

/// The embedded test frame of the board's size, both presets' (in MRAM).
const LEFT: &[u8] = include_bytes!("../../../firmware-sim/assets/frame_240x320_left.gray");
const RIGHT: &[u8] = include_bytes!("../../../firmware-sim/assets/frame_240x320_right.gray");
const _: () = assert!(LEFT.len() == FRAME.pixels() && RIGHT.len() == FRAME.pixels());

/// Bytes of the side-by-side frame: both views.
const FRAME_LEN: usize = 2 * FRAME.pixels();

/// The pipeline's arena: SRAM0, not zeroed at reset.
#[link_section = ".sram0.arena"]
static mut ARENA: MaybeUninit<Aligned<[u8; ARENA_LEN]>> = MaybeUninit::uninit();

/// The frame buffer: SRAM0, where a camera's DMA would write the side-by-side frame; not zeroed
/// at reset.
#[link_section = ".sram0.frame"]
static mut FRAME_BUFFER: MaybeUninit<Aligned<[u8; FRAME_LEN]>> = MaybeUninit::uninit();

#[entry]
fn main() -> ! {
    let mut cp = cortex_m::Peripherals::take().unwrap();
    cp.SCB.enable_icache();
    cp.SCB.enable_dcache(&mut cp.CPUID);
    let has_cycles = clock::start(&mut cp.DCB, &mut cp.DWT, &mut cp.SYST);

    // SAFETY: main runs once and makes the only reference to ARENA; zeroing it first makes
    // every byte initialised.
    let arena = unsafe {
        let arena = addr_of_mut!(ARENA).cast::<u8>();
        core::ptr::write_bytes(arena, 0, ARENA_LEN);
        core::slice::from_raw_parts_mut(arena, ARENA_LEN)
    };
    // SAFETY: as for ARENA: the only reference to FRAME_BUFFER, every byte written first.
    let frame = unsafe {
        let frame = addr_of_mut!(FRAME_BUFFER).cast::<u8>();
        core::ptr::write_bytes(frame, 0, FRAME_LEN);
        core::slice::from_raw_parts_mut(frame, FRAME_LEN)
    };
    // The test frame laid out as a camera lays out a side-by-side frame, then the preset.
    let loaded: Result<Preset<'static>, _> =
        interleave(LEFT, RIGHT, FRAME.width, frame).and_then(|()| preset::load_preset());
    let frame: &[u8] = frame;
    defmt::println!(
        "bino board=alif-e7 core=cortex-m55-hp core_hz={=u32} frame={=usize}x{=usize} arena_bytes={=usize} blob_bytes={=usize} cycle_counter={=bool}",
        CORE_HZ,
        FRAME.width,
        FRAME.height,
        ARENA_LEN,
        preset::BLOB_LEN,
        has_cycles
    );
    defmt::println!("bino source=test-frame frame_bytes={=usize}", FRAME_LEN);
    match loaded {
        // The frame again and again: each run prints its summary and cycles, so the
        // log can be read whenever the probe attaches.
        Ok(preset) => {
            defmt::println!("bino preset={=str}", preset.name());
            for n in 0u32.. {
                bino_board::check::test_frame(
                    &preset,
                    n,
                    SideBySide::new(frame, FRAME.width, FRAME.height),
                    arena,
                    expected::REFINED_CRC,
                    &expected::SECTORS,
                    CORE_HZ,
                );
            }
        }
        Err(e) => defmt::println!("bino result=error error={}", defmt::Display2Format(&e)),
    }
    loop {
        cortex_m::asm::wfi();
    }
}

#[exception]
fn SysTick() {
    clock::tick();
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    defmt::println!("bino result=panic {}", defmt::Display2Format(info));
    loop {
        cortex_m::asm::wfi();
    }
}
