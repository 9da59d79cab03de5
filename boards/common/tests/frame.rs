//! The fast preset on a real frame: the QEMU firmware's 160x120 test frame through
//! `run_frame` (the census readout refined to pixels, no weights) on the host, its summary checked
//! against the rows themselves, side by side as a camera delivers them, and its refined rows'
//! CRC-32 the one both QEMU firmwares recorded for their census run.

use bino_board::options::{BAND_WIDTH, FAST_ARENA_BYTES, FRAME_HEIGHT};
use bino_board::run::{run_frame, Preset};
use bino_board::side_by_side::SideBySide;
use bino_board::summary::{NoClock, Summary, SECTORS};
use bino_core::crc32::Crc32;
use bino_core::pipeline::{CensusRow, Sink, SlicePair};

fn read(rel: &str) -> Vec<u8> {
    let path = format!("{}/../../{rel}", env!("CARGO_MANIFEST_DIR"));
    std::fs::read(&path).unwrap_or_else(|e| panic!("{path}: {e}"))
}

/// Forwards to a summary and keeps every refined row and census mask.
struct Tee {
    summary: Summary<NoClock>,
    rows: Vec<Vec<u16>>,
    masks: Vec<Vec<u8>>,
}

impl Sink for Tee {
    fn census(&mut self, row: &CensusRow<'_>) {
        self.masks.push(row.consistent.to_vec());
        self.summary.census(row);
    }
    fn refined(&mut self, row: usize, disparity_q8: &[u16]) {
        self.rows.push(disparity_q8.to_vec());
        self.summary.refined(row, disparity_q8);
    }
}

/// The `refined` digest of the census run a committed QEMU run recorded (its JSON, read line by
/// line: the outputs are pretty-printed one field a line).
fn firmware_census_refined(core: &str) -> u32 {
    let text = String::from_utf8(read(&format!("firmware-sim/measured/{core}.json"))).unwrap();
    let lines: Vec<&str> = text.lines().map(str::trim).collect();
    let at = lines
        .windows(3)
        .find(|w| w[0] == r#""pathway": "census","# && w[1] == r#""name": "refined","#)
        .unwrap_or_else(|| panic!("{core}.json: no census refined digest"));
    let digest = at[2].trim_start_matches(r#""digest": ""#).trim_end_matches(r#"","#);
    u32::from_str_radix(digest, 16).unwrap_or_else(|e| panic!("{core}.json: {:?}: {e}", at[2]))
}

#[test]
fn the_fast_preset_summarises_the_test_frame_as_the_firmware_refines_it() {
    let left = read("firmware-sim/assets/frame_120x160_left.gray");
    let right = read("firmware-sim/assets/frame_120x160_right.gray");
    let mut arena = vec![0u8; FAST_ARENA_BYTES];
    let mut tee = Tee {
        summary: Summary::new(BAND_WIDTH, NoClock).unwrap(),
        rows: Vec::new(),
        masks: Vec::new(),
    };
    let mut source = SlicePair::new(&left, &right, BAND_WIDTH, FRAME_HEIGHT).unwrap();
    let report = run_frame(&mut source, &mut arena, &mut tee.summary).unwrap();
    assert!(report.arena_used <= FAST_ARENA_BYTES && report.bands > 1, "{report:?}");
    // Again through the tee, to keep the rows.
    let mut source = SlicePair::new(&left, &right, BAND_WIDTH, FRAME_HEIGHT).unwrap();
    let mut sink = Tee {
        summary: Summary::new(BAND_WIDTH, NoClock).unwrap(),
        rows: Vec::new(),
        masks: Vec::new(),
    };
    bino_core::pipeline::run_census(
        &mut source,
        &bino_board::options::OPTIONS,
        Some(&bino_board::options::CENSUS_REFINE),
        &mut arena,
        &mut sink,
    )
    .unwrap();
    assert_eq!(sink.rows.len(), FRAME_HEIGHT);
    assert_eq!(tee.summary.refined_rows(), FRAME_HEIGHT);
    let mut crc = Crc32::new();
    for d in sink.rows.iter().flatten() {
        crc.update(&d.to_le_bytes());
    }
    assert_eq!(tee.summary.refined_crc(), crc.finish());
    for core in ["m55", "m7"] {
        assert_eq!(
            tee.summary.refined_crc(),
            firmware_census_refined(core),
            "{core}: the board's fast preset against the QEMU firmware's census run"
        );
    }
    let sectors = tee.summary.sectors();
    let cols = BAND_WIDTH / 4 / SECTORS;
    for (s, got) in sectors.iter().enumerate() {
        let (ok, all) = sink.masks.iter().fold((0, 0), |(ok, all), m| {
            let part = &m[s * cols..(s + 1) * cols];
            (ok + part.iter().filter(|&&c| c != 0).count(), all + part.len())
        });
        assert_eq!(usize::from(got.consistent_permille), ok * 1000 / all, "sector {s}");
    }
    assert!(
        sectors.iter().any(|s| s.median_px != sectors[0].median_px),
        "{sectors:?}"
    );

    // Side by side, as the DCMI captures it, through the preset the board runs.
    let frame: Vec<u8> = left
        .chunks(BAND_WIDTH)
        .zip(right.chunks(BAND_WIDTH))
        .flat_map(|(l, r)| l.iter().chain(r).copied())
        .collect();
    let preset = Preset::Fast;
    assert_eq!(
        (preset.height(), preset.arena_bytes()),
        (FRAME_HEIGHT, FAST_ARENA_BYTES)
    );
    let mut camera = Summary::new(BAND_WIDTH, NoClock).unwrap();
    let mut source = SideBySide::new(&frame, BAND_WIDTH, preset.height()).unwrap();
    preset.run(&mut source, &mut arena, &mut camera).unwrap();
    assert_eq!(camera.refined_crc(), tee.summary.refined_crc());
    assert_eq!(camera.sectors(), sectors);
}
