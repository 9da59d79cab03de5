//! The camera path: rows from an interrupt, as a DCMI or a parallel/MIPI bridge delivers them.
//!
//! The SysTick interrupt plays the sensor and its DMA: every row interval it exposes the next
//! row of the embedded frame (the band pair, or a whole frame), copies it into a free slot of the left/right line
//! buffers (what the DMA would write) and pushes the row's index and slot into a
//! `heapless::spsc::Queue` (producer: the interrupt). [`Camera`], the pipeline's `RowSource`,
//! is the consumer: it pops an index, copies the line into the band buffer and frees the slot.
//!
//! The sensor never waits: when every line buffer is taken (the queue is full) the row is
//! lost, counted, and the next `next_row` is an [`Error::RowsLost`], never a silent gap. The
//! sensor starts streaming at the pipeline's first request and stops after its last row, so
//! no interrupt lands in any later stage's instruction count.
//!
//! Under QEMU with `-icount shift=0` (scripts/firmware.sh) one executed instruction is 1 ns of
//! virtual time, so the row interval is set in instructions: the rate it stands for at the
//! core's clock is an IPC-1 figure, like every time in the budget. The interval paces the
//! sensor only: the instructions the pipeline executes do not depend on it, as long as no row is
//! lost (the firmware fails the run otherwise).

use core::cell::RefCell;

use bino_core::pipeline::RowSource;
use bino_core::Error;
use cortex_m::interrupt::{self, Mutex};
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::SYST;
use cortex_m_rt::exception;
use heapless::spsc::{Consumer, Producer, Queue};

use crate::expected::WIDTH;

/// Line buffers per view: how far the sensor may run ahead of the pipeline, in rows.
pub const LINES: usize = 8;

/// Bytes of the line buffers for rows `width` pixels wide: [`LINES`] slots of a row of each
/// view, `[slot][view][pixel]`.
pub const fn line_bytes(width: usize) -> usize {
    LINES * 2 * width
}

/// Executed instructions between two sensor rows (virtual time under `-icount shift=0`):
/// 100,000 rows/s at 400 MHz and one instruction per cycle, about four times what the
/// interrupt and the consumer's copies take per row (~1,060), so the queue never fills.
pub const ROW_INTERVAL_INSNS: u32 = 4_000;

/// Executed instructions between two sensor rows of the fast preset's whole frame: a camera
/// streaming 120-row frames at 4 per second into the Cortex-M55 at 400 MHz (480 rows/s, IPC 1),
/// at 3 per second into the Cortex-M7 at 480 MHz (360 rows/s). The census run reads four rows per
/// token row, each batch after the previous token row's work, so the line buffers hold the rows
/// that arrive meanwhile; a run slower than its camera loses rows and fails.
#[cfg(board = "an547")]
pub const FRAME_ROW_INTERVAL_INSNS: u32 = 400_000_000 / (4 * 120);
#[cfg(board = "an500")]
pub const FRAME_ROW_INTERVAL_INSNS: u32 = 480_000_000 / (3 * 120);

/// Executed instructions between two sensor rows of the learned preset's whole frame: slow
/// enough that the line buffers never overflow while a band is encoded (each band after the
/// first reads about 24 new rows, then encodes and reads out for about 0.7G instructions on
/// the Cortex-M55 and 4.2G on the Cortex-M7). A camera feeding the learned preset needs a
/// snapshot or frame buffer; the core waits (WFI, not counted) until its rows are there.
#[cfg(board = "an547")]
pub const LEARNED_FRAME_ROW_INTERVAL_INSNS: u32 = 100_000_000;
#[cfg(board = "an500")]
pub const LEARNED_FRAME_ROW_INTERVAL_INSNS: u32 = 600_000_000;

/// Executed instructions between two sensor rows of the fast preset on the E7's 240-row frame
/// (the Cortex-M55 only): a camera streaming it at one frame every two seconds at 400 MHz
/// (120 rows/s, IPC 1), slower than the run so that no row is lost.
#[cfg(feature = "frame320")]
pub const FRAME320_ROW_INTERVAL_INSNS: u32 = 400_000_000 / 120;

