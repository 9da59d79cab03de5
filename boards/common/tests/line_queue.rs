//! Camera rows through the line queue (`bino_board::line_queue`) with a fake camera as the
//! producer, interleaved with the pipeline's requests as an interrupt would be, both taking free
//! slots line by line and through a double-buffered DMA's two targets
//! (`bino_board::double_buffer`, the H743's): rows in order and as written, rows lost when the
//! camera runs further ahead than the line buffers hold, a frame that ends early, a transfer
//! error, a camera that stalls (a fake millisecond clock), a clean frame after each error, and the
//! STM32H743's whole 160x120 test frame through the fast preset giving the same summary and report
//! as the same frame in memory.

mod common;

use bino_board::double_buffer::{DoubleBuffer, Refill};
use bino_board::line_queue::{line_bytes, LinePort, LineQueue, QueueStats, QueuedRows, LINES};
use bino_board::options::STM32H7;
use bino_board::run::Preset;
use bino_board::side_by_side::SideBySide;
use bino_board::summary::{NoClock, Summary};
use bino_core::pipeline::{Report, RowSource};
use bino_core::Error;
use common::{side_by_side, test_frame};

/// A DMA in double-buffer mode: the targets' slots, and the one it writes now.
struct FakeDma {
    buffer: DoubleBuffer,
    targets: [Option<usize>; 2],
    current: usize,
    /// The line whose transfer fails, if any.
    error_at: Option<usize>,
    /// The line whose transfer-complete interrupt is missed (served after the next one), if any.
    missed_at: Option<usize>,
}

/// A camera that exposes the rows of a side-by-side frame into free line buffers: a burst of
/// rows at its start and one at each wait of the consumer (as interrupts land meanwhile).
struct FakeCamera {
    queue: LineQueue,
    /// Through a double-buffered DMA (else each line takes a free slot as it comes).
    dma: Option<FakeDma>,
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
            dma: None,
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

    /// The same camera behind a double-buffered DMA expecting frames of `height` lines.
    fn through_dma(mut self, height: usize) -> Self {
        self.dma = Some(FakeDma {
            buffer: DoubleBuffer::new(height),
            targets: [None, None],
            current: 0,
            error_at: None,
            missed_at: None,
        });
        self
    }

