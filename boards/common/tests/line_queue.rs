//! Camera rows through the line queue (`bino_board::line_queue`) with a fake camera as the
//! producer, interleaved with the pipeline's requests as an interrupt would be: rows in order
//! and as written, rows lost when the camera runs further ahead than the line buffers hold, a
//! frame that ends early, a camera that stalls (a fake millisecond clock), a clean frame after
//! each error, and the STM32H743's whole 160x120 test frame through the fast preset giving the
//! same summary and report as the same frame in memory.

mod common;

use bino_board::line_queue::{line_bytes, LinePort, LineQueue, QueueStats, QueuedRows, LINES};
use bino_board::options::STM32H7;
use bino_board::run::Preset;
use bino_board::side_by_side::SideBySide;
use bino_board::summary::{NoClock, Summary};
use bino_core::pipeline::RowSource;
use bino_core::Error;
use common::{side_by_side, test_frame};

/// A camera that exposes the rows of a side-by-side frame into free line buffers: a burst of
/// rows at its start and one at each wait of the consumer (as interrupts land meanwhile).
struct FakeCamera {
    queue: LineQueue,
    /// The line buffers: `LINES` slots of `line_bytes(width)`.
    lines: Vec<u8>,
    frame: Vec<u8>,
    width: usize,
    /// Rows it sends; after them it says the frame ended if `ends`, else falls silent.
    rows: usize,
    ends: bool,
    /// Rows exposed at `start`.
    start_burst: usize,
    /// Rows exposed at each wait, in turn.
    bursts: Vec<usize>,
    /// Exposes only as many rows as slots are free (a sensor paced to the pipeline).
    paced: bool,
    next: usize,
    running: bool,
    waits: usize,
    clock_ms: u32,
    ms_per_wait: u32,
}

impl FakeCamera {
    /// A camera sending the whole `frame` (`2 x width` bytes a line), a row at each wait, then
    /// the frame's end.
    fn new(frame: Vec<u8>, width: usize) -> Self {
        let rows = frame.len() / line_bytes(width);
        Self {
            queue: LineQueue::new(),
            lines: vec![0; LINES * line_bytes(width)],
            frame,
            width,
            rows,
            ends: true,
            start_burst: 0,
            bursts: vec![1],
            paced: true,
            next: 0,
            running: false,
            waits: 0,
            clock_ms: 0,
            ms_per_wait: 1,
        }
    }

    /// One row interval: the next row into a free slot, or lost.
    fn expose(&mut self) {
        if !self.running || self.next >= self.rows {
            return;
        }
        let (row, line) = (self.next, line_bytes(self.width));
        self.next += 1;
        match self.queue.take_free() {
            Some(slot) => {
                let src = &self.frame[row * line..(row + 1) * line];
                self.lines[slot * line..(slot + 1) * line].copy_from_slice(src);
                self.queue.push(row, slot);
            }
            None => self.queue.lose(),
        }
        if self.next == self.rows {
            self.running = false;
            if self.ends {
                self.queue.end();
            }
        }
    }

    fn burst(&mut self, rows: usize) {
        for _ in 0..rows {
            if self.paced && self.queue.free_slots() == 0 {
                return;
            }
            self.expose();
        }
    }
}

impl LinePort for FakeCamera {
    fn with_queue<R>(&mut self, f: impl FnOnce(&mut LineQueue) -> R) -> R {
        f(&mut self.queue)
    }

    fn read_line(&mut self, slot: usize, left: &mut [u8], right: &mut [u8]) -> Result<(), Error> {
        let line = &self.lines[slot * line_bytes(self.width)..(slot + 1) * line_bytes(self.width)];
        let (l, r) = line.split_at(self.width);
        left.copy_from_slice(l);
        right.copy_from_slice(r);
        Ok(())
    }

    fn start(&mut self) {
        (self.next, self.running) = (0, true);
        self.burst(self.start_burst);
    }

    fn stop(&mut self) {
        self.running = false;
    }

    fn wait(&mut self) {
        let rows = self.bursts[self.waits % self.bursts.len()];
        self.waits += 1;
        self.clock_ms = self.clock_ms.wrapping_add(self.ms_per_wait);
        self.burst(rows);
    }

