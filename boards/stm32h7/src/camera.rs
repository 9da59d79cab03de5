//! Camera rows from the DCMI through the line queue (`bino_board::line_queue`), one frame per
//! run: the producer side of the queue, by register.
//!
//! embassy-stm32 0.6's DCMI driver captures a whole frame into one buffer
//! (`Dcmi::capture`); it has no line-by-line mode and its DMA no double-buffer mode. It still
//! sets up the pins, the clock and the DCMI's polarities and bus width (`Dcmi::new_8bit`,
//! given DMA1 stream 0, which stays idle); the capture itself is programmed here through the
//! PAC embassy re-exports (`embassy_stm32::pac`, feature `unstable-pac`):
//!
//! - the DCMI in snapshot mode (one frame per start) with its crop window set to exactly
//!   `FRAME.height` lines of `2 x FRAME.width` bytes from the sensor's line [`CROP_TOP`], so
//!   that every line is the same number of 32-bit words whatever the sensor's frame size;
//! - DMA1 stream 1 (DMAMUX1 request 75, the DCMI's) in double-buffer mode, one line per
//!   transfer: while it writes one line buffer the other target register holds the next.
//!
//! Its transfer-complete interrupt is the queue's producer (`bino_board::double_buffer` keeps
//! the targets' slots): the line just finished is pushed as (row, slot), and the target
//! register it used gets the next free slot. With none free the capture stops once the line
//! being written has landed (the rest of that sensor frame is dropped) and the queue records the
//! row it stopped before; when the pipeline, having drained the queued rows, asks for that row,
//! [`DcmiLines::restart_from`] re-arms the snapshot with the crop window starting at it, and the
//! sensor's next frame delivers the rest. The sensor free-runs and no row is lost, but a frame
//! is stitched from as many sensor frames as re-arms plus one (logged as `captures`): in a
//! moving scene its bands are from different moments, like a rolling shutter's rows. The DCMI's
//! interrupt ends the frame (its end, or an overrun, which loses the rest of the frame). Both
//! run in a critical section on [`CAPTURE`], which the pipeline's side ([`DcmiLines`], a
//! [`LinePort`]) takes for each queue operation.
//!
//! The line buffers live in the AXI SRAM (DMA1 does not reach the DTCM) and are cached: the
//! CPU never writes them after boot (no dirty line can be evicted over what the DMA wrote), and
//! the consumer invalidates a line's cache lines before reading it. An interrupt served so late
//! that the next line finished too loses the rest of the frame (`double_buffer` sees the wrong
//! target finish); one that missed two lines would go unseen, but nothing masks interrupts for
//! anywhere near two line times while a frame is captured (the consumer's critical sections
//! copy a line's bookkeeping, not its bytes, and the log prints after the run).

use core::cell::RefCell;
use core::mem::MaybeUninit;
use core::ptr::{addr_of, addr_of_mut};

use bino_board::clock;
use bino_board::double_buffer::{DoubleBuffer, Refill};
use bino_board::line_queue::{line_bytes, LinePort, LineQueue, LINES};
use bino_core::Error;
use cortex_m::interrupt::Mutex;
use cortex_m::peripheral::SCB;
use embassy_stm32::interrupt::typelevel::{self, Handler};
use embassy_stm32::pac;
use embassy_stm32::pac::dma::vals;

use super::{Aligned, CORE_HZ, FRAME};

/// Bytes of one side-by-side line: the left row, then the right.
const LINE: usize = line_bytes(FRAME.width);
/// 32-bit words of one line: one DMA transfer.
const LINE_WORDS: usize = LINE / 4;
const _: () = assert!(LINE.is_multiple_of(32), "a line must be whole cache lines");
const _: () = assert!(LINE_WORDS <= u16::MAX as usize && FRAME.height <= 1 << 14);

/// The DMA1 stream (and DMAMUX1 channel) the capture uses.
const STREAM: usize = 1;
/// DMAMUX1's request line of the DCMI (RM0433, DMAMUX1 inputs).
const DCMI_REQUEST: u8 = 75;

