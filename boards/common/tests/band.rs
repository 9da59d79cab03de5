//! The summary on a real run: the shipped blob and the QEMU firmware's 48x160 test band
//! through the pipeline on the host, checked against the refined rows themselves.

use bino_board::options::{ARENA_BYTES, BAND_HEIGHT, BAND_WIDTH};
use bino_board::run::{load, run_band};
use bino_board::side_by_side::SideBySide;
use bino_board::summary::{NoClock, Summary, SECTORS};
use bino_core::crc32::Crc32;
use bino_core::pipeline::{HeadChecked, MatchedRow, Sink, SlicePair};

fn read(rel: &str) -> Vec<u8> {
    let path = format!("{}/../../{rel}", env!("CARGO_MANIFEST_DIR"));
    std::fs::read(&path).unwrap_or_else(|e| panic!("{path}: {e}"))
}

/// Forwards to a summary and keeps every refined row and head-check mask.
struct Tee {
    summary: Summary<NoClock>,
    rows: Vec<Vec<u16>>,
    masks: Vec<Vec<u8>>,
}

impl Sink for Tee {
    fn matched(&mut self, row: &MatchedRow<'_>) {
        self.summary.matched(row);
    }
    fn head_checked(&mut self, row: &HeadChecked<'_>) {
        self.masks.push(row.consistent.to_vec());
        self.summary.head_checked(row);
    }
    fn refined(&mut self, row: usize, disparity_q8: &[u16]) {
        self.rows.push(disparity_q8.to_vec());
        self.summary.refined(row, disparity_q8);
    }
}

#[test]
fn summary_of_the_test_band_matches_its_refined_rows() {
    let blob = read("weights/bino_int8.bin");
    let left = read("firmware-sim/assets/band_48x160_left.gray");
    let right = read("firmware-sim/assets/band_48x160_right.gray");
    let pipeline = load(&blob).unwrap();
    let mut arena = vec![0u8; ARENA_BYTES];
    let mut tee = Tee {
        summary: Summary::new(BAND_WIDTH, NoClock).unwrap(),
        rows: Vec::new(),
        masks: Vec::new(),
    };
    let mut source = SlicePair::new(&left, &right, BAND_WIDTH, BAND_HEIGHT).unwrap();
    let report = pipeline
        .run_refined(
            &mut source,
            &bino_board::options::OPTIONS,
            &bino_board::options::REFINE,
            &mut arena,
            &mut tee,
        )
        .unwrap();
    assert!(report.arena_used <= ARENA_BYTES);
    assert_eq!(tee.rows.len(), BAND_HEIGHT);
    assert_eq!(tee.summary.refined_rows(), BAND_HEIGHT);

    let mut crc = Crc32::new();
    for row in &tee.rows {
        for d in row {
            crc.update(&d.to_le_bytes());
        }
    }
    assert_eq!(tee.summary.refined_crc(), crc.finish());

    let sectors = tee.summary.sectors();
    let sector_px = BAND_WIDTH / SECTORS;
    for (s, got) in sectors.iter().enumerate() {
        let mut px: Vec<u16> = tee
            .rows
            .iter()
            .flat_map(|r| r[s * sector_px..(s + 1) * sector_px].iter().map(|d| (d >> 8).min(64)))
            .collect();
        px.sort_unstable();
        let rank = |pct: usize| px[(px.len() * pct).div_ceil(100) - 1];
        assert_eq!(got.median_px, rank(50), "sector {s} median");
        assert_eq!(got.near_px, rank(90), "sector {s} near");
        let cols = BAND_WIDTH / 4 / SECTORS;
        let (ok, all) = tee.masks.iter().fold((0, 0), |(ok, all), m| {
            let part = &m[s * cols..(s + 1) * cols];
            (ok + part.iter().filter(|&&c| c != 0).count(), all + part.len())
        });
        assert_eq!(usize::from(got.consistent_permille), ok * 1000 / all, "sector {s}");
    }
    // The scene is not flat: the summary must see different depths across the sectors.
    assert!(
        sectors.iter().any(|s| s.median_px != sectors[0].median_px),
        "{sectors:?}"
    );
    println!(
        "test band: {sectors:?} refined_crc={:08x} arena_used={}",
        tee.summary.refined_crc(),
        report.arena_used
    );
}

#[test]
fn a_side_by_side_frame_gives_the_same_summary_as_the_two_views() {
    let blob = read("weights/bino_int8.bin");
    let left = read("firmware-sim/assets/band_48x160_left.gray");
    let right = read("firmware-sim/assets/band_48x160_right.gray");
    let frame: Vec<u8> = left
        .chunks(BAND_WIDTH)
        .zip(right.chunks(BAND_WIDTH))
        .flat_map(|(l, r)| l.iter().chain(r).copied())
        .collect();
    let pipeline = load(&blob).unwrap();
    let mut arena = vec![0u8; ARENA_BYTES];

    let mut views = Summary::new(BAND_WIDTH, NoClock).unwrap();
    let mut source = SlicePair::new(&left, &right, BAND_WIDTH, BAND_HEIGHT).unwrap();
    run_band(&pipeline, &mut source, &mut arena, &mut views).unwrap();

    let mut camera = Summary::new(BAND_WIDTH, NoClock).unwrap();
    let mut source = SideBySide::new(&frame, BAND_WIDTH, BAND_HEIGHT).unwrap();
    run_band(&pipeline, &mut source, &mut arena, &mut camera).unwrap();

    assert_eq!(camera.refined_crc(), views.refined_crc());
    assert_eq!(camera.sectors(), views.sectors());
}
