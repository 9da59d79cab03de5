//! BINO edge on an STM32H743 board (Nucleo-H743ZI; OpenMV Cam H7 class): Cortex-M7 at
//! 480 MHz, the int8 weight blob in internal flash, the pipeline's arena in the AXI SRAM, the
//! stack in DTCM.
//!
//! Frames come from the DCMI (embassy-stm32's driver, 8-bit parallel, snapshot mode with DMA):
//! one frame is `FRAME.height` (120) lines of `2 x FRAME.width` gray pixels, the rectified left
//! row then the right row (a side-by-side stereo module). The frame lands in a buffer in the AXI
//! SRAM beside the arena, the pipeline reads it line by line ([`SideBySide`]), band after band of
//! the learned preset, and the board prints each frame's sector summary and the cycles of every
//! stage over defmt-RTT. With the `test-frame` feature the board runs the QEMU firmware's
//! embedded 160x120 test frame instead, over and over, and reports whether it reproduced the
//! host's result bit for bit.
//!
//! With the `fast` feature the board runs the fast preset (`census+lr+ref`, no encoder, no
//! weights in flash) on the same frames, in its own `FRAME.fast_arena_bytes()` arena.
#![no_std]
#![no_main]

use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;

use bino_board::clock;
use bino_board::options::{Frame, STM32H7};
use bino_board::run::Preset;
use cortex_m_rt::{entry, exception};
use defmt_rtt as _;
use embassy_stm32::Config;

/// The board's frame: 160x120.
const FRAME: Frame = STM32H7;

/// The core clock the RCC is set to.
const CORE_HZ: u32 = 480_000_000;

#[repr(C, align(32))]
struct Aligned<T>(T);

/// The preset's arena for a whole frame, bytes.
#[cfg(not(feature = "fast"))]
const ARENA_LEN: usize = FRAME.arena_bytes();
#[cfg(feature = "fast")]
const ARENA_LEN: usize = FRAME.fast_arena_bytes();

#[cfg(not(feature = "fast"))]
mod weights {
    //! The learned preset's weights.

    use super::Aligned;
    use bino_board::run::{load, Preset};
    use bino_core::Error;

    pub const BLOB_LEN: usize = include_bytes!("../../../weights/bino_int8_native.bin").len();

    /// The int8 weight blob, in internal flash (`.weights`, see `memory.x`).
    #[link_section = ".weights"]
    #[used]
    static BLOB: Aligned<[u8; BLOB_LEN]> = Aligned(*include_bytes!("../../../weights/bino_int8_native.bin"));

    /// The learned preset on the blob's engine (checked once, here).
    pub fn preset() -> Result<Preset<'static>, Error> {
        // black_box: the blob's bytes must be read from flash, never folded into the code.
        load(core::hint::black_box(&BLOB.0)).map(Preset::Learned)
    }
}

#[cfg(feature = "fast")]
mod weights {
    //! The fast preset reads no weights: none are linked.

    use bino_board::run::Preset;
    use bino_core::Error;

    pub const BLOB_LEN: usize = 0;

    /// The fast preset.
    pub fn preset() -> Result<Preset<'static>, Error> {
        Ok(Preset::Fast)
    }
}

/// The pipeline's arena: AXI SRAM, not zeroed at reset.
#[link_section = ".axisram.arena"]
static mut ARENA: MaybeUninit<Aligned<[u8; ARENA_LEN]>> = MaybeUninit::uninit();