/// The sensor line the frame's row 0 is (the crop window's top): a re-arm at row `r` starts the
/// window at line `CROP_TOP + r`.
const CROP_TOP: usize = 0;
// CWSTRT.VST is 13 bits, CWSIZE.VLINE 14.
const _: () = assert!(CROP_TOP + FRAME.height <= 1 << 13);

/// Bytes of the line buffers: [`LINES`] slots and the discard line.
pub const LINE_BUFFER_BYTES: usize = (LINES + 1) * LINE;

/// The line buffers, AXI SRAM, cache-line aligned: only the DMA writes them after boot.
#[link_section = ".axisram.lines"]
static mut LINE_BUFFERS: MaybeUninit<Aligned<[u8; LINE_BUFFER_BYTES]>> = MaybeUninit::uninit();

/// Address of slot `slot`'s line (`None`: the discard line).
fn line_address(slot: Option<usize>) -> usize {
    addr_of!(LINE_BUFFERS) as usize + slot.unwrap_or(LINES).min(LINES) * LINE
}

/// What the interrupts and the pipeline share.
struct Capture {
    queue: LineQueue,
    /// The slots of the DMA's target registers (M0AR, M1AR) and the frame's rows.
    dma: DoubleBuffer,
}

static CAPTURE: Mutex<RefCell<Capture>> = Mutex::new(RefCell::new(Capture {
    queue: LineQueue::new(),
    dma: DoubleBuffer::new(FRAME.height),
}));

impl Capture {
    /// Starts the DMA on the first two free slots and the DCMI on the sensor's next frame, from
    /// row `first` to the frame's last (0: a new frame; later: a re-arm where the last capture
    /// stopped). The DCMI and the DMA are stopped (`halt`: `stop` ran), so every register below
    /// may be written, and the queue holds no line.
    fn start(&mut self, first: usize) {
        let first = first.min(FRAME.height - 1);
        let targets = self.dma.start(&mut self.queue, first);
        let st = pac::DMA1.st(STREAM);
        // A stopped transfer's flags must not count as a line of this capture.
        clear_dma_flags();
        // The DCMI's data register, read a word at a time, into the two targets in turn. The
        // targets, the count and CT are written only while the stream is disabled: a whole line
        // again (a stopped transfer left NDTR part-way), target 0 first (double_buffer counts
        // the capture's rows from target 0).
        st.par().write_value(pac::DCMI.dr().as_ptr() as u32);
        st.m0ar().write_value(line_address(targets[0]) as u32);
        st.m1ar().write_value(line_address(targets[1]) as u32);
        st.ndtr().write(|w| w.set_ndt(LINE_WORDS as u16));
        st.fcr().write(|w| {
            w.set_dmdis(vals::Dmdis::DISABLED);
            w.set_fth(vals::Fth::FULL);
        });
        pac::DMAMUX1.ccr(STREAM).write(|w| w.set_dmareq_id(DCMI_REQUEST));
        st.cr().write(|w| {
            w.set_dir(vals::Dir::PERIPHERAL_TO_MEMORY);
            w.set_minc(true);
            w.set_psize(vals::Size::BITS32);
            w.set_msize(vals::Size::BITS32);
            w.set_pl(vals::Pl::VERY_HIGH);
            w.set_dbm(true);
            w.set_ct(vals::Ct::MEMORY0);
            w.set_tcie(true);
            w.set_teie(true);
            w.set_dmeie(true);
        });
        st.cr().modify(|w| w.set_en(true));

        let dcmi = pac::DCMI;
        // The stopped capture's frame end or overrun must not end this one.
        clear_dcmi_flags();
        // The crop window starts at row `first` of the frame: the lines above it in the
        // sensor's next frame are skipped, and the rows come out as `first`, `first + 1`, ...
        dcmi.cwstrt().write(|w| {
            w.set_hoffcnt(0);
            w.set_vst((CROP_TOP + first) as u16);
        });
        // Pixel clocks per line (a byte each on the 8-bit bus) and the rows left, each minus one:
        // the snapshot ends with the frame's last row.
        dcmi.cwsize().write(|w| {
            w.set_capcnt((LINE - 1) as u16);
            w.set_vline((FRAME.height - first - 1) as u16);
        });
        dcmi.ier().modify(|w| {
            w.set_frame_ie(true);
            w.set_ovr_ie(true);
            w.set_err_ie(true);
        });
        // Configured while disabled (`stop`), then enabled with the DMA ready: a snapshot
        // starts at the next frame start (VSYNC), never part-way through the sensor's frame
        // (a re-arm waits for up to a frame period, then for the lines above the window).
        dcmi.cr().modify(|w| {
            w.set_cm(true); // snapshot: this frame only
            w.set_crop(true);
        });
        dcmi.cr().modify(|w| {
            w.set_enable(true);
            w.set_capture(true);
        });
    }

