//! The camera path: rows from an interrupt, as a DCMI or a parallel/MIPI bridge delivers them.
//!
//! The SysTick interrupt plays the sensor and its DMA: every row interval it exposes the next
//! row of the embedded frame (the band pair, or the fast preset's whole frame), copies it into a free slot of the left/right line
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

/// The line buffers, `[slot][view][pixel]`: what the DMA writes, a zeroed static (`.bss`).
type Lines = [[[u8; WIDTH]; 2]; LINES];

impl Sensor {
    /// One row interval: expose the next row into `lines`, or stop after the last.
    fn tick(&mut self, lines: &mut Lines) {
        if self.next >= self.rows {
            self.stop();
            return;
        }
        let row = self.next;
        self.next += 1;
        let slot = self.filled % LINES;
        let range = row * WIDTH..(row + 1) * WIDTH;
        match (self.left.get(range.clone()), self.right.get(range)) {
            (Some(l), Some(r)) if self.producer.ready() => {
                lines[slot][0].copy_from_slice(l);
                lines[slot][1].copy_from_slice(r);
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

/// The line buffers, shared the same way.
static LINE_BUFFERS: Mutex<RefCell<Lines>> = Mutex::new(RefCell::new([[[0; WIDTH]; 2]; LINES]));

#[exception]
fn SysTick() {
    interrupt::free(|cs| {
        if let Some(sensor) = SENSOR.borrow(cs).borrow_mut().as_mut() {
            sensor.tick(&mut LINE_BUFFERS.borrow(cs).borrow_mut());
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
    /// Rows of the frame.
    height: usize,
}

impl Camera {
    /// Sets up the sensor on the frame `left`/`right` (`rows x WIDTH` each), a row every
    /// [`ROW_INTERVAL_INSNS`], with its timer stopped; `None` if called twice (the queue is a
    /// singleton). Not inlined: its temporaries stay out of the caller's frame, which the whole
    /// run keeps.
    #[inline(never)]
    pub fn new(syst: SYST, left: &'static [u8], right: &'static [u8], rows: usize) -> Option<Self> {
        let queue: &'static mut Queue<Line, { LINES + 1 }> =
            cortex_m::singleton!(: Queue<Line, { LINES + 1 }> = Queue::new())?;
        let (producer, consumer) = queue.split();
        let mut sensor = Sensor {
            syst,
            producer,
            left,
            right,
            rows: rows.min(left.len().min(right.len()) / WIDTH),
            next: 0,
            filled: 0,
            lost: 0,
            queue_high_water: 0,
            running: false,
        };
        sensor.syst.disable_counter();
        sensor.syst.set_clock_source(SystClkSource::Core);
        sensor.syst.set_reload(reload(ROW_INTERVAL_INSNS) - 1);
        sensor.syst.clear_current();
        let height = sensor.rows;
        interrupt::free(|cs| *SENSOR.borrow(cs).borrow_mut() = Some(sensor));
        Some(Self {
            consumer,
            started: false,
            next: 0,
            height,
        })
    }

    /// Stops the sensor and points it at another frame, `left`/`right` (`rows x WIDTH` each), a
    /// row every `interval_insns` instructions; the next request starts it (as [`Camera::rewind`]).
    pub fn load(&mut self, left: &'static [u8], right: &'static [u8], rows: usize, interval_insns: u32) {
        let rows = rows.min(left.len().min(right.len()) / WIDTH);
        interrupt::free(|cs| {
            if let Some(s) = SENSOR.borrow(cs).borrow_mut().as_mut() {
                s.stop();
                (s.left, s.right) = (left, right);
                s.syst.set_reload(reload(interval_insns).max(16) - 1);
            }
        });
        self.height = rows;
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
                s.rows = rows.min(s.left.len().min(s.right.len()) / WIDTH);
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
                let sensor = SENSOR.borrow(cs).borrow();
                let Some(s) = sensor.as_ref() else {
                    return Some(None);
                };
                if let Some(line) = self.consumer.dequeue() {
                    // The slot stays ours until this critical section ends: the interrupt can
                    // refill it only after the dequeue, and cannot run before we copied.
                    let lines = LINE_BUFFERS.borrow(cs).borrow();
                    let [l, r] = &lines[usize::from(line.slot) % LINES];
                    left.copy_from_slice(l);
                    right.copy_from_slice(r);
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
        WIDTH
    }

    fn height(&self) -> usize {
        self.height
    }

    fn next_row(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), Error> {
        for (buf, what) in [(&*left, "left row buffer"), (&*right, "right row buffer")] {
            if buf.len() != WIDTH {
                return Err(Error::BufferSize {
                    what,
                    expected: WIDTH,
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
