//! The test-frame check both boards can run: the QEMU firmware's embedded 160x120 test frame
//! through the preset, its summary printed, and compared with the host's (baked in by the
//! board's `build.rs` through [`crate::bake`]).

use bino_core::pipeline::SlicePair;

use crate::clock::DwtClock;
use crate::options::{FRAME_HEIGHT, FRAME_WIDTH};
use crate::run::Preset;
use crate::summary::{Sector, Summary, SECTORS};

/// Runs `preset` on the test frame `left`/`right` in `arena` as frame `frame`, prints its
/// summary and `bino result=pass` when the refined rows' CRC and the sectors equal the host's
/// (`fail` otherwise, `error` on an engine error). Returns whether it passed.
#[allow(clippy::too_many_arguments)]
pub fn test_frame(
    preset: &Preset<'_>,
    frame: u32,
    left: &[u8],
    right: &[u8],
    arena: &mut [u8],
    expected_crc: u32,
    expected: &[Sector; SECTORS],
    core_hz: u32,
) -> bool {
    let result = SlicePair::new(left, right, FRAME_WIDTH, FRAME_HEIGHT).and_then(|mut rows| {
        let mut summary = Summary::new(FRAME_WIDTH, DwtClock)?;
        preset
            .run(&mut rows, arena, &mut summary)
            .map(|report| (summary, report))
    });
    match result {
        Ok((summary, report)) => {
            crate::log::print(frame, &summary, &report, core_hz);
            let pass = summary.refined_crc() == expected_crc && summary.sectors() == *expected;
            defmt::println!(
                "bino frame={=u32} result={=str} refined_crc={=u32:08x} host_refined_crc={=u32:08x}",
                frame,
                if pass { "pass" } else { "fail" },
                summary.refined_crc(),
                expected_crc
            );
            pass
        }
        Err(e) => {
            defmt::println!(
                "bino frame={=u32} result=error error={}",
                frame,
                defmt::Display2Format(&e)
            );
            false
        }
    }
}