    /// Stops the DCMI and the DMA; hands back the slots the DMA held; the capture ends (the
    /// frame, unless it stopped for want of a slot and is re-armed).
    fn stop(&mut self) {
        halt();
        self.dma.stop(&mut self.queue);
    }

    /// DMA interrupt: a line is complete, or the transfer failed.
    fn on_dma(&mut self) {
        let flags = pac::DMA1.isr(STREAM / 4).read();
        clear_dma_flags();
        let n = STREAM % 4;
        if !self.dma.running() {
            return;
        }
        if flags.teif(n) || flags.dmeif(n) {
            return self.lose_rest();
        }
        if flags.tcif(n) {
            // The target register the DMA no longer uses is the one just filled.
            let done = match pac::DMA1.st(STREAM).cr().read().ct() {
                vals::Ct::MEMORY1 => 0,
                _ => 1,
            };
            let address = match self.dma.line_done(&mut self.queue, done) {
                Refill::Target(slot) => line_address(slot) as u32,
                Refill::FrameDone => return self.stop(),
            };
            // In double-buffer mode the target register not in use may be written while the
            // stream runs.
            let st = pac::DMA1.st(STREAM);
            match done {
                0 => st.m0ar().write_value(address),
                _ => st.m1ar().write_value(address),
            }
        }
    }

    /// DCMI interrupt: the frame's end (short of the height: fewer rows), or an overrun.
    fn on_dcmi(&mut self) {
        let ris = pac::DCMI.ris().read();
        clear_dcmi_flags();
        if !self.dma.running() {
            return;
        }
        if ris.ovr_ris() || ris.err_ris() {
            return self.lose_rest();
        }
        if ris.frame_ris() {
            // The last line's transfer may complete just after the frame's end is flagged.
            if pac::DMA1.isr(STREAM / 4).read().tcif(STREAM % 4) {
                self.on_dma();
            }
            if self.dma.running() {
                self.stop();
            }
        }
    }

    /// The transfer failed or the DCMI overran: the line in flight and the rest of the frame
    /// are lost.
    fn lose_rest(&mut self) {
        halt();
        self.dma.lose_rest(&mut self.queue);
    }
}

/// Stops the DCMI and the DMA stream, their interrupts masked and flags cleared.
fn halt() {
    pac::DCMI.cr().modify(|w| {
        w.set_capture(false);
        w.set_enable(false);
    });
    pac::DCMI.ier().write(|_| {});
    let st = pac::DMA1.st(STREAM);
    st.cr().modify(|w| w.set_en(false));
    // The stream stops after the word in flight; bounded, never an endless loop.
    for _ in 0..10_000 {
        if !st.cr().read().en() {
            break;
        }
    }
    clear_dma_flags();
    clear_dcmi_flags();
}

fn clear_dma_flags() {
    let n = STREAM % 4;
    pac::DMA1.ifcr(STREAM / 4).write(|w| {
        w.set_tcif(n, true);
        w.set_htif(n, true);
        w.set_teif(n, true);
        w.set_dmeif(n, true);
        w.set_feif(n, true);
    });
}

fn clear_dcmi_flags() {
    pac::DCMI.icr().write(|w| {
        w.set_frame_isc(true);
        w.set_ovr_isc(true);
        w.set_err_isc(true);
        w.set_vsync_isc(true);
        w.set_line_isc(true);
    });
}

fn with_capture<R>(f: impl FnOnce(&mut Capture) -> R) -> R {
    cortex_m::interrupt::free(|cs| f(&mut CAPTURE.borrow(cs).borrow_mut()))
}

