//! Camera rows through the line queue (`bino_board::line_queue`) with a fake camera as the
//! producer, interleaved with the pipeline's requests as an interrupt would be, both taking free
//! slots line by line and through a double-buffered DMA's two targets
//! (`bino_board::double_buffer`, the H743's): rows in order and as written, rows lost when the
//! camera runs further ahead than the line buffers hold, a frame that ends early, a transfer
//! error, a camera that stalls (a fake millisecond clock), a clean frame after each error, and the
//! STM32H743's whole 160x120 test frame through the fast preset giving the same summary and report
//! as the same frame in memory. A free-running sensor (a frame every so many line times, read
//! in bands with long pauses as the learned preset reads) behind a port that re-arms mid-frame:
//! every row once, in order, each from the sensor frame its capture took, stitched from as many
//! sensor frames as expected; the same without the re-arm: rows lost; a re-arm the sensor never
//! answers: stalled; and the H743's frame from such a sensor, still, giving both presets the
//! summary and report of the frame in memory. And 400 randomized cameras and consumers: every
//! request returns, rows in order or one clear error naming the row, the next frame clean.

mod common;

use bino_board::double_buffer::{DoubleBuffer, Refill};
use bino_board::line_queue::{line_bytes, LinePort, LineQueue, QueueStats, QueuedRows, LINES};
use bino_board::options::STM32H7;
use bino_board::run::{load, Preset};
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

/// A sensor that streams frames whether or not a capture is armed: line `step % period` of frame
/// `step / period` at each step (the rows, then blanking lines).
struct Sensor {
    period: usize,
    step: usize,
    /// Frames it sends before falling silent, if it does.
    frames: Option<usize>,
    /// Each frame's rows differ by the frame's number (a moving scene), else all alike.
    moving: bool,
    /// A capture waits for the next frame's start.
    armed: bool,
}

