//! Camera rows through a heapless queue: what a board's camera interrupt (a DCMI's DMA, a
//! parallel or MIPI bridge) and the pipeline's [`RowSource`] share, the same path the QEMU
//! firmware models (`firmware-sim/src/camera.rs`; its sensor is never re-armed, but paced so that
//! no row is lost).
//!
//! [`LINES`] line buffers each hold one side-by-side line (`2 x width` bytes: the left view's
//! row, then the right's). The producer (the interrupt) takes a free slot for the next line
//! ([`LineQueue::take_free`]), and once the line has landed there pushes its row index and slot
//! into a `heapless::spsc::Queue` ([`LineQueue::push`]). The consumer, [`QueuedRows`], pops a
//! line, copies it into the pipeline's row buffers and hands the slot back over the free-slot
//! queue; while nothing is queued it sleeps (the board's [`LinePort::wait`]: `wfi`).
//!
//! The camera never waits. A line that finds no free slot ends the capture there when the port
//! can re-arm its camera mid-frame ([`LinePort::restarts`]): the producer records that row
//! ([`LineQueue::stop_at`]) and drops the rest of that sensor frame; the consumer drains the
//! rows already queued, and when the pipeline asks for the missing row it re-arms the camera
//! from there ([`LinePort::restart_from`]), so the sensor's next frame delivers the rest. No row
//! is lost and they come in order, but a frame is then stitched from several sensor frames (the
//! re-arms are counted: [`QueueStats::captures`]); in a moving scene its bands are from
//! different moments, as with a rolling shutter. A port that cannot re-arm mid-frame loses the
//! line and counts it ([`LineQueue::lose`]), and the pipeline gets [`Error::RowsLost`] instead
//! of a later row, never a silent gap; so does a failed transfer on any port. A frame that ends
//! before its height is [`Error::EndOfRows`]; a camera that sends nothing for the port's timeout
//! (after a start or a re-arm too) is [`Error::RowsStalled`], never an endless wait.
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
    /// The producer has said the frame ended (or, resuming, that its capture stopped).
    pub ended: bool,
    /// Camera frames this frame's rows came from: the capture started at the frame's first row
    /// and each re-arm at a row that found no free slot (1: no re-arm).
    pub captures: usize,
}

