//! Both presets on the Alif E7's whole 320x240 frame: its test frame through the board's code on
//! the host, as the board runs it (side by side from its frame buffer), with the options and the
//! refinement of that width (the head and the census SGM search 16 candidates, the refinement
//! +-4 px: `bino_core::preset::options_for_width`). Each preset's summary is checked against the
//! refined rows themselves, its refined rows' CRC-32 and its arena are the ones `bino run
//! --profile native` gives for the same frame and preset (recorded in
//! `firmware-sim/measured/host-frame-320x240.json`, which `std-host/tests/e7_frame.rs` holds
//! `bino run` to), and a short or cut frame is one error with the next frame clean.

mod common;

use bino_board::options::{Frame, ALIF_E7};
use bino_board::run::{load, Preset};
use bino_core::pipeline::{self, SlicePair};
use common::{bad_frames_then_a_clean_one, host_frame_run, run_side_by_side_twice, test_frame, Tee};

/// The E7's frame: 320x240, with options wider than the 160-px presets'.
fn e7_frame() -> Frame {
    let frame = ALIF_E7;
    assert_eq!((frame.width, frame.height), (320, 240));
    assert!(frame.options().head_candidates > bino_board::options::OPTIONS.head_candidates);
    assert!(frame.refine().params.search > bino_board::options::REFINE.params.search);
    frame
}

#[test]
fn the_learned_preset_refines_the_e7_frame_as_bino_run_does() {
    let frame = e7_frame();
    let (left, right) = test_frame(frame);
    let blob = common::read("weights/bino_int8_native.bin");
    let pipeline = load(&blob).unwrap();
    let (digest, arena_bytes, arena_used) = host_frame_run("learned");
    assert_eq!(frame.arena_bytes(), arena_bytes, "the board's arena against bino run's");
    let mut arena = vec![0u8; frame.arena_bytes()];

    let mut tee = Tee::new(frame);
    let mut source = SlicePair::new(&left, &right, frame.width, frame.height).unwrap();
    let report = pipeline
        .run_refined(&mut source, &frame.options(), &frame.refine(), &mut arena, &mut tee)
        .unwrap();
    assert_eq!(report.arena_used, arena_used, "{report:?}");
    assert!(report.bands > 1, "{report:?}");
    let views = tee.checked_summary();
    assert_eq!(
        views.refined_crc(),
        digest,
        "the board's learned preset against bino run's"
    );

    let preset = Preset::Learned(pipeline);
    run_side_by_side_twice(&preset, frame, &mut arena, (&left, &right), &views);
    // Cut off in the frame's third band, then a whole frame in the same (dirty) arena.
    bad_frames_then_a_clean_one(&preset, frame, &mut arena, (&left, &right), 130, digest);
    println!(
        "e7 test frame, learned: {:?} refined_crc={:08x} arena_used={}",
        views.sectors(),
        views.refined_crc(),
        report.arena_used
    );
}

#[test]
fn the_fast_preset_refines_the_e7_frame_as_bino_run_does() {
    let frame = e7_frame();
    let (left, right) = test_frame(frame);
    let (digest, arena_bytes, arena_used) = host_frame_run("fast");
    assert_eq!(
        frame.fast_arena_bytes(),
        arena_bytes,
        "the board's arena against bino run's"
    );
    let mut arena = vec![0u8; frame.fast_arena_bytes()];

    let mut tee = Tee::new(frame);
    let mut source = SlicePair::new(&left, &right, frame.width, frame.height).unwrap();
    let census = frame.census_refine();
    let report = pipeline::run_census(&mut source, &frame.options(), Some(&census), &mut arena, &mut tee).unwrap();
    assert_eq!(report.arena_used, arena_used, "{report:?}");
    let views = tee.checked_summary();
    assert_eq!(
        views.refined_crc(),
        digest,
        "the board's fast preset against bino run's"
    );

    let preset = Preset::Fast;
    assert_eq!(preset.arena_bytes(frame), frame.fast_arena_bytes());
    run_side_by_side_twice(&preset, frame, &mut arena, (&left, &right), &views);
    bad_frames_then_a_clean_one(&preset, frame, &mut arena, (&left, &right), 130, digest);
}
