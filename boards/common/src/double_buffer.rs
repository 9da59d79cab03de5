//! The producer side of the line queue ([`crate::line_queue`]) for a DMA in double-buffer mode
//! (the STM32H743's DCMI stream): two target registers, one line each; while the DMA writes
//! one, the other is set up for the line after. Its transfer-complete interrupt calls
//! [`DoubleBuffer::line_done`], which queues the line just finished and says what that target
//! takes next: a free slot, the discard line when none is free (the line written there is
//! lost and counted), or that the frame is complete.
//!
//! A target is set up one line ahead, so a line is lost when no slot was free as its target
//! was set up, even if one came free while it was written. With nobody reading, [`LINES`]
//! lines are queued and the rest lost, as in the QEMU firmware's model. Row `r` is always in
//! target `r % 2`: an interrupt served so late that the next line finished too shows as the
//! other target finishing, and the rest of the frame is lost rather than mislabelled.
//! Bookkeeping only: the board writes the registers.

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
    height: usize,
    running: bool,
}

impl DoubleBuffer {
    /// Frames of `height` lines; stopped.
    pub const fn new(height: usize) -> Self {
        Self {
            targets: [None, None],
            row: 0,
            height,
            running: false,
        }
    }

    /// A frame starts: a slot for each target (target 0 takes row 0), from a freshly reset
    /// `queue`.
    pub fn start(&mut self, queue: &mut LineQueue) -> [Option<usize>; 2] {
        self.targets = [queue.take_free(), queue.take_free()];
        (self.row, self.running) = (0, true);
        self.targets
    }

    /// Target `done` (0 or 1) finished a line: it is queued (or lost, from the discard line);
    /// the target is refilled for the line after the one now being written. The other target
    /// than the row's (an interrupt missed) loses the rest of the frame.
    pub fn line_done(&mut self, queue: &mut LineQueue, done: usize) -> Refill {
        if !self.running {
            return Refill::FrameDone;
        }
        if done != self.row % 2 {
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
        if self.row >= self.height {
            return Refill::FrameDone;
        }
        // The other target is writing row + 1; this one gets row + 2, if the frame has it.
        let next = if row + 2 < self.height { queue.take_free() } else { None };
        *target = next;
        Refill::Target(next)
    }

    /// The transfer failed or the camera overran: the line in flight and the rest of the frame
    /// are lost; the frame stops.
    pub fn lose_rest(&mut self, queue: &mut LineQueue) {
        if self.running {
            for _ in self.row..self.height {
                queue.lose();
            }
        }
        self.stop(queue);
    }

    /// The DMA has stopped: the targets' slots go back, and a running frame ends there (short
    /// of its height if lines are missing).
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

    /// Lines finished this frame (queued or lost).
    pub fn lines_done(&self) -> usize {
        self.row
    }
}