    fn now_ms(&mut self) -> u32 {
        self.clock_ms
    }
}

/// A `rows x width` side-by-side frame whose every byte names its row and place.
fn numbered_frame(width: usize, rows: usize) -> Vec<u8> {
    (0..rows * line_bytes(width)).map(|i| (i * 7 + i / 13) as u8).collect()
}

const STALL_MS: u32 = 100;

/// The next `n` rows of `source`, as (left, right) pairs.
fn take(source: &mut impl RowSource, n: usize) -> Vec<(Vec<u8>, Vec<u8>)> {
    let w = source.width();
    (0..n)
        .map(|_| {
            let (mut l, mut r) = (vec![0; w], vec![0; w]);
            source.next_row(&mut l, &mut r).unwrap();
            (l, r)
        })
        .collect()
}

/// Rows `from..to` of a side-by-side `frame`, split as [`take`] returns them.
fn expected(frame: &[u8], width: usize, rows: std::ops::Range<usize>) -> Vec<(Vec<u8>, Vec<u8>)> {
    let line = line_bytes(width);
    rows.map(|r| {
        let (l, rt) = frame[r * line..(r + 1) * line].split_at(width);
        (l.to_vec(), rt.to_vec())
    })
    .collect()
}

fn next_err(source: &mut impl RowSource) -> Error {
    let w = source.width();
    let (mut l, mut r) = (vec![0; w], vec![0; w]);
    source.next_row(&mut l, &mut r).expect_err("an error")
}

#[test]
fn rows_come_out_in_order_as_the_camera_wrote_them() {
    let (width, height) = (12, 40);
    let frame = numbered_frame(width, height);
    let mut camera = FakeCamera::new(frame.clone(), width);
    camera.bursts = vec![1, 3, 0, 8, 2, 5];
    let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
    assert_eq!(take(&mut rows, height), expected(&frame, width, 0..height));
    let stats = rows.stats();
    assert_eq!(
        stats,
        QueueStats {
            queued: height,
            lost: 0,
            high_water: LINES,
            ended: true
        }
    );
    // Past the frame's height: the end, not a wait.
    assert_eq!(next_err(&mut rows), Error::EndOfRows { row: height, height });
}

#[test]
fn a_camera_further_ahead_than_the_line_buffers_loses_exactly_the_rows_beyond_them() {
    // 11 rows with nobody reading: 8 queued, 3 lost, then the frame ends.
    let (width, height) = (8, 11);
    let frame = numbered_frame(width, height);
    let mut camera = FakeCamera::new(frame.clone(), width);
    (camera.start_burst, camera.paced, camera.bursts) = (11, false, vec![0]);
    let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
    assert_eq!(take(&mut rows, LINES), expected(&frame, width, 0..LINES));
    assert_eq!(next_err(&mut rows), Error::RowsLost { row: 8, lost: 3 });
    assert_eq!(rows.stats().high_water, LINES);

    // The camera goes on after the loss: the first later row is the error, not a gap.
    let (width, height) = (8, 20);
    let frame = numbered_frame(width, height);
    let mut camera = FakeCamera::new(frame.clone(), width);
    (camera.start_burst, camera.paced, camera.bursts) = (10, false, vec![1]);
    let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
    assert_eq!(take(&mut rows, LINES), expected(&frame, width, 0..LINES));
    assert_eq!(next_err(&mut rows), Error::RowsLost { row: 8, lost: 2 });
}

#[test]
fn a_frame_that_ends_early_is_the_end_of_rows() {
    let (width, height) = (8, 12);
    let frame = numbered_frame(width, 5);
    let mut camera = FakeCamera::new(frame.clone(), width);
    camera.bursts = vec![2];
    let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
    assert_eq!(take(&mut rows, 5), expected(&frame, width, 0..5));
    assert_eq!(next_err(&mut rows), Error::EndOfRows { row: 5, height: 5 });
}