/// Executed instructions between two sensor rows of the learned preset on the E7's frame: each
/// of its 7 bands after the first reads about 24 new rows, then encodes and reads out for about
/// a seventh of the frame's instructions, while 8 line buffers hold what arrives meanwhile
/// (the SysTick reload's 24 bits allow at most ~524M at the board's 32 MHz).
#[cfg(feature = "frame320")]
pub const LEARNED_FRAME320_ROW_INTERVAL_INSNS: u32 = 500_000_000;

/// The board's SysTick clock (QEMU: the processor clock of the FPGA image).
#[cfg(board = "an547")]
const SYSTICK_HZ: u32 = 32_000_000;
#[cfg(board = "an500")]
const SYSTICK_HZ: u32 = 25_000_000;

/// SysTick reload for a row interval of `insns`: QEMU's virtual nanoseconds (= instructions) to
/// ticks.
const fn reload(insns: u32) -> u32 {
    (insns as u64 * SYSTICK_HZ as u64 / 1_000_000_000) as u32
}
const _: () = {
    let (band, frame) = (reload(ROW_INTERVAL_INSNS), reload(FRAME_ROW_INTERVAL_INSNS));
    let learned = reload(LEARNED_FRAME_ROW_INTERVAL_INSNS);
    assert!(band >= 16 && band < (1 << 24), "SysTick reload out of range");
    assert!(frame >= 16 && frame < (1 << 24), "SysTick reload out of range");
    assert!(learned >= 16 && learned < (1 << 24), "SysTick reload out of range");
};
#[cfg(feature = "frame320")]
const _: () = {
    let (fast, learned) = (
        reload(FRAME320_ROW_INTERVAL_INSNS),
        reload(LEARNED_FRAME320_ROW_INTERVAL_INSNS),
    );
    assert!(fast >= 16 && fast < (1 << 24), "SysTick reload out of range");
    assert!(learned >= 16 && learned < (1 << 24), "SysTick reload out of range");
};

/// A filled line: the image row it holds and the slot of the line buffers it is in.
#[derive(Debug, Clone, Copy)]
struct Line {
    row: u16,
    slot: u8,
}

/// What the interrupt owns: the timer, the producer end, the frame and its counters.
struct Sensor {
    syst: SYST,
    producer: Producer<'static, Line>,
    left: &'static [u8],
    right: &'static [u8],
    /// Pixels per row of the frame.
    width: usize,
    /// The line buffers for rows up to the band's width ([`line_bytes`]`(WIDTH)`, `.bss`):
    /// what the DMA writes.
    narrow: &'static mut [u8],
    /// The line buffers for wider rows (the E7 frame's, outside the DTCM); empty without them.
    wide: &'static mut [u8],
    /// The rows of the frame.
    rows: usize,
    /// Next row the sensor exposes.
    next: usize,
    /// Rows put into line buffers so far (the next one goes to slot `filled % LINES`).
    filled: usize,
    /// Rows lost because every line buffer was taken.
    lost: usize,
    /// Most lines waiting in the queue at once.
    queue_high_water: usize,
    /// The timer runs (between `start` and the last row or `stop`).
    running: bool,
}

/// The line buffers that hold [`LINES`] rows `width` wide: `narrow` when it does, else `wide`.
fn line_buffers<'a>(narrow: &'a mut [u8], wide: &'a mut [u8], width: usize) -> &'a mut [u8] {
    if line_bytes(width) <= narrow.len() {
        narrow
    } else {
        wide
    }
}

impl Sensor {
    /// One row interval: expose the next row into the line buffers, or stop after the last.
    fn tick(&mut self) {
        if self.next >= self.rows {
            self.stop();
            return;
        }
        let row = self.next;
        self.next += 1;
        let slot = self.filled % LINES;
        let width = self.width;
        let range = row * width..(row + 1) * width;
        let lines = line_buffers(self.narrow, self.wide, width);
        let line = lines.get_mut(2 * width * slot..2 * width * (slot + 1));
        match (self.left.get(range.clone()), self.right.get(range), line) {
            (Some(l), Some(r), Some(line)) if self.producer.ready() => {
                let (to_l, to_r) = line.split_at_mut(width);
                to_l.copy_from_slice(l);
                to_r.copy_from_slice(r);
                // Cannot fail: ready() was true and only this interrupt produces.
                let _ = self.producer.enqueue(Line {
                    row: row as u16,
                    slot: slot as u8,
                });
                self.filled += 1;
                self.queue_high_water = self.queue_high_water.max(self.producer.len());
            }
            _ => self.lost += 1,
        }
        if self.next >= self.rows {
            self.stop();
        }
    }

