//! BINO edge on an STM32H743 board (Nucleo-H743ZI; OpenMV Cam H7 class): Cortex-M7 at
//! 480 MHz, the int8 weight blob (learned preset) in internal flash, the pipeline's arena in the AXI SRAM, the
//! stack in DTCM.
//!
//! Rows come from the DCMI (8-bit parallel): one frame is `FRAME.height` (120) lines of
//! `2 x FRAME.width` gray pixels, the rectified left row then the right row (a side-by-side
//! stereo module). There is no frame buffer: the DCMI's DMA writes each line into one of 8 line
//! buffers in the AXI SRAM beside the arena, and its interrupt pushes the line's row and slot
//! into a heapless queue that the pipeline's row source pops (`camera`,
//! `bino_board::line_queue`), one whole frame per run, started at the run's first row. A line
//! that finds every buffer taken stops the capture there; once the pipeline has read the rows
//! before it, the DCMI is re-armed with its crop window starting at that row and the sensor's
//! next frame delivers the rest: no row is lost with a free-running sensor, and a frame is
//! stitched from several sensor frames when the pipeline falls behind (the learned preset's
//! encoder does). A DCMI overrun or DMA error fails the frame with `RowsLost`; a camera that
//! sends nothing for `STALL_MS` fails it with `RowsStalled`; the next frame starts clean either
//! way. The board prints each frame's sector summary, the cycles of every stage (the rows
//! stage includes the wait for the camera) and the queue's high-water mark, lost rows and
//! captures (sensor frames used) over defmt-RTT. With the `test-frame` feature the board runs
//! the QEMU firmware's embedded 160x120 test frame instead, over and over, and reports whether
//! it reproduced the host's result bit for bit.
//!
//! By default the board runs the fast preset (`census+lr+ref`, no encoder, no weights in
//! flash), the more accurate and the cheaper one on every real labeled set measured, in its own
//! `FRAME.fast_arena_bytes()` arena; with the `learned` feature the learned preset (the native
//! pathway's `fuse-census+lr+ref`, the blob in flash) on the same frames.
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
#[cfg(feature = "learned")]
const ARENA_LEN: usize = FRAME.arena_bytes();
#[cfg(not(feature = "learned"))]
const ARENA_LEN: usize = FRAME.fast_arena_bytes();

#[cfg(feature = "learned")]
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

#[cfg(not(feature = "learned"))]
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
mod camera;

#[cfg(not(feature = "test-frame"))]
mod source {
    //! Camera frames from the DCMI, row by row through the line queue, forever.

    use super::*;
    use bino_board::clock::DwtClock;
    use bino_board::line_queue::QueuedRows;
    use bino_board::summary::Summary;
    use cortex_m::peripheral::SCB;
    use embassy_stm32::dcmi::{self, Dcmi};
    use embassy_stm32::{bind_interrupts, dma, peripherals, Peripherals};

    use crate::camera::{DcmiLines, FrameEnd, LineComplete, LINE_BUFFER_BYTES};

    bind_interrupts!(struct Irqs {
        DCMI => dcmi::InterruptHandler<peripherals::DCMI>, FrameEnd;
        DMA1_STREAM0 => dma::InterruptHandler<peripherals::DMA1_CH0>;
        DMA1_STREAM1 => LineComplete;
    });

    /// Milliseconds `next_row` waits for a line before the frame fails as stalled. After a
    /// start or a re-arm the row waits for the sensor's next frame to start (up to one frame
    /// period) and then for the lines above it (up to another, for a row near the bottom): 3 s
    /// covers a slow sensor's 1-s frame period twice with a second to spare. A camera that is
    /// gone is reported that much later.
    const STALL_MS: u32 = 3_000;

    pub fn run(p: Peripherals, scb: &mut SCB, preset: &Preset<'_>, arena: &mut [u8]) -> ! {
        // Pins of the DCMI's 8-bit bus (the embassy STM32H7 DCMI example's): D0 PC6, D1 PC7,
        // D2 PE0, D3 PE1, D4 PE4, D5 PD3, D6 PE5, D7 PE6, VSYNC PB7, HSYNC PA4, PIXCLK PA6.
        // The driver sets up the pins, the clock and the bus; the capture is `camera`'s, on
        // DMA1 stream 1 (the driver's stream 0 stays idle).
        let _dcmi = Dcmi::new_8bit(
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
        // The capture's stream: taken so that nothing else claims it.
        let _stream = p.DMA1_CH1;
        let mut rows = QueuedRows::new(DcmiLines::new(scb), FRAME.width, FRAME.height, STALL_MS);
        defmt::println!(
            "bino source=dcmi line_buffer_bytes={=usize} waiting for frames",
            LINE_BUFFER_BYTES
        );
        let mut n = 0u32;
        loop {
            // A new frame: capture stopped, queue empty, every slot free, counters zeroed.
            rows.rewind();
            let result = Summary::new(FRAME.width, DwtClock)
                .and_then(|mut summary| preset.run(&mut rows, arena, &mut summary).map(|r| (summary, r)));
            let (delivered, stats) = (rows.delivered(), rows.stats());
            // Stops a capture an error left running.
            rows.rewind();
            match result {
                Ok((summary, report)) => bino_board::log::print(n, &summary, &report, CORE_HZ),
                Err(e) => defmt::println!("bino frame={=u32} error={}", n, defmt::Display2Format(&e)),
            }
            bino_board::log::print_queue(n, delivered, &stats);
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