/// DMA1 stream 1's interrupt: the queue's producer.
pub struct LineComplete;

impl Handler<typelevel::DMA1_STREAM1> for LineComplete {
    unsafe fn on_interrupt() {
        with_capture(Capture::on_dma);
    }
}

/// The DCMI's interrupt (after embassy's driver's, which only masks what fired): the frame's
/// end or an overrun.
pub struct FrameEnd;

impl Handler<typelevel::DCMI> for FrameEnd {
    unsafe fn on_interrupt() {
        with_capture(Capture::on_dcmi);
    }
}

/// The pipeline's side: the queue, the line buffers, the capture's start and stop, `wfi`, and
/// milliseconds from the DWT clock.
pub struct DcmiLines<'a> {
    scb: &'a mut SCB,
}

impl<'a> DcmiLines<'a> {
    /// Zeroes the line buffers once (every byte initialised, none left dirty in the cache).
    /// The DCMI must be set up (pins, clock: `Dcmi::new_8bit`) and stopped.
    pub fn new(scb: &'a mut SCB) -> Self {
        // SAFETY: the capture is stopped (nothing writes the buffers) and this is the only
        // write the CPU makes to them.
        unsafe { core::ptr::write_bytes(addr_of_mut!(LINE_BUFFERS).cast::<u8>(), 0, LINE_BUFFER_BYTES) };
        scb.clean_invalidate_dcache_by_address(line_address(Some(0)), LINE_BUFFER_BYTES);
        Self { scb }
    }
}

impl LinePort for DcmiLines<'_> {
    fn with_queue<R>(&mut self, f: impl FnOnce(&mut LineQueue) -> R) -> R {
        with_capture(|c| f(&mut c.queue))
    }

    fn read_line(&mut self, slot: usize, left: &mut [u8], right: &mut [u8]) -> Result<(), Error> {
        Error::check_len("left row buffer", FRAME.width, left.len())?;
        Error::check_len("right row buffer", FRAME.width, right.len())?;
        if slot >= LINES {
            return Err(Error::OutOfRange {
                what: "line slot",
                value: slot,
                min: 0,
                max: LINES - 1,
            });
        }
        let line = line_address(Some(slot));
        // SAFETY: the slot was popped from the queue and is not handed back until this copy is
        // done, so no DMA target points at it; its LINE bytes are whole 32-byte cache lines of
        // the buffers, which nothing else shares, and were written whole by the DMA (or zeroed
        // at boot). Dropping its cached copies makes the reads see what the DMA wrote.
        unsafe {
            self.scb.invalidate_dcache_by_address(line, LINE);
            core::ptr::copy_nonoverlapping(line as *const u8, left.as_mut_ptr(), FRAME.width);
            core::ptr::copy_nonoverlapping((line + FRAME.width) as *const u8, right.as_mut_ptr(), FRAME.width);
        }
        Ok(())
    }

    fn start(&mut self) {
        with_capture(|c| c.start(0));
    }

    fn stop(&mut self) {
        with_capture(Capture::stop);
    }

    /// The DCMI's crop window starts at any line: a capture re-armed at a row takes the rest of
    /// the sensor's next frame.
    fn restarts(&self) -> bool {
        true
    }

    /// Re-arms the snapshot from `row` (the capture was stopped by `stop`: DCMI and stream
    /// disabled, the DMA's slots back): the registers as for a new frame, the window lower.
    fn restart_from(&mut self, row: usize) {
        with_capture(|c| {
            // The DCMI's capture and the stream must be off for the window, the targets, the
            // count and CT to be written; `stop` turned them off, and doing it again is harmless.
            halt();
            c.start(row)
        });
    }

    fn wait(&mut self) {
        cortex_m::interrupt::free(|cs| {
            if !CAPTURE.borrow(cs).borrow().queue.ready() {
                // Masked: a line's or the SysTick's interrupt wakes the core and runs once
                // `free` ends.
                cortex_m::asm::wfi();
            }
        });
    }

    fn now_ms(&mut self) -> u32 {
        (clock::tick() / u64::from(CORE_HZ / 1000)) as u32
    }
}
