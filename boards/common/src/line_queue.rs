//! Camera rows through a heapless queue: what a board's camera interrupt (a DCMI's DMA, a
//! parallel or MIPI bridge) and the pipeline's [`RowSource`] share, the same path the QEMU
//! firmware models (`firmware-sim/src/camera.rs`).
//!
//! [`LINES`] line buffers each hold one side-by-side line (`2 x width` bytes: the left view's
//! row, then the right's). The producer (the interrupt) takes a free slot for the next line
//! ([`LineQueue::take_free`]), and once the line has landed there pushes its row index and slot
//! into a `heapless::spsc::Queue` ([`LineQueue::push`]). The consumer, [`QueuedRows`], pops a
//! line, copies it into the pipeline's row buffers and hands the slot back over the free-slot
//! queue; while nothing is queued it sleeps (the board's [`LinePort::wait`]: `wfi`).
//!
//! The camera never waits: a line that finds no free slot is lost and counted
//! ([`LineQueue::lose`]), and the pipeline gets [`Error::RowsLost`] instead of a later row,
//! never a silent gap. A frame that ends before its height is [`Error::EndOfRows`]; a camera
//! that sends nothing for the port's timeout is [`Error::RowsStalled`], never an endless wait.
//! Every frame starts clean: the producer stopped, the queue emptied, every slot free, the
//! counters zeroed, whatever the last frame left.
//!
//! The memory of the line buffers is the board's (the DMA writes it), reached only through
//! [`LinePort::read_line`]; this module keeps the slots' bookkeeping, so it runs the same on
//! the host (the tests) and on a board, where the queue sits in a critical-section mutex shared
//! with the interrupt.

use bino_core::pipeline::RowSource;
use bino_core::Error;
use heapless::spsc::Queue;

/// Line buffers: how far the camera may run ahead of the pipeline, in lines.
pub const LINES: usize = 8;

/// Bytes of one side-by-side line of views `width` pixels wide.
pub const fn line_bytes(width: usize) -> usize {
    2 * width
}

/// A filled line: the image row it holds and the slot it is in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Line {
    /// Row of the frame (0 = top).
    pub row: u16,
    /// Slot of the line buffers, `0..LINES`.
    pub slot: u8,
}

/// What a frame's queue saw, for the board's log.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct QueueStats {
    /// Lines the producer queued.
    pub queued: usize,
    /// Lines lost because no slot was free.
    pub lost: usize,
    /// Most lines waiting in the queue at once.
    pub high_water: usize,
    /// The producer has said the frame ended.
    pub ended: bool,
}

/// The slots' bookkeeping: filled lines in row order, free slots, the frame's counters.
#[derive(Debug)]
pub struct LineQueue {
    /// Filled lines, oldest first (producer: the interrupt; consumer: the pipeline).
    filled: Queue<Line, { LINES + 1 }>,
    /// Free slots (producer: the pipeline, as it is done with a line; consumer: the interrupt).
    free: Queue<u8, { LINES + 1 }>,
    stats: QueueStats,
}

impl Default for LineQueue {
    fn default() -> Self {
        Self::new()
    }
}

impl LineQueue {
    /// A queue with no free slot yet (a `static` needs a `const` constructor):
    /// [`LineQueue::reset`] before the first frame frees them all.
    pub const fn new() -> Self {
        Self {
            filled: Queue::new(),
            free: Queue::new(),
            stats: QueueStats {
                queued: 0,
                lost: 0,
                high_water: 0,
                ended: false,
            },
        }
    }

    /// A new frame: no line queued, every slot free, every counter zeroed. The producer must be
    /// stopped (it holds no slot afterwards).
    pub fn reset(&mut self) {
        while self.filled.dequeue().is_some() {}
        while self.free.dequeue().is_some() {}
        for slot in 0..LINES as u8 {
            // Cannot fail: the queue was just emptied and holds LINES.
            let _ = self.free.enqueue(slot);
        }
        self.stats = QueueStats::default();
    }

