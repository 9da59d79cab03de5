//! The test-frame check both boards can run: the embedded test frame of the board's size (the
//! built-in scene, `firmware-sim/assets/frame_<H>x<W>_*.gray`) through the preset, its summary
//! printed, and compared with the host's (baked in by the board's `build.rs` through
//! [`crate::bake`]).

use bino_core::pipeline::RowSource;
use bino_core::Error;

use crate::clock::DwtClock;
use crate::run::Preset;
use crate::summary::{Sector, Summary, SECTORS};

/// Runs `preset` on the test frame `rows` delivers in `arena` as frame `frame`, prints its
/// summary and `bino result=pass` when the refined rows' CRC and the sectors equal the host's
/// (`fail` otherwise, `error` on an engine error or a source that could not be made). Returns
/// whether it passed.
pub fn test_frame(
    preset: &Preset<'_>,
    frame: u32,
    rows: Result<impl RowSource, Error>,
    arena: &mut [u8],
    expected_crc: u32,
    expected: &[Sector; SECTORS],
    core_hz: u32,
) -> bool {
    let result = rows.and_then(|mut rows| {
        let mut summary = Summary::new(rows.width(), DwtClock)?;
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