#[test]
fn a_camera_that_stalls_is_an_error_after_the_timeout() {
    // Silent from the start: every wait moves the clock 10 ms; the 10th reaches the timeout.
    let (width, height) = (8, 12);
    let mut camera = FakeCamera::new(numbered_frame(width, height), width);
    (camera.bursts, camera.ms_per_wait) = (vec![0], 10);
    let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
    assert_eq!(next_err(&mut rows), Error::RowsStalled { row: 0, waited_ms: 100 });
    assert_eq!(rows.port_mut().waits, 10);

    // Three rows, then silence without the frame's end; the clock wraps meanwhile.
    let frame = numbered_frame(width, height);
    let mut camera = FakeCamera::new(frame.clone(), width);
    (camera.rows, camera.ends, camera.ms_per_wait, camera.clock_ms) = (3, false, 30, u32::MAX - 40);
    let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
    assert_eq!(take(&mut rows, 3), expected(&frame, width, 0..3));
    assert_eq!(next_err(&mut rows), Error::RowsStalled { row: 3, waited_ms: 120 });
    // The error is one line that says what happened.
    let text = Error::RowsStalled { row: 3, waited_ms: 120 }.to_string();
    assert!(
        text.contains("no row 3 within 120 ms") && !text.contains('\n'),
        "{text}"
    );
}

#[test]
fn after_each_error_the_next_frame_runs_clean() {
    let (width, height) = (8, 16);
    let frame = numbered_frame(width, height);
    let mut camera = FakeCamera::new(frame.clone(), width);
    (camera.start_burst, camera.paced, camera.bursts) = (12, false, vec![0]);
    let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
    assert_eq!(take(&mut rows, LINES), expected(&frame, width, 0..LINES));
    // Rows lost (reported once the camera falls silent), the producer left running: the next
    // frame resets it all.
    assert_eq!(next_err(&mut rows), Error::RowsLost { row: 8, lost: 4 });
    for (start_burst, rows_sent, ends) in [(0, 5, false), (0, 7, true), (0, height, true)] {
        rows.rewind();
        assert_eq!(rows.stats(), QueueStats::default());
        let camera = rows.port_mut();
        (camera.start_burst, camera.paced, camera.bursts) = (start_burst, true, vec![3, 1]);
        (camera.rows, camera.ends) = (rows_sent, ends);
        assert_eq!(take(&mut rows, rows_sent), expected(&frame, width, 0..rows_sent));
        let stats = rows.stats();
        assert_eq!((stats.queued, stats.lost), (rows_sent, 0));
        if rows_sent < height {
            // The stall, then the early end: each still a clean frame's error.
            let want = match ends {
                false => Error::RowsStalled {
                    row: rows_sent,
                    waited_ms: STALL_MS,
                },
                true => Error::EndOfRows {
                    row: rows_sent,
                    height: rows_sent,
                },
            };
            assert_eq!(next_err(&mut rows), want);
        }
    }
    // Every slot came back: a frame that fills all of them again loses nothing.
    assert_eq!(rows.port_mut().queue.free_slots(), LINES);
}

#[test]
fn the_h743_frame_through_the_queue_gives_the_summary_of_the_frame_in_memory() {
    let frame = STM32H7;
    let (left, right) = test_frame(frame);
    let whole = side_by_side(&left, &right, frame.width);
    let preset = Preset::Fast;
    let mut arena = vec![0u8; frame.fast_arena_bytes()];

    let mut in_memory = Summary::new(frame.width, NoClock).unwrap();
    let mut source = SideBySide::new(&whole, frame.width, frame.height).unwrap();
    let want = preset.run(&mut source, &mut arena, &mut in_memory).unwrap();

    let mut camera = FakeCamera::new(whole.clone(), frame.width);
    camera.bursts = vec![1, 4, 0, 8, 2, 7, 3];
    let mut rows = QueuedRows::new(camera, frame.width, frame.height, STALL_MS);
    // Twice: the second frame after a rewind, in the same arena.
    for _ in 0..2 {
        rows.rewind();
        let mut queued = Summary::new(frame.width, NoClock).unwrap();
        let report = preset.run(&mut rows, &mut arena, &mut queued).unwrap();
        assert_eq!(report, want);
        assert_eq!(queued.refined_rows(), frame.height);
        assert_eq!(queued.refined_crc(), in_memory.refined_crc());
        assert_eq!(queued.sectors(), in_memory.sectors());
        let stats = rows.stats();
        assert_eq!((stats.queued, stats.lost, stats.high_water), (frame.height, 0, LINES));
        assert_eq!(rows.delivered(), frame.height);
    }
}