/// The slots' bookkeeping: filled lines in row order, free slots, the frame's counters.
#[derive(Debug)]
pub struct LineQueue {
    /// Filled lines, oldest first (producer: the interrupt; consumer: the pipeline).
    filled: Queue<Line, { LINES + 1 }>,
    /// Free slots (producer: the pipeline, as it is done with a line; consumer: the interrupt).
    free: Queue<u8, { LINES + 1 }>,
    stats: QueueStats,
    /// A line without a free slot stops the capture ([`LineQueue::stop_at`]) rather than being
    /// lost: the port re-arms its camera from that row.
    resumes: bool,
    /// The first row the stopped capture did not store: where it resumes.
    resume_at: Option<usize>,
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
                captures: 0,
            },
            resumes: false,
            resume_at: None,
        }
    }

    /// A new frame: no line queued, every slot free, every counter zeroed; a line without a
    /// free slot stops the capture if `resumes` (the port re-arms mid-frame), else is lost. The
    /// producer must be stopped (it holds no slot afterwards).
    pub fn reset(&mut self, resumes: bool) {
        while self.filled.dequeue().is_some() {}
        while self.free.dequeue().is_some() {}
        for slot in 0..LINES as u8 {
            // Cannot fail: the queue was just emptied and holds LINES.
            let _ = self.free.enqueue(slot);
        }
        self.stats = QueueStats::default();
        (self.resumes, self.resume_at) = (resumes, None);
    }

    /// Consumer: a capture is armed (the frame's first, or a re-arm after
    /// [`LineQueue::stop_at`]): counted; the stopped capture's end and row are forgotten. The
    /// producer must be stopped.
    pub fn arm(&mut self) {
        self.stats.captures += 1;
        (self.stats.ended, self.resume_at) = (false, None);
    }

    /// Whether a line without a free slot stops the capture ([`LineQueue::stop_at`]) rather
    /// than being lost ([`LineQueue::lose`]).
    pub fn resumes(&self) -> bool {
        self.resumes
    }

    /// Producer, resuming: row `row` found no free slot; the capture stops before it (the
    /// producer takes no more lines until re-armed) and resumes there. The first such row
    /// counts.
    pub fn stop_at(&mut self, row: usize) {
        self.resume_at = self.resume_at.or(Some(row));
    }

    /// Where the stopped capture resumes, if it stopped for want of a slot.
    pub fn resume_at(&self) -> Option<usize> {
        self.resume_at
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

    /// Whether a waiting consumer has nothing to wait for: a line is queued, the frame ended,
    /// or the capture stopped to resume.
    pub fn ready(&self) -> bool {
        !self.filled.is_empty() || self.stats.ended || self.resume_at.is_some()
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
/// start, re-arm and stop, a way to sleep and a millisecond clock.
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
    /// Whether the producer can be re-armed mid-frame ([`LinePort::restart_from`]): a camera
    /// whose capture can start at any row of its next frame (a crop window). Without it a line
    /// that finds no free slot is lost.
    fn restarts(&self) -> bool;
    /// Re-arms the stopped producer on the camera's next frame from row `row` on (to the
    /// frame's last row); the queue holds no line and the producer no slot. Called only if
    /// [`LinePort::restarts`].
    fn restart_from(&mut self, row: usize);
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
    /// Milliseconds `next_row` waits for a line before [`Error::RowsStalled`]; after a start
    /// or a re-arm the first row waits for the camera's next frame, and then for its row.
    stall_ms: u32,
    /// Next row the pipeline gets.
    next: usize,
    /// The producer runs on this frame (started at the first request).
    started: bool,
}

impl<P: LinePort> QueuedRows<P> {
    /// Frames of `height` rows of views `width` pixels wide from `port`, waiting at most
    /// `stall_ms` for each row (more than two of the camera's frame periods: a re-arm waits for
    /// the next frame's start, then for the row). The producer starts at the first row asked
    /// for.
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
        let resumes = self.port.restarts();
        self.port.with_queue(|q| q.reset(resumes));
        (self.next, self.started) = (0, false);
    }

    /// The capture stopped at the next row for want of a slot and every row before it is
    /// delivered: re-arms the camera from it.
    fn resume(&mut self) {
        self.port.stop();
        self.port.with_queue(LineQueue::arm);
        self.port.restart_from(self.next);
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
            self.port.with_queue(LineQueue::arm);
            self.port.start();
            self.started = true;
        }
        if self.next >= self.height {
            return Err(Error::EndOfRows {
                row: self.next,
                height: self.height,
            });
        }
        let mut since = self.port.now_ms();
        // Re-armed for this row: with every slot free the row must come, or the port is broken.
        let mut rearmed = false;
        loop {
            match self.port.with_queue(|q| q.pop().ok_or((q.stats(), q.resume_at()))) {
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
                // Every row before the stop is delivered: the camera's next frame gives the
                // rest, and the wait for it starts now.
                Err((_, Some(row))) if row == self.next && !rearmed => {
                    self.resume();
                    (since, rearmed) = (self.port.now_ms(), true);
                }
                // Stopped past a row the queue never got, or again before the re-armed row: lost.
                Err((_, Some(_))) => return Err(self.lost()),
                Err((stats, None)) if stats.lost > 0 && stats.ended => return Err(self.lost()),
                Err((stats, None)) if stats.ended => {
                    return Err(Error::EndOfRows {
                        row: self.next,
                        height: self.next,
                    })
                }
                Err((stats, None)) => {
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
        q.reset(false);
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
        q.reset(false);
        assert_eq!((q.stats(), q.free_slots()), (QueueStats::default(), LINES));
    }

    #[test]
    fn a_stop_keeps_its_first_row_until_the_re_arm() {
        let mut q = LineQueue::new();
        q.reset(true);
        assert!(q.resumes() && !q.ready());
        q.arm();
        q.stop_at(5);
        q.stop_at(7);
        assert_eq!(q.resume_at(), Some(5));
        assert!(q.ready(), "a stopped capture is nothing to wait for");
        q.end();
        q.arm();
        assert_eq!((q.resume_at(), q.stats().ended, q.stats().captures), (None, false, 2));
        assert!(!q.ready());
        q.reset(false);
        assert_eq!((q.resumes(), q.resume_at(), q.stats().captures), (false, None, 0));
    }
}
