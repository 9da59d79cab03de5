//! The learned preset on a real frame: the shipped blob and the STM32H743's 160x120 test frame
//! (the QEMU firmware's) through the board's code on the host, band after band, its summary
//! checked against the refined rows themselves, side by side as the DCMI captures it, again in
//! the same arena, and its refined rows' CRC-32 the one both QEMU firmwares recorded for their
//! learned frame run; a bad frame is one error and the next frame starts clean.

mod common;

use bino_board::options::{OPTIONS, REFINE, STM32H7};
use bino_board::run::{load, Preset};
use bino_core::pipeline::SlicePair;
use common::{bad_frames_then_a_clean_one, firmware_refined, run_side_by_side_twice, test_frame, Tee};

#[test]
fn the_learned_preset_summarises_the_test_frame_as_the_firmware_refines_it() {
    let blob = common::read("weights/bino_int8_native.bin");
    let frame = STM32H7;
    let (left, right) = test_frame(frame);
    let pipeline = load(&blob).unwrap();
    // At 160 px the frame's options are the presets the QEMU firmware runs.
    assert_eq!((frame.options(), frame.refine()), (OPTIONS, REFINE));
    let mut arena = vec![0u8; frame.arena_bytes()];

    let mut tee = Tee::new(frame);
    let mut source = SlicePair::new(&left, &right, frame.width, frame.height).unwrap();
    let report = pipeline
        .run_refined(&mut source, &OPTIONS, &REFINE, &mut arena, &mut tee)
        .unwrap();
    // A whole frame in the arena of its const fn: several bands, none of them growing it.
    assert!(
        report.arena_used <= frame.arena_bytes() && report.bands > 1,
        "{report:?}"
    );
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
    assert_eq!(preset.arena_bytes(frame), frame.arena_bytes());
    run_side_by_side_twice(&preset, frame, &mut arena, (&left, &right), &views);
    println!(
        "test frame, learned: {:?} refined_crc={:08x} arena_used={}",
        views.sectors(),
        views.refined_crc(),
        report.arena_used
    );
}

#[test]
fn a_bad_frame_is_one_error_line_and_the_next_frame_starts_clean() {
    let blob = common::read("weights/bino_int8_native.bin");
    let frame = STM32H7;
    let (left, right) = test_frame(frame);
    let preset = Preset::Learned(load(&blob).unwrap());
    let mut arena = vec![0u8; frame.arena_bytes()];
    // Cut off in the frame's second band.
    let expected = firmware_refined("m7", "frame");
    bad_frames_then_a_clean_one(&preset, frame, &mut arena, (&left, &right), 70, expected);
}