#[entry]
fn main() -> ! {
    let mut cp = cortex_m::Peripherals::take().unwrap();
    // Caches: the arena and the blob are read many times per pass.
    cp.SCB.enable_icache();
    cp.SCB.enable_dcache(&mut cp.CPUID);
    let p = embassy_stm32::init(rcc_480mhz());
    let has_cycles = clock::start(&mut cp.DCB, &mut cp.DWT, &mut cp.SYST);

    // SAFETY: main runs once and makes the only reference to ARENA; zeroing it first makes
    // every byte initialised.
    let arena = unsafe {
        let arena = addr_of_mut!(ARENA).cast::<u8>();
        core::ptr::write_bytes(arena, 0, ARENA_LEN);
        core::slice::from_raw_parts_mut(arena, ARENA_LEN)
    };
    let preset = match weights::preset() {
        Ok(p) => p,
        Err(e) => halt(defmt::Display2Format(&e)),
    };
    defmt::println!(
        "bino board=stm32h743 core=cortex-m7 core_hz={=u32} preset={=str} frame={=usize}x{=usize} arena_bytes={=usize} blob_bytes={=usize} cycle_counter={=bool}",
        CORE_HZ,
        preset.name(),
        FRAME.width,
        FRAME.height,
        ARENA_LEN,
        weights::BLOB_LEN,
        has_cycles
    );
    source::run(p, &mut cp.SCB, &preset, arena)
}

#[cfg(not(feature = "test-frame"))]
mod source {
    //! Camera frames from the DCMI, forever.

    use super::*;
    use bino_board::clock::DwtClock;
    use bino_board::side_by_side::SideBySide;
    use bino_board::summary::Summary;
    use cortex_m::peripheral::SCB;
    use embassy_stm32::dcmi::{self, Dcmi};
    use embassy_stm32::{bind_interrupts, dma, peripherals, Peripherals};

    bind_interrupts!(struct Irqs {
        DCMI => dcmi::InterruptHandler<peripherals::DCMI>;
        DMA1_STREAM0 => dma::InterruptHandler<peripherals::DMA1_CH0>;
    });

    /// Words of one frame: FRAME.height lines of 2 x FRAME.width bytes.
    const FRAME_WORDS: usize = 2 * FRAME.pixels() / 4;

    /// The DCMI's DMA target: AXI SRAM (the DMA does not reach DTCM), cache-line aligned.
    #[link_section = ".axisram.frame"]
    static mut FRAME_BUFFER: MaybeUninit<Aligned<[u32; FRAME_WORDS]>> = MaybeUninit::uninit();

    pub fn run(p: Peripherals, scb: &mut SCB, preset: &Preset<'_>, arena: &mut [u8]) -> ! {
        // Pins of the DCMI's 8-bit bus (the embassy STM32H7 DCMI example's): D0 PC6, D1 PC7,
        // D2 PE0, D3 PE1, D4 PE4, D5 PD3, D6 PE5, D7 PE6, VSYNC PB7, HSYNC PA4, PIXCLK PA6.
        let mut dcmi = Dcmi::new_8bit(
            p.DCMI,
            p.DMA1_CH0,
            Irqs,
            p.PC6,
            p.PC7,
            p.PE0,
            p.PE1,
            p.PE4,
            p.PD3,
            p.PE5,
            p.PE6,
            p.PB7,
            p.PA4,
            p.PA6,
            dcmi::Config::default(),
        );
        // SAFETY: FRAME_BUFFER is only referenced here, once; zeroing it makes it initialised.
        let frame = unsafe {
            let f = addr_of_mut!(FRAME_BUFFER).cast::<u32>();
            core::ptr::write_bytes(f, 0, FRAME_WORDS);
            core::slice::from_raw_parts_mut(f, FRAME_WORDS)
        };
        defmt::println!(
            "bino source=dcmi frame_bytes={=usize} waiting for frames",
            FRAME_WORDS * 4
        );
        let mut n = 0u32;
        loop {
            // No dirty line of the frame may be evicted over what the DMA writes: write back
            // and drop its lines first (the zeroing above left some dirty).
            scb.clean_invalidate_dcache_by_address(frame.as_ptr() as usize, FRAME_WORDS * 4);
            let captured = embassy_futures::block_on(dcmi.capture(frame));
            // The DMA wrote behind the data cache: drop the lines speculative reads may have
            // filled meanwhile, before reading.
            // SAFETY: the buffer is 32-byte aligned and a whole number of cache lines, so no
            // other data shares its lines; nothing else writes it.
            unsafe { scb.invalidate_dcache_by_slice(frame) };
            if let Err(e) = captured {
                defmt::println!("bino frame={=u32} capture_error={}", n, defmt::Debug2Format(&e));
                continue;
            }
            let bytes: &[u8] = bytemuck::cast_slice(frame);
            let result = SideBySide::new(bytes, FRAME.width, FRAME.height).and_then(|mut rows| {
                let mut summary = Summary::new(FRAME.width, DwtClock)?;
                preset.run(&mut rows, arena, &mut summary).map(|r| (summary, r))
            });
            match result {
                Ok((summary, report)) => bino_board::log::print(n, &summary, &report, CORE_HZ),
                Err(e) => defmt::println!("bino frame={=u32} error={}", n, defmt::Display2Format(&e)),
            }
            n = n.wrapping_add(1);
        }
    }
}