    /// One row interval: the next row into a free slot, or lost.
    fn expose(&mut self) {
        if !self.running || self.next >= self.rows {
            return;
        }
        if self.dma.is_some() {
            return self.expose_by_dma();
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

    /// One row interval behind the DMA: the line lands in the current target (the discard
    /// line: dropped), the DMA turns to the other, the finished target is refilled.
    fn expose_by_dma(&mut self) {
        let (row, line) = (self.next, line_bytes(self.width));
        self.next += 1;
        let Some(dma) = self.dma.as_mut() else { return };
        if dma.error_at == Some(row) {
            dma.buffer.lose_rest(&mut self.queue);
            self.running = false;
            return;
        }
        let done = dma.current;
        if let Some(slot) = dma.targets[done] {
            let src = &self.frame[row * line..(row + 1) * line];
            self.lines[slot * line..(slot + 1) * line].copy_from_slice(src);
        }
        dma.current ^= 1;
        if dma.missed_at == Some(row) {
            return;
        }
        match dma.buffer.line_done(&mut self.queue, done) {
            Refill::Target(slot) => dma.targets[done] = slot,
            Refill::FrameDone => {
                dma.buffer.stop(&mut self.queue);
                self.running = false;
            }
        }
        if self.next == self.rows && self.running {
            // The camera's frame ends here, short of the DMA's height: its frame-end interrupt.
            self.running = false;
            if self.ends {
                dma.buffer.stop(&mut self.queue);
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
        if let Some(dma) = self.dma.as_mut() {
            dma.targets = dma.buffer.start(&mut self.queue);
            dma.current = 0;
        }
        self.burst(self.start_burst);
    }

    fn stop(&mut self) {
        self.running = false;
        if let Some(dma) = self.dma.as_mut() {
            dma.buffer.stop(&mut self.queue);
        }
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

/// The camera sending `frame` both ways: slot by slot as lines come, and through a
/// double-buffered DMA expecting `height` lines; with the most lines a paced camera queues (the
/// DMA's two targets hold two slots).
fn both_ways(frame: &[u8], width: usize, height: usize) -> [(FakeCamera, usize); 2] {
    [
        (FakeCamera::new(frame.to_vec(), width), LINES),
        (FakeCamera::new(frame.to_vec(), width).through_dma(height), LINES - 2),
    ]
}

#[test]
fn rows_come_out_in_order_as_the_camera_wrote_them() {
    let (width, height) = (12, 40);
    let frame = numbered_frame(width, height);
    for (mut camera, most) in both_ways(&frame, width, height) {
        camera.bursts = vec![1, 3, 0, 8, 2, 5];
        let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
        assert_eq!(take(&mut rows, height), expected(&frame, width, 0..height));
        let stats = rows.stats();
        assert_eq!(
            stats,
            QueueStats {
                queued: height,
                lost: 0,
                high_water: most,
                ended: true
            }
        );
        // Past the frame's height: the end, not a wait.
        assert_eq!(next_err(&mut rows), Error::EndOfRows { row: height, height });
    }
}

#[test]
fn a_camera_further_ahead_than_the_line_buffers_loses_exactly_the_rows_beyond_them() {
    // 11 rows with nobody reading: 8 queued, 3 lost, then the frame ends.
    let (width, height) = (8, 11);
    let frame = numbered_frame(width, height);
    for (mut camera, _) in both_ways(&frame, width, height) {
        (camera.start_burst, camera.paced, camera.bursts) = (11, false, vec![0]);
        let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
        assert_eq!(take(&mut rows, LINES), expected(&frame, width, 0..LINES));
        assert_eq!(next_err(&mut rows), Error::RowsLost { row: 8, lost: 3 });
        assert_eq!(rows.stats().high_water, LINES);
    }

    // The camera goes on after the loss: the first later row is the error, not a gap. Slot by
    // slot rows 8 and 9 are lost and row 10 finds a slot the pipeline freed; behind the DMA
    // rows 10 and 11 are lost too, their targets set up while no slot was free.
    let (width, height) = (8, 20);
    let frame = numbered_frame(width, height);
    for ((mut camera, _), lost) in both_ways(&frame, width, height).into_iter().zip([2, 4]) {
        (camera.start_burst, camera.paced, camera.bursts) = (10, false, vec![1]);
        let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
        assert_eq!(take(&mut rows, LINES), expected(&frame, width, 0..LINES));
        assert_eq!(next_err(&mut rows), Error::RowsLost { row: 8, lost });
    }
}

#[test]
fn a_frame_that_ends_early_is_the_end_of_rows() {
    let (width, height) = (8, 12);
    let frame = numbered_frame(width, 5);
    for (mut camera, _) in both_ways(&frame, width, height) {
        camera.bursts = vec![2];
        let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
        assert_eq!(take(&mut rows, 5), expected(&frame, width, 0..5));
        assert_eq!(next_err(&mut rows), Error::EndOfRows { row: 5, height: 5 });
    }
}

#[test]
fn a_failed_transfer_or_a_missed_interrupt_loses_the_rest_of_the_frame() {
    let (width, height) = (8, 12);
    let frame = numbered_frame(width, height);
    let mut camera = FakeCamera::new(frame.clone(), width).through_dma(height);
    camera.bursts = vec![3];
    if let Some(dma) = camera.dma.as_mut() {
        dma.error_at = Some(4);
    }
    let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
    assert_eq!(take(&mut rows, 4), expected(&frame, width, 0..4));
    assert_eq!(next_err(&mut rows), Error::RowsLost { row: 4, lost: 8 });
    // Every slot came back, the DMA's two included.
    assert_eq!(rows.port_mut().queue.free_slots(), LINES);

    // An interrupt missed at row 5: the next one sees row 6's target finish; rows 5 to 11 are
    // lost, never row 6 handed over as row 5.
    let mut camera = FakeCamera::new(frame.clone(), width).through_dma(height);
    camera.bursts = vec![1];
    if let Some(dma) = camera.dma.as_mut() {
        dma.missed_at = Some(5);
    }
    let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
    assert_eq!(take(&mut rows, 5), expected(&frame, width, 0..5));
    assert_eq!(next_err(&mut rows), Error::RowsLost { row: 5, lost: 7 });
    assert_eq!(rows.port_mut().queue.free_slots(), LINES);
}

#[test]
fn a_camera_that_stalls_is_an_error_after_the_timeout() {
    // Silent from the start: every wait moves the clock 10 ms; the 10th reaches the timeout.
    let (width, height) = (8, 12);
    let frame = numbered_frame(width, height);
    for (mut camera, _) in both_ways(&frame, width, height) {
        (camera.bursts, camera.ms_per_wait) = (vec![0], 10);
        let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
        assert_eq!(next_err(&mut rows), Error::RowsStalled { row: 0, waited_ms: 100 });
        assert_eq!(rows.port_mut().waits, 10);
    }

    // Three rows, then silence without the frame's end; the clock wraps meanwhile.
    for (mut camera, _) in both_ways(&frame, width, height) {
        (camera.rows, camera.ends) = (3, false);
        (camera.ms_per_wait, camera.clock_ms) = (30, u32::MAX - 40);
        let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
        assert_eq!(take(&mut rows, 3), expected(&frame, width, 0..3));
        assert_eq!(next_err(&mut rows), Error::RowsStalled { row: 3, waited_ms: 120 });
    }
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
    for (camera, _) in both_ways(&frame, width, height) {
        frames_after_errors(camera, &frame, width, height);
    }
}

/// Rows lost, then frames that stall, end early and run whole, each after a rewind.
fn frames_after_errors(mut camera: FakeCamera, frame: &[u8], width: usize, height: usize) {
    (camera.start_burst, camera.paced, camera.bursts) = (12, false, vec![0]);
    let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
    assert_eq!(take(&mut rows, LINES), expected(frame, width, 0..LINES));
    // Rows lost (reported once the camera falls silent), the producer left running: the next
    // frame resets it all.
    assert_eq!(next_err(&mut rows), Error::RowsLost { row: 8, lost: 4 });
    for (start_burst, rows_sent, ends) in [(0, 5, false), (0, 7, true), (0, height, true)] {
        rows.rewind();
        assert_eq!(rows.stats(), QueueStats::default());
        let camera = rows.port_mut();
        (camera.start_burst, camera.paced, camera.bursts) = (start_burst, true, vec![3, 1]);
        (camera.rows, camera.ends) = (rows_sent, ends);
        assert_eq!(take(&mut rows, rows_sent), expected(frame, width, 0..rows_sent));
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

    for (mut camera, most) in both_ways(&whole, frame.width, frame.height) {
        camera.bursts = vec![1, 4, 0, 8, 2, 7, 3];
        let rows = QueuedRows::new(camera, frame.width, frame.height, STALL_MS);
        twice_as_in_memory(rows, &preset, &mut arena, (&want, &in_memory), most);
    }
}

/// Two frames from `rows`, the second after a rewind, in the same arena: each gives `want`'s
/// report and `in_memory`'s summary, losing nothing, `most` lines queued at once.
fn twice_as_in_memory(
    mut rows: QueuedRows<FakeCamera>,
    preset: &Preset<'_>,
    arena: &mut [u8],
    (want, in_memory): (&Report, &Summary<NoClock>),
    most: usize,
) {
    let frame = STM32H7;
    for _ in 0..2 {
        rows.rewind();
        let mut queued = Summary::new(frame.width, NoClock).unwrap();
        let report = preset.run(&mut rows, arena, &mut queued).unwrap();
        assert_eq!(&report, want);
        assert_eq!(queued.refined_rows(), frame.height);
        assert_eq!(queued.refined_crc(), in_memory.refined_crc());
        assert_eq!(queued.sectors(), in_memory.sectors());
        let stats = rows.stats();
        assert_eq!((stats.queued, stats.lost, stats.high_water), (frame.height, 0, most));
        assert_eq!(rows.delivered(), frame.height);
    }
}