    /// Producer: a free slot for the next line, if any is left.
    pub fn take_free(&mut self) -> Option<usize> {
        self.free.dequeue().map(usize::from)
    }

    /// Producer: row `row` has landed in `slot` (one [`LineQueue::take_free`] gave). A slot out
    /// of range or a row past `u16` counts as lost.
    pub fn push(&mut self, row: usize, slot: usize) {
        let line = match (u16::try_from(row), u8::try_from(slot)) {
            (Ok(row), Ok(slot)) if usize::from(slot) < LINES => Line { row, slot },
            _ => return self.lose(),
        };
        if self.filled.enqueue(line).is_err() {
            // More lines than slots: a producer that pushed a slot twice; never silently.
            return self.lose();
        }
        self.stats.queued += 1;
        self.stats.high_water = self.stats.high_water.max(self.filled.len());
    }

    /// Producer: a line found no free slot (or its transfer failed): lost.
    pub fn lose(&mut self) {
        self.stats.lost += 1;
    }

    /// Producer: the frame ended; no more lines come until the next [`LineQueue::reset`].
    pub fn end(&mut self) {
        self.stats.ended = true;
    }

    /// Producer: hands back a slot it took but will not fill (the frame ended first).
    pub fn give_back(&mut self, slot: usize) {
        self.release(slot);
    }

    /// Consumer: the oldest filled line; its slot stays the consumer's until
    /// [`LineQueue::release`].
    pub fn pop(&mut self) -> Option<Line> {
        self.filled.dequeue()
    }

    /// Consumer: done with `slot`'s line; the producer may fill it again.
    pub fn release(&mut self, slot: usize) {
        if let Ok(slot) = u8::try_from(slot) {
            if usize::from(slot) < LINES {
                // Fails only for a slot handed back twice: the queue holds every slot once.
                let _ = self.free.enqueue(slot);
            }
        }
    }

    /// Whether a waiting consumer has nothing to wait for: a line is queued, or the frame
    /// ended.
    pub fn ready(&self) -> bool {
        !self.filled.is_empty() || self.stats.ended
    }

    /// Slots free for the producer now.
    pub fn free_slots(&self) -> usize {
        self.free.len()
    }

    /// The frame's counters so far.
    pub fn stats(&self) -> QueueStats {
        self.stats
    }
}

/// What a board gives [`QueuedRows`]: the shared queue, the line buffers' memory, the producer's
/// start and stop, a way to sleep and a millisecond clock.
pub trait LinePort {
    /// Runs `f` on the queue the producer shares (in a critical section on a board).
    fn with_queue<R>(&mut self, f: impl FnOnce(&mut LineQueue) -> R) -> R;
    /// Copies `slot`'s line into `left` and `right` (`width` bytes each: the line's first and
    /// second half). The slot is the consumer's: the producer does not write it meanwhile.
    fn read_line(&mut self, slot: usize, left: &mut [u8], right: &mut [u8]) -> Result<(), Error>;
    /// Starts the producer on a new frame (the queue was just reset).
    fn start(&mut self);
    /// Stops the producer: afterwards it takes, pushes and loses nothing (at once if stopped).
    fn stop(&mut self);
    /// Sleeps until the producer may have pushed a line or the clock moved (`wfi`), or
    /// returns at once when the queue is [`ready`](LineQueue::ready).
    fn wait(&mut self);
    /// A free-running millisecond counter (wraps).
    fn now_ms(&mut self) -> u32;
}

/// The pipeline's [`RowSource`] over a [`LinePort`]: one frame of `height` rows per run.
pub struct QueuedRows<P> {
    port: P,
    width: usize,
    height: usize,
    /// Milliseconds `next_row` waits for a line before [`Error::RowsStalled`].
    stall_ms: u32,
    /// Next row the pipeline gets.
    next: usize,
    /// The producer runs on this frame (started at the first request).
    started: bool,
}

