//! The producer side of the line queue ([`crate::line_queue`]) for a DMA in double-buffer mode
//! (the STM32H743's DCMI stream): two target registers, one line each; while the DMA writes
//! one, the other is set up for the line after. Its transfer-complete interrupt calls
//! [`DoubleBuffer::line_done`], which queues the line just finished and says what that target
//! takes next: a free slot, the discard line when none is free (the line written there is
//! lost and counted), or that the frame is complete.
//!
//! A target is set up one line ahead, so a line is lost when no slot was free as its target
//! was set up, even if one came free while it was written. With nobody reading, [`LINES`]
//! lines are queued and the rest lost, as in the QEMU firmware's model; or, when the queue
//! [resumes](LineQueue::resumes), the capture stops before the first row whose target found no
//! slot (the line being written then still lands in its slot, so all [`LINES`] are queued) and
//! is re-armed from that row later ([`DoubleBuffer::start`] at a row). The `k`-th row of a
//! capture is always in target `k % 2`: an interrupt served so late that the next line finished
//! too shows as the other target finishing, and the rest of the frame is lost rather than
//! mislabelled. Bookkeeping only: the board writes the registers.

use crate::line_queue::LineQueue;
#[cfg(doc)]
use crate::line_queue::LINES;

/// What a target takes after its line is done.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refill {
    /// A slot of the line buffers, or the discard line (`None`).
    Target(Option<usize>),
    /// The frame's last line is done: stop the DMA ([`DoubleBuffer::stop`]).
    FrameDone,
}

/// The two targets' slots and the frame's row count.
#[derive(Debug)]
pub struct DoubleBuffer {
    /// The slot each target points at; `None`: the discard line.
    targets: [Option<usize>; 2],
    /// The row of the next line to finish.
    row: usize,
    /// The capture's first row (target 0's).
    first: usize,
    /// The row the capture stops before: the frame's height, or the first row without a slot.
    end: usize,
    height: usize,
    running: bool,
}

impl DoubleBuffer {
    /// Frames of `height` lines; stopped.
    pub const fn new(height: usize) -> Self {
        Self {
            targets: [None, None],
            row: 0,
            first: 0,
            end: height,
            height,
            running: false,
        }
    }

    /// A capture starts at row `first` (0: the frame's start; later, a re-arm): a slot for each
    /// target (target 0 takes row `first`), from a queue holding no line.
    pub fn start(&mut self, queue: &mut LineQueue, first: usize) -> [Option<usize>; 2] {
        self.targets = [queue.take_free(), queue.take_free()];
        (self.row, self.first, self.end, self.running) = (first, first, self.height, true);
        self.targets
    }

    /// Target `done` (0 or 1) finished a line: it is queued (or lost, from the discard line);
    /// the target is refilled for the line after the one now being written. The other target
    /// than the row's (an interrupt missed) loses the rest of the frame.
    pub fn line_done(&mut self, queue: &mut LineQueue, done: usize) -> Refill {
        if !self.running {
            return Refill::FrameDone;
        }
        if done != (self.row - self.first) % 2 {
            // Two lines finished for one interrupt: the first target's slot was written over.
            self.lose_rest(queue);
            return Refill::FrameDone;
        }
        let Some(target) = self.targets.get_mut(done) else {
            return Refill::FrameDone;
        };
        let row = self.row;
        self.row += 1;
        match target.take() {
            Some(slot) => queue.push(row, slot),
            None => queue.lose(),
        }
        if self.row >= self.end {
            return Refill::FrameDone;
        }
        // The other target is writing row + 1; this one gets row + 2, if the capture has it.
        let after = row + 2;
        let next = if after < self.end { queue.take_free() } else { None };
        if next.is_none() && after < self.end && queue.resumes() {
            // No slot for it: the capture ends once row + 1 is done, and resumes there.
            queue.stop_at(after);
            self.end = after;
        }
        *target = next;
        Refill::Target(next)
    }

    /// The transfer failed or the camera overran: the line in flight and the rest of the frame
    /// are lost (a stopped capture's rows after its end too); the frame stops.
    pub fn lose_rest(&mut self, queue: &mut LineQueue) {
        if self.running {
            for _ in self.row..self.height {
                queue.lose();
            }
        }
        self.stop(queue);
    }

    /// The DMA has stopped: the targets' slots go back, and a running capture ends there (short
    /// of its height if lines are missing, or stopped to resume).
    pub fn stop(&mut self, queue: &mut LineQueue) {
        for slot in self.targets.iter_mut().filter_map(Option::take) {
            queue.give_back(slot);
        }
        if self.running {
            queue.end();
        }
        self.running = false;
    }

    /// Whether a frame is being captured.
    pub fn running(&self) -> bool {
        self.running
    }

    /// The row of the next line to finish: the frame's rows before it are done (queued, lost,
    /// or queued by an earlier capture).
    pub fn next_row(&self) -> usize {
        self.row
    }
}