/// A camera that exposes the rows of a side-by-side frame into free line buffers: a burst of
/// rows at its start and one at each wait of the consumer (as interrupts land meanwhile); or,
/// with a [`Sensor`], a step of the sensor at each.
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
    /// The port re-arms a capture mid-frame ([`LinePort::restart_from`]).
    restarts: bool,
    /// A broken re-arm: the capture stops again before its first row.
    rearm_stops: bool,
    /// A free-running sensor behind the capture (else the frame starts as the capture does).
    sensor: Option<Sensor>,
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
            restarts: false,
            rearm_stops: false,
            sensor: None,
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

    /// A free-running sensor streaming `frames`' rows (the camera's), a frame every `period`
    /// steps, behind a port that re-arms mid-frame; paced by nothing, a step at each wait.
    fn free_running(mut self, period: usize, moving: bool) -> Self {
        self.sensor = Some(Sensor {
            period,
            step: 0,
            frames: None,
            moving,
            armed: false,
        });
        (self.restarts, self.paced, self.bursts) = (true, false, vec![1]);
        self
    }

    /// The capture is armed at row `row`: at once, or at the sensor's next frame start.
    fn arm_at(&mut self, row: usize) {
        self.next = row;
        match self.sensor.as_mut() {
            Some(sensor) => (sensor.armed, self.running) = (true, false),
            None => self.running = true,
        }
        if let Some(dma) = self.dma.as_mut() {
            dma.targets = dma.buffer.start(&mut self.queue, row);
            dma.current = 0;
        }
    }

    /// The sensor's step: whether its line is the capture's next row. A frame's start begins an
    /// armed capture; lines above the capture's window and the blanking carry nothing.
    fn sensor_step(&mut self) -> bool {
        let Some(sensor) = self.sensor.as_mut() else {
            return true;
        };
        let (frame, line) = (sensor.step / sensor.period, sensor.step % sensor.period);
        sensor.step += 1;
        if sensor.frames.is_some_and(|n| frame >= n) {
            return false;
        }
        if line == 0 && sensor.armed {
            (sensor.armed, self.running) = (false, true);
        }
        line == self.next
    }

    /// What the sensor's current frame shows on row `row`: the frame's row, each byte plus the
    /// sensor frame's number if the scene moves.
    fn write_row(&mut self, row: usize, slot: usize) {
        let line = line_bytes(self.width);
        let shift = match &self.sensor {
            Some(s) if s.moving => ((s.step - 1) / s.period) as u8,
            _ => 0,
        };
        let src = &self.frame[row * line..(row + 1) * line];
        for (dst, &b) in self.lines[slot * line..(slot + 1) * line].iter_mut().zip(src) {
            *dst = b.wrapping_add(shift);
        }
    }

    /// One row interval: the next row into a free slot, or lost, or (resuming) the capture
    /// stops before it.
    fn expose(&mut self) {
        if !self.sensor_step() || !self.running || self.next >= self.rows {
            return;
        }
        if self.dma.is_some() {
            return self.expose_by_dma();
        }
        let row = self.next;
        self.next += 1;
        match self.queue.take_free() {
            Some(slot) => {
                self.write_row(row, slot);
                self.queue.push(row, slot);
            }
            None if self.queue.resumes() => {
                self.queue.stop_at(row);
                self.running = false;
                return;
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
        let row = self.next;
        self.next += 1;
        let Some(dma) = self.dma.as_mut() else { return };
        if dma.error_at == Some(row) {
            dma.buffer.lose_rest(&mut self.queue);
            self.running = false;
            return;
        }
        let done = dma.current;
        let target = dma.targets[done];
        dma.current ^= 1;
        if let Some(slot) = target {
            self.write_row(row, slot);
        }
        let Some(dma) = self.dma.as_mut() else { return };
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
        self.arm_at(0);
        self.burst(self.start_burst);
    }

    fn stop(&mut self) {
        self.running = false;
        if let Some(dma) = self.dma.as_mut() {
            dma.buffer.stop(&mut self.queue);
        }
    }

    fn restarts(&self) -> bool {
        self.restarts
    }

    fn restart_from(&mut self, row: usize) {
        assert!(self.restarts, "re-armed a port that cannot");
        self.arm_at(row);
        if self.rearm_stops {
            self.queue.stop_at(row);
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
                ended: true,
                captures: 1,
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

/// Reads `height` rows in bands of `band`, the sensor running `pause` steps after each band (the
/// pipeline working on it): every row, and the sensor frame each came from (each row must be
/// that frame's row exactly).
fn read_in_bands(
    rows: &mut QueuedRows<FakeCamera>,
    frame: &[u8],
    (band, pause): (usize, usize),
) -> Result<Vec<usize>, Error> {
    let (width, height) = (rows.width(), rows.height());
    let mut from = Vec::new();
    let (mut l, mut r) = (vec![0; width], vec![0; width]);
    for row in 0..height {
        rows.next_row(&mut l, &mut r)?;
        // A moving scene adds the sensor frame's number to every byte of its rows.
        let line = &frame[row * line_bytes(width)..(row + 1) * line_bytes(width)];
        let shift = l[0].wrapping_sub(line[0]);
        let want: Vec<u8> = line.iter().map(|b| b.wrapping_add(shift)).collect();
        assert_eq!([l.as_slice(), r.as_slice()].concat(), want, "row {row}");
        from.push(usize::from(shift));
        if (row + 1).is_multiple_of(band) {
            rows.port_mut().burst(pause);
        }
    }
    Ok(from)
}

/// Both ways, behind a free-running sensor with a frame every `period` steps, re-arming.
fn free_running(frame: &[u8], width: usize, height: usize, period: usize) -> [FakeCamera; 2] {
    both_ways(frame, width, height).map(|(camera, _)| camera.free_running(period, true))
}

#[test]
fn a_free_running_sensor_resumes_where_the_line_buffers_ran_out() {
    // 40 rows and 10 blanking lines a sensor frame; bands of 16 rows, 150 steps of work after
    // each. Rows 0-15 come as the sensor sends sensor frame 0; in the pause rows 16-23 fill the
    // 8 line buffers and the capture stops before row 24. The next band drains them and asks
    // for row 24: the re-arm at step 166 waits for sensor frame 4 (step 200), which gives rows
    // 24-31 as they come; in the next pause rows 32-39 fill the buffers and end the frame.
    let (width, height, period) = (8, 40, 50);
    let frame = numbered_frame(width, height);
    for camera in free_running(&frame, width, height, period) {
        let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
        for _ in 0..2 {
            // The second frame after a rewind: clean, the sensor still running.
            rows.rewind();
            let from = read_in_bands(&mut rows, &frame, (16, 3 * period)).unwrap();
            let first = from[0];
            let mut want = vec![first; 24];
            want.extend([first + 4; 16]);
            assert_eq!(from, want);
            let stats = rows.stats();
            assert_eq!((stats.queued, stats.lost, stats.captures), (height, 0, 2));
            assert_eq!((stats.high_water, stats.ended), (LINES, true));
            assert_eq!(next_err(&mut rows), Error::EndOfRows { row: height, height });
        }
    }
}

#[test]
fn rows_come_in_order_from_later_sensor_frames_whatever_the_pauses() {
    // Bands and pauses of every size against a short and a long sensor frame: each row once,
    // in order, its sensor frame never earlier than the row before's; each capture is one
    // sensor frame, so the frames used are the captures.
    let (width, height) = (8, 40);
    let frame = numbered_frame(width, height);
    for period in [41, 120] {
        for (band, pause) in [(1, 9), (3, 40), (8, 8), (8, 9), (13, 500), (40, 0)] {
            for camera in free_running(&frame, width, height, period) {
                let mut rows = QueuedRows::new(camera, width, height, 3 * period as u32);
                let from = read_in_bands(&mut rows, &frame, (band, pause)).unwrap();
                assert!(from.windows(2).all(|w| w[0] <= w[1]), "{from:?}");
                let mut used = from.clone();
                used.dedup();
                let stats = rows.stats();
                assert_eq!((stats.queued, stats.lost), (height, 0));
                assert_eq!(stats.captures, used.len(), "band {band} pause {pause}: {from:?}");
                // A pause shorter than the line buffers fill never needs a re-arm.
                if pause < LINES - 2 || band == height {
                    assert_eq!(stats.captures, 1);
                }
            }
        }
    }
}

#[test]
fn without_the_re_arm_the_rows_beyond_the_line_buffers_are_lost() {
    // As above, but the port cannot re-arm: rows 24-39 of the only capture are lost.
    let (width, height, period) = (8, 40, 50);
    let frame = numbered_frame(width, height);
    for mut camera in free_running(&frame, width, height, period) {
        camera.restarts = false;
        let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
        let err = read_in_bands(&mut rows, &frame, (16, 3 * period)).unwrap_err();
        assert_eq!(err, Error::RowsLost { row: 24, lost: 16 });
        let stats = rows.stats();
        assert_eq!((stats.queued, stats.captures), (24, 1));
    }
}

#[test]
fn a_re_arm_the_sensor_never_answers_stalls_and_the_next_frame_is_clean() {
    let (width, height, period) = (8, 40, 50);
    let frame = numbered_frame(width, height);
    for mut camera in free_running(&frame, width, height, period) {
        // One sensor frame, then silence: the re-arm at row 24 waits for nothing.
        if let Some(sensor) = camera.sensor.as_mut() {
            sensor.frames = Some(1);
        }
        let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
        let err = read_in_bands(&mut rows, &frame, (16, 3 * period)).unwrap_err();
        assert_eq!(
            err,
            Error::RowsStalled {
                row: 24,
                waited_ms: STALL_MS
            }
        );
        assert_eq!(rows.stats().captures, 2);
        // The sensor back: a clean frame, every slot free, stitched again.
        rows.rewind();
        assert_eq!(rows.stats(), QueueStats::default());
        assert_eq!(rows.port_mut().queue.free_slots(), LINES);
        if let Some(sensor) = rows.port_mut().sensor.as_mut() {
            sensor.frames = None;
        }
        read_in_bands(&mut rows, &frame, (16, 3 * period)).unwrap();
        let stats = rows.stats();
        assert_eq!((stats.queued, stats.lost, stats.captures), (height, 0, 2));
    }
}

#[test]
fn a_re_arm_that_stops_again_before_its_row_is_an_error_not_a_loop() {
    let (width, height, period) = (8, 40, 50);
    let frame = numbered_frame(width, height);
    for mut camera in free_running(&frame, width, height, period) {
        camera.rearm_stops = true;
        let mut rows = QueuedRows::new(camera, width, height, STALL_MS);
        let err = read_in_bands(&mut rows, &frame, (16, 3 * period)).unwrap_err();
        assert_eq!(err, Error::RowsLost { row: 24, lost: 0 });
        assert_eq!(rows.stats().captures, 2);
    }
}

#[test]
fn a_re_arm_low_in_the_frame_waits_up_to_two_sensor_frames() {
    // 40 rows and a blanking line a sensor frame; bands of 30 rows, 53 steps of work after the
    // first: rows 30-37 fill the line buffers, the capture stops before row 38, and the pause
    // ends at step 83, line 1 of sensor frame 2. The re-arm there misses that frame: row 38
    // comes from frame 3, at step 161, 78 steps (ms) later, most of two frame periods. A stall
    // limit of one period calls that a stall; the boards' limit covers two periods and more.
    let (width, height, period) = (8, 40, 41);
    let frame = numbered_frame(width, height);
    for (limit, stalls) in [(period, true), (2 * period + 10, false)] {
        for camera in free_running(&frame, width, height, period) {
            let mut rows = QueuedRows::new(camera, width, height, limit as u32);
            let result = read_in_bands(&mut rows, &frame, (30, 53));
            if stalls {
                let waited_ms = limit as u32;
                assert_eq!(result, Err(Error::RowsStalled { row: 38, waited_ms }));
            } else {
                let mut want = vec![0; 38];
                want.extend([3; 2]);
                assert_eq!(result, Ok(want));
                assert_eq!(rows.stats().captures, 2);
            }
        }
    }
}

/// A row source that works `pause` sensor steps after every `band` rows, as the learned preset
/// encodes a band between reading its rows.
struct Slow {
    rows: QueuedRows<FakeCamera>,
    band: usize,
    pause: usize,
    read: usize,
}

impl RowSource for Slow {
    fn width(&self) -> usize {
        self.rows.width()
    }

    fn height(&self) -> usize {
        self.rows.height()
    }

    fn next_row(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), Error> {
        self.rows.next_row(left, right)?;
        self.read += 1;
        if self.read.is_multiple_of(self.band) {
            self.rows.port_mut().burst(self.pause);
        }
        Ok(())
    }
}

#[test]
fn the_h743_frame_from_a_free_running_sensor_read_slowly_gives_both_presets_the_frame_in_memory() {
    // A still scene from a free-running sensor, read by each preset with a long pause after
    // every 16 rows (the learned preset as it encodes its bands): stitched from several sensor
    // frames, the frame's summary and report.
    let frame = STM32H7;
    let (left, right) = test_frame(frame);
    let whole = side_by_side(&left, &right, frame.width);
    let blob = common::read("weights/bino_int8_native.bin");
    let learned = Preset::Learned(load(&blob).unwrap());
    for preset in [Preset::Fast, learned] {
        let mut arena = vec![0u8; preset.arena_bytes(frame)];
        let mut in_memory = Summary::new(frame.width, NoClock).unwrap();
        let mut source = SideBySide::new(&whole, frame.width, frame.height).unwrap();
        let want = preset.run(&mut source, &mut arena, &mut in_memory).unwrap();

        let period = frame.height + 20;
        for (camera, _) in both_ways(&whole, frame.width, frame.height) {
            let camera = camera.free_running(period, false);
            let rows = QueuedRows::new(camera, frame.width, frame.height, 3 * period as u32);
            let (band, pause) = (16, 2 * period);
            let mut slow = Slow {
                rows,
                band,
                pause,
                read: 0,
            };
            let mut queued = Summary::new(frame.width, NoClock).unwrap();
            let report = preset.run(&mut slow, &mut arena, &mut queued).unwrap();
            assert_eq!(report, want, "{}", preset.name());
            assert_eq!(queued.refined_crc(), in_memory.refined_crc());
            assert_eq!(queued.sectors(), in_memory.sectors());
            let stats = slow.rows.stats();
            assert_eq!((stats.queued, stats.lost), (frame.height, 0));
            // Each band after the first drains 8 rows and re-arms for the other 8.
            assert_eq!(stats.captures, frame.height / band);
        }
    }
}

/// A small deterministic generator for the randomized schedules below.
struct Lcg(u64);

impl Lcg {
    fn below(&mut self, n: usize) -> usize {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 33) as usize) % n.max(1)
    }
}

/// One randomized camera for a frame of `height` rows (each of `rows_sent` rows sent): bursts,
/// pacing, a DMA with a failed or missed transfer, a free-running sensor (still or moving), a
/// port that re-arms or not, a sensor that falls silent.
fn random_camera(rng: &mut Lcg, frame: &[u8], width: usize, height: usize) -> FakeCamera {
    let mut camera = FakeCamera::new(frame.to_vec(), width);
    if rng.below(2) == 0 {
        camera = camera.through_dma(height);
        if let Some(dma) = camera.dma.as_mut() {
            dma.error_at = (rng.below(4) == 0).then(|| rng.below(height));
            dma.missed_at = (rng.below(4) == 0).then(|| rng.below(height));
        }
    }
    if rng.below(3) == 0 {
        camera = camera.free_running(height + rng.below(60), rng.below(2) == 0);
        camera.restarts = rng.below(4) != 0;
        if let Some(sensor) = camera.sensor.as_mut() {
            sensor.frames = (rng.below(4) == 0).then(|| 1 + rng.below(4));
        }
    } else {
        camera.paced = rng.below(2) == 0;
        camera.bursts = (0..1 + rng.below(6)).map(|_| rng.below(LINES + 3)).collect();
        camera.start_burst = rng.below(LINES + 3);
    }
    if rng.below(3) == 0 {
        // A frame that ends up to three rows short.
        camera.rows = height - rng.below(4);
    }
    camera.ends = rng.below(4) != 0;
    camera.ms_per_wait = 1 + rng.below(3) as u32;
    camera
}

#[test]
fn any_schedule_gives_the_frames_rows_in_order_or_one_clear_error_and_the_next_frame_runs_clean() {
    // Randomized cameras and consumers (read in random bands with random pauses): every request
    // returns, the rows before the first error are the frame's rows in order (a moving scene
    // shifts a whole row by its sensor frame), the error names the row asked for and is one of
    // the camera path's, and after a rewind a well-behaved camera on the same port delivers a
    // whole frame.
    let (width, height) = (8, 24);
    let frame = numbered_frame(width, height);
    let line = line_bytes(width);
    let mut rng = Lcg(0x5eed);
    let (mut whole, mut failed) = (0, 0);
    for case in 0..400 {
        let camera = random_camera(&mut rng, &frame, width, height);
        let mut rows = QueuedRows::new(camera, width, height, 40 + rng.below(200) as u32);
        let (band, pause) = (1 + rng.below(height), rng.below(3 * LINES));
        let (mut l, mut r) = (vec![0; width], vec![0; width]);
        let mut delivered = 0;
        let error = loop {
            if delivered == height {
                break None;
            }
            match rows.next_row(&mut l, &mut r) {
                Ok(()) => {
                    let want = &frame[delivered * line..(delivered + 1) * line];
                    let shift = l[0].wrapping_sub(want[0]);
                    let got = [l.as_slice(), r.as_slice()].concat();
                    let want: Vec<u8> = want.iter().map(|b| b.wrapping_add(shift)).collect();
                    assert_eq!(got, want, "case {case}: row {delivered}");
                    delivered += 1;
                    if delivered % band == 0 {
                        rows.port_mut().burst(pause);
                    }
                }
                Err(e) => break Some(e),
            }
        };
        match error {
            None => whole += 1,
            Some(Error::RowsLost { row, .. } | Error::RowsStalled { row, .. }) => {
                assert_eq!(row, delivered, "case {case}");
                failed += 1;
            }
            Some(Error::EndOfRows { row, .. }) => {
                assert_eq!(row, delivered, "case {case}");
                failed += 1;
            }
            Some(e) => panic!("case {case}: unexpected {e:?}"),
        }
        // The next frame: the same port, its camera now well behaved.
        let camera = rows.port_mut();
        (camera.rows, camera.ends, camera.paced, camera.bursts) = (height, true, true, vec![1]);
        camera.sensor = None;
        if let Some(dma) = camera.dma.as_mut() {
            (dma.error_at, dma.missed_at) = (None, None);
        }
        rows.rewind();
        assert_eq!(
            take(&mut rows, height),
            expected(&frame, width, 0..height),
            "case {case}: next frame"
        );
    }
    // The schedules reach both ends: whole frames and every kind of failure.
    assert!(whole > 40 && failed > 40, "{whole} whole frames, {failed} failed");
}
