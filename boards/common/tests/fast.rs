//! The fast preset on a real frame: the STM32H743's 160x120 test frame (the QEMU firmware's)
//! through the board's code on the host (the census readout refined to pixels, no weights), its
//! summary checked against the refined rows themselves, side by side as the DCMI captures it,
//! again in the same arena, and its refined rows' CRC-32 the one both QEMU firmwares recorded
//! for their census run.

mod common;

use bino_board::options::{CENSUS_REFINE, OPTIONS, STM32H7};
use bino_board::run::Preset;
use bino_core::pipeline::{self, SlicePair};
use common::{firmware_refined, run_side_by_side_twice, test_frame, Tee};

#[test]
fn the_fast_preset_summarises_the_test_frame_as_the_firmware_refines_it() {
    let frame = STM32H7;
    let (left, right) = test_frame(frame);
    // At 160 px the frame's options are the presets the QEMU firmware runs.
    assert_eq!((frame.options(), frame.census_refine()), (OPTIONS, CENSUS_REFINE));
    let mut arena = vec![0u8; frame.fast_arena_bytes()];

    let mut tee = Tee::new(frame);
    let mut source = SlicePair::new(&left, &right, frame.width, frame.height).unwrap();
    let report = pipeline::run_census(&mut source, &OPTIONS, Some(&CENSUS_REFINE), &mut arena, &mut tee).unwrap();
    assert!(
        report.arena_used <= frame.fast_arena_bytes() && report.bands > 1,
        "{report:?}"
    );
    let views = tee.checked_summary();
    for core in ["m55", "m7"] {
        assert_eq!(
            views.refined_crc(),
            firmware_refined(core, "census"),
            "{core}: the board's fast preset against the QEMU firmware's census run"
        );
    }

    // Side by side, as the DCMI captures it, through the preset the board runs, twice in the
    // same arena.
    let preset = Preset::Fast;
    assert_eq!(preset.arena_bytes(frame), frame.fast_arena_bytes());
    run_side_by_side_twice(&preset, frame, &mut arena, (&left, &right), &views);
}