    fn stop(&mut self) {
        self.syst.disable_interrupt();
        self.syst.disable_counter();
        self.running = false;
    }
}

/// The sensor, shared between the interrupt and [`Camera`] (which starts it and reads its
/// line buffers), each access in a critical section.
static SENSOR: Mutex<RefCell<Option<Sensor>>> = Mutex::new(RefCell::new(None));

#[exception]
fn SysTick() {
    interrupt::free(|cs| {
        if let Some(sensor) = SENSOR.borrow(cs).borrow_mut().as_mut() {
            sensor.tick();
        }
    });
}

/// What the camera path reports after a frame.
#[derive(Debug, Clone, Copy)]
pub struct CameraStats {
    /// Rows handed to the pipeline.
    pub delivered: usize,
    /// Rows the sensor lost (queue full).
    pub lost: usize,
    /// Most lines waiting in the queue at once.
    pub queue_high_water: usize,
}

/// The consumer end: a `RowSource` fed by the interrupt.
pub struct Camera {
    consumer: Consumer<'static, Line>,
    started: bool,
    /// Next row the pipeline gets.
    next: usize,
    /// Pixels per row of the frame.
    width: usize,
    /// Rows of the frame.
    height: usize,
}

impl Camera {
    /// Sets up the sensor with no frame and its timer stopped ([`Camera::load`] gives it
    /// one), its line buffers for rows up to the band's width in `.bss` and for wider rows
    /// `wide` (empty: none); `None` if called twice (the queue and the line buffers are
    /// singletons). Not inlined: its temporaries stay out of the caller's frame, which the
    /// whole run keeps.
    #[inline(never)]
    pub fn new(syst: SYST, wide: &'static mut [u8]) -> Option<Self> {
        let queue: &'static mut Queue<Line, { LINES + 1 }> =
            cortex_m::singleton!(: Queue<Line, { LINES + 1 }> = Queue::new())?;
        let narrow: &'static mut [u8; line_bytes(WIDTH)] =
            cortex_m::singleton!(: [u8; line_bytes(WIDTH)] = [0; line_bytes(WIDTH)])?;
        let (producer, consumer) = queue.split();
        let mut sensor = Sensor {
            syst,
            producer,
            left: &[],
            right: &[],
            width: 0,
            narrow,
            wide,
            rows: 0,
            next: 0,
            filled: 0,
            lost: 0,
            queue_high_water: 0,
            running: false,
        };
        sensor.syst.disable_counter();
        sensor.syst.set_clock_source(SystClkSource::Core);
        sensor.syst.clear_current();
        interrupt::free(|cs| *SENSOR.borrow(cs).borrow_mut() = Some(sensor));
        Some(Self {
            consumer,
            started: false,
            next: 0,
            width: 0,
            height: 0,
        })
    }

    /// Stops the sensor and points it at another frame, `left`/`right` (`rows x width` each;
    /// rows wider than the line buffers are lost), a row every `interval_insns` instructions;
    /// the next request starts it (as [`Camera::rewind`]).
    pub fn load(&mut self, left: &'static [u8], right: &'static [u8], width: usize, rows: usize, interval_insns: u32) {
        let rows = rows.min(left.len().min(right.len()).checked_div(width).unwrap_or(0));
        interrupt::free(|cs| {
            if let Some(s) = SENSOR.borrow(cs).borrow_mut().as_mut() {
                s.stop();
                (s.left, s.right, s.width) = (left, right, width);
                s.syst.set_reload(reload(interval_insns).max(16) - 1);
            }
        });
        (self.width, self.height) = (width, rows);
        self.rewind(rows);
    }

