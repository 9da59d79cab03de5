//! The learned preset on a real frame: the shipped blob and the QEMU firmware's 160x120 test
//! frame through the board's code on the host, band after band, its summary checked against the
//! refined rows themselves, side by side as the DCMI captures it, again in the same arena, and
//! its refined rows' CRC-32 the one both QEMU firmwares recorded for their learned frame run.

mod common;

use bino_board::options::{ARENA_BYTES, FRAME_HEIGHT, FRAME_WIDTH, OPTIONS, REFINE};
use bino_board::run::{load, Preset};
use bino_board::side_by_side::SideBySide;
use bino_board::summary::{NoClock, Summary};
use bino_core::pipeline::{RowSource, SlicePair};
use bino_core::Error;
use common::{firmware_refined, run_side_by_side_twice, side_by_side, test_frame, Tee};

#[test]
fn the_learned_preset_summarises_the_test_frame_as_the_firmware_refines_it() {
    let blob = common::read("weights/bino_int8_native.bin");
    let (left, right) = test_frame();
    let pipeline = load(&blob).unwrap();
    let mut arena = vec![0u8; ARENA_BYTES];

    let mut tee = Tee::new();
    let mut source = SlicePair::new(&left, &right, FRAME_WIDTH, FRAME_HEIGHT).unwrap();
    let report = pipeline
        .run_refined(&mut source, &OPTIONS, &REFINE, &mut arena, &mut tee)
        .unwrap();
    // A whole frame in the arena of its const fn: several bands, none of them growing it.
    assert!(report.arena_used <= ARENA_BYTES && report.bands > 1, "{report:?}");
    let views = tee.checked_summary();
    for core in ["m55", "m7"] {
        assert_eq!(
            views.refined_crc(),
            firmware_refined(core, "frame"),
            "{core}: the board's learned preset against the QEMU firmware's frame run"
        );
    }

    // Side by side, as the DCMI captures it, through the preset the board runs, twice in the
    // same arena: a frame starts clean whatever the last one left there.
    let preset = Preset::Learned(pipeline);
    assert_eq!(preset.arena_bytes(), ARENA_BYTES);
    run_side_by_side_twice(&preset, &mut arena, (&left, &right), &views);
    println!(
        "test frame, learned: {:?} refined_crc={:08x} arena_used={}",
        views.sectors(),
        views.refined_crc(),
        report.arena_used
    );
}

/// A camera that stops sending after `rows` lines of the frame (a capture cut short).
struct Cut<S> {
    inner: S,
    rows: usize,
    sent: usize,
}

impl<S: RowSource> RowSource for Cut<S> {
    fn width(&self) -> usize {
        self.inner.width()
    }
    fn height(&self) -> usize {
        self.inner.height()
    }
    fn next_row(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), Error> {
        if self.sent == self.rows {
            return Err(Error::EndOfRows {
                row: self.sent,
                height: self.rows,
            });
        }
        self.sent += 1;
        self.inner.next_row(left, right)
    }
}

#[test]
fn a_bad_frame_is_one_error_line_and_the_next_frame_starts_clean() {
    let blob = common::read("weights/bino_int8_native.bin");
    let (left, right) = test_frame();
    let frame = side_by_side(&left, &right);
    let preset = Preset::Learned(load(&blob).unwrap());
    let mut arena = vec![0u8; ARENA_BYTES];

    // A frame of the wrong size never reaches the pipeline.
    let short = SideBySide::new(&frame[..frame.len() - 2 * FRAME_WIDTH], FRAME_WIDTH, FRAME_HEIGHT);
    let e = short.expect_err("a frame one line short");
    assert!(
        e.to_string().contains("side-by-side frame") && !e.to_string().contains('\n'),
        "{e}"
    );

    // A capture cut off in the frame's second band: an error mid-run, the arena left dirty.
    let mut summary = Summary::new(FRAME_WIDTH, NoClock).unwrap();
    let mut cut = Cut {
        inner: SideBySide::new(&frame, FRAME_WIDTH, FRAME_HEIGHT).unwrap(),
        rows: 70,
        sent: 0,
    };
    let e = preset.run(&mut cut, &mut arena, &mut summary).expect_err("a cut frame");
    assert!(!e.to_string().contains('\n'), "{e}");
    assert!(summary.refined_rows() < FRAME_HEIGHT);

    // The next whole frame in the same arena: the host's result, bit for bit.
    let mut summary = Summary::new(FRAME_WIDTH, NoClock).unwrap();
    let mut source = SideBySide::new(&frame, FRAME_WIDTH, FRAME_HEIGHT).unwrap();
    preset.run(&mut source, &mut arena, &mut summary).unwrap();
    assert_eq!(summary.refined_crc(), firmware_refined("m7", "frame"));
}