#[cfg(feature = "test-frame")]
mod source {
    //! The embedded 160x120 test frame, again and again, checked against the host.

    use super::*;
    use bino_core::pipeline::SlicePair;
    use cortex_m::peripheral::SCB;
    use embassy_stm32::Peripherals;

    mod expected {
        include!(concat!(env!("OUT_DIR"), "/expected.rs"));
    }

    const LEFT: &[u8] = include_bytes!("../../../firmware-sim/assets/frame_120x160_left.gray");
    const RIGHT: &[u8] = include_bytes!("../../../firmware-sim/assets/frame_120x160_right.gray");
    const _: () = assert!(LEFT.len() == FRAME.pixels() && RIGHT.len() == FRAME.pixels());

    pub fn run(_p: Peripherals, _scb: &mut SCB, preset: &Preset<'_>, arena: &mut [u8]) -> ! {
        defmt::println!("bino source=test-frame");
        // The frame again and again: each run prints its summary and cycles.
        for frame in 0u32.. {
            bino_board::check::test_frame(
                preset,
                frame,
                SlicePair::new(LEFT, RIGHT, FRAME.width, FRAME.height),
                arena,
                expected::REFINED_CRC,
                &expected::SECTORS,
                CORE_HZ,
            );
        }
        halt("frame counter exhausted")
    }
}

/// RCC: HSI 64 MHz / 4 x 60 / 2 = 480 MHz core (VOS0), AHB 240 MHz, APBs 120 MHz.
fn rcc_480mhz() -> Config {
    use embassy_stm32::rcc::*;
    let mut config = embassy_stm32::Config::default();
    config.rcc.hsi = Some(HSIPrescaler::DIV1);
    config.rcc.pll1 = Some(Pll {
        source: PllSource::HSI,
        prediv: PllPreDiv::DIV4,
        mul: PllMul::MUL60,
        fracn: None,
        divp: Some(PllDiv::DIV2),
        divq: Some(PllDiv::DIV8),
        divr: None,
    });
    config.rcc.sys = Sysclk::PLL1_P;
    config.rcc.d1c_pre = AHBPrescaler::DIV1;
    config.rcc.ahb_pre = AHBPrescaler::DIV2;
    config.rcc.apb1_pre = APBPrescaler::DIV2;
    config.rcc.apb2_pre = APBPrescaler::DIV2;
    config.rcc.apb3_pre = APBPrescaler::DIV2;
    config.rcc.apb4_pre = APBPrescaler::DIV2;
    config.rcc.voltage_scale = VoltageScale::Scale0;
    config
}

#[exception]
fn SysTick() {
    clock::tick();
}

/// Logs `why` and parks the core (the log stays readable over RTT).
fn halt(why: impl defmt::Format) -> ! {
    defmt::println!("bino halt {}", why);
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    defmt::println!("bino result=panic {}", defmt::Display2Format(info));
    loop {
        cortex_m::asm::wfi();
    }
}