impl<P: LinePort> QueuedRows<P> {
    /// Frames of `height` rows of views `width` pixels wide from `port`, waiting at most
    /// `stall_ms` for each row. The producer starts at the first row asked for.
    pub fn new(port: P, width: usize, height: usize, stall_ms: u32) -> Self {
        Self {
            port,
            width,
            height,
            stall_ms,
            next: 0,
            started: false,
        }
    }

    /// Stops the producer; the next request starts a new frame, clean (after an error too).
    pub fn rewind(&mut self) {
        self.port.stop();
        self.port.with_queue(LineQueue::reset);
        (self.next, self.started) = (0, false);
    }

    /// The frame's counters so far.
    pub fn stats(&mut self) -> QueueStats {
        self.port.with_queue(|q| q.stats())
    }

    /// Rows handed to the pipeline this frame.
    pub fn delivered(&self) -> usize {
        self.next
    }

    /// The port (a test's producer, a board's DMA state).
    pub fn port_mut(&mut self) -> &mut P {
        &mut self.port
    }

    fn lost(&mut self) -> Error {
        Error::RowsLost {
            row: self.next,
            lost: self.stats().lost,
        }
    }
}

impl<P: LinePort> RowSource for QueuedRows<P> {
    fn width(&self) -> usize {
        self.width
    }

    fn height(&self) -> usize {
        self.height
    }

    fn next_row(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), Error> {
        Error::check_len("left row buffer", self.width, left.len())?;
        Error::check_len("right row buffer", self.width, right.len())?;
        if !self.started {
            self.rewind();
            self.port.start();
            self.started = true;
        }
        if self.next >= self.height {
            return Err(Error::EndOfRows {
                row: self.next,
                height: self.height,
            });
        }
        let since = self.port.now_ms();
        loop {
            match self.port.with_queue(|q| q.pop().ok_or(q.stats())) {
                Ok(line) => {
                    let slot = usize::from(line.slot);
                    let copied = self.port.read_line(slot, left, right);
                    self.port.with_queue(|q| q.release(slot));
                    copied?;
                    // A row other than the next one: lines in between were lost.
                    if usize::from(line.row) != self.next {
                        return Err(self.lost());
                    }
                    self.next += 1;
                    return Ok(());
                }
                Err(stats) if stats.lost > 0 && stats.ended => return Err(self.lost()),
                Err(stats) if stats.ended => {
                    return Err(Error::EndOfRows {
                        row: self.next,
                        height: self.next,
                    })
                }
                Err(stats) => {
                    let waited_ms = self.port.now_ms().wrapping_sub(since);
                    if waited_ms >= self.stall_ms {
                        return Err(if stats.lost > 0 {
                            self.lost()
                        } else {
                            Error::RowsStalled {
                                row: self.next,
                                waited_ms,
                            }
                        });
                    }
                    self.port.wait();
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bad_slot_or_row_is_lost_and_a_slot_comes_back_once() {
        let mut q = LineQueue::new();
        assert_eq!(q.take_free(), None, "no slot before the first reset");
        q.reset();
        assert_eq!(q.free_slots(), LINES);
        let slot = q.take_free().unwrap();
        q.push(usize::from(u16::MAX) + 1, slot);
        q.push(0, LINES);
        assert_eq!((q.stats().queued, q.stats().lost), (0, 2));
        assert!(!q.ready());
        q.push(3, slot);
        assert!(q.ready());
        assert_eq!(
            q.pop(),
            Some(Line {
                row: 3,
                slot: slot as u8
            })
        );
        // Handed back twice, or out of range: the free slots stay the LINES distinct ones.
        q.release(slot);
        q.release(slot);
        q.release(LINES);
        assert_eq!(q.free_slots(), LINES);
        let mut taken = [usize::MAX; LINES];
        for t in taken.iter_mut() {
            *t = q.take_free().unwrap();
        }
        taken.sort_unstable();
        assert_eq!(taken, core::array::from_fn(|i| i));
        assert_eq!(q.take_free(), None);
        q.end();
        assert!(q.ready());
        q.reset();
        assert_eq!((q.stats(), q.free_slots()), (QueueStats::default(), LINES));
    }
}