    /// Starts the sensor (the first row comes one interval later).
    pub fn start(&mut self) {
        interrupt::free(|cs| {
            if let Some(s) = SENSOR.borrow(cs).borrow_mut().as_mut() {
                s.syst.clear_current();
                s.syst.enable_interrupt();
                s.syst.enable_counter();
                s.running = true;
            }
        });
        self.started = true;
    }

    /// Stops the sensor and empties the line buffers: the next request starts a new frame of
    /// `rows` rows (at most the frame's), after which the sensor stops by itself.
    pub fn rewind(&mut self, rows: usize) {
        interrupt::free(|cs| {
            if let Some(s) = SENSOR.borrow(cs).borrow_mut().as_mut() {
                s.stop();
                s.syst.clear_current();
                (s.next, s.filled, s.lost, s.queue_high_water) = (0, 0, 0, 0);
                s.rows = rows.min(s.left.len().min(s.right.len()).checked_div(s.width).unwrap_or(0));
            }
            while self.consumer.dequeue().is_some() {}
        });
        (self.next, self.started) = (0, false);
    }

    /// Waits until the sensor has stopped (after its frame's last row, or at once if it is not
    /// running), taking no rows: lets it run ahead of the pipeline.
    pub fn wait_stopped(&mut self) {
        loop {
            let done = interrupt::free(|cs| {
                let s = SENSOR.borrow(cs).borrow();
                let done = s.as_ref().is_none_or(|s| !s.running);
                if !done {
                    // Masked: the tick that is due wakes the core and runs once `free` ends.
                    cortex_m::asm::wfi();
                }
                done
            });
            if done {
                return;
            }
        }
    }

    /// Rows delivered and lost so far.
    pub fn stats(&self) -> CameraStats {
        interrupt::free(|cs| {
            let s = SENSOR.borrow(cs).borrow();
            CameraStats {
                delivered: self.next,
                lost: s.as_ref().map_or(0, |s| s.lost),
                queue_high_water: s.as_ref().map_or(0, |s| s.queue_high_water),
            }
        })
    }

    /// Takes one line off the queue into `left`/`right`, waiting for the interrupt when the
    /// queue is empty. `Ok(None)`: the sensor has stopped with nothing left to give.
    fn take_line(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<Option<usize>, Error> {
        loop {
            let taken = interrupt::free(|cs| {
                let mut sensor = SENSOR.borrow(cs).borrow_mut();
                let Some(s) = sensor.as_mut() else {
                    return Some(None);
                };
                if let Some(line) = self.consumer.dequeue() {
                    // The slot stays ours until this critical section ends: the interrupt can
                    // refill it only after the dequeue, and cannot run before we copied.
                    let width = s.width;
                    let lines = line_buffers(s.narrow, s.wide, width);
                    let at = 2 * width * usize::from(line.slot);
                    // next_row checked both buffers against the frame's width.
                    if let Some((l, r)) = lines.get(at..at + 2 * width).map(|b| b.split_at(width)) {
                        left.copy_from_slice(l);
                        right.copy_from_slice(r);
                    }
                    return Some(Some(usize::from(line.row)));
                }
                if !s.running {
                    return Some(None);
                }
                // Masked: the tick that is due wakes the core and runs once `free` ends.
                cortex_m::asm::wfi();
                None
            });
            if let Some(t) = taken {
                return Ok(t);
            }
        }
    }
}

impl RowSource for Camera {
    fn width(&self) -> usize {
        self.width
    }

    fn height(&self) -> usize {
        self.height
    }

    fn next_row(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), Error> {
        for (buf, what) in [(&*left, "left row buffer"), (&*right, "right row buffer")] {
            if buf.len() != self.width {
                return Err(Error::BufferSize {
                    what,
                    expected: self.width,
                    found: buf.len(),
                });
            }
        }
        if !self.started {
            self.start();
        }
        let lost = |camera: &Self| Error::RowsLost {
            row: camera.next,
            lost: camera.stats().lost,
        };
        match self.take_line(left, right)? {
            Some(row) if row == self.next => {
                self.next += 1;
                Ok(())
            }
            Some(_) => Err(lost(self)),
            None if self.stats().lost > 0 => Err(lost(self)),
            None => Err(Error::EndOfRows {
                row: self.next,
                height: self.next,
            }),
        }
    }
}
