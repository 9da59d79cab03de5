//! What the host tests of both presets share: the committed files, the test frame side by side
//! as the DCMI captures it, a sink that keeps the refined rows, the summary checked against
//! those rows, and the QEMU firmware's recorded digests.

use bino_board::options::{FRAME_HEIGHT, FRAME_WIDTH};
use bino_board::run::Preset;
use bino_board::side_by_side::SideBySide;
use bino_board::summary::{NoClock, Summary, SECTORS};
use bino_core::crc32::Crc32;
use bino_core::pipeline::{CensusRow, HeadChecked, MatchedRow, Sink};

/// A committed file of the repository.
pub fn read(rel: &str) -> Vec<u8> {
    let path = format!("{}/../../{rel}", env!("CARGO_MANIFEST_DIR"));
    std::fs::read(&path).unwrap_or_else(|e| panic!("{path}: {e}"))
}

/// The QEMU firmware's 160x120 test frame, (left, right).
pub fn test_frame() -> (Vec<u8>, Vec<u8>) {
    (
        read("firmware-sim/assets/frame_120x160_left.gray"),
        read("firmware-sim/assets/frame_120x160_right.gray"),
    )
}

/// The two views side by side, line by line, as the DCMI captures a stereo module.
pub fn side_by_side(left: &[u8], right: &[u8]) -> Vec<u8> {
    left.chunks(FRAME_WIDTH)
        .zip(right.chunks(FRAME_WIDTH))
        .flat_map(|(l, r)| l.iter().chain(r).copied())
        .collect()
}

/// Runs `preset` on the views side by side, as the DCMI captures them, twice in the same
/// `arena`: each run's summary must be `views`' (a frame starts clean whatever the last one
/// left there).
pub fn run_side_by_side_twice(
    preset: &Preset<'_>,
    arena: &mut [u8],
    (left, right): (&[u8], &[u8]),
    views: &Summary<NoClock>,
) {
    let frame = side_by_side(left, right);
    for _ in 0..2 {
        let mut camera = Summary::new(FRAME_WIDTH, NoClock).unwrap();
        let mut source = SideBySide::new(&frame, FRAME_WIDTH, FRAME_HEIGHT).unwrap();
        preset.run(&mut source, arena, &mut camera).unwrap();
        assert_eq!(camera.refined_crc(), views.refined_crc());
        assert_eq!(camera.sectors(), views.sectors());
    }
}

/// Forwards to a summary and keeps every refined row and the readout's left-right masks (the
/// head's, or the census SGM's).
pub struct Tee {
    pub summary: Summary<NoClock>,
    pub rows: Vec<Vec<u16>>,
    pub masks: Vec<Vec<u8>>,
}

impl Tee {
    pub fn new() -> Self {
        Self {
            summary: Summary::new(FRAME_WIDTH, NoClock).unwrap(),
            rows: Vec::new(),
            masks: Vec::new(),
        }
    }

    /// The summary, finished, checked against the rows it saw: every refined row of the frame,
    /// their CRC-32, each sector's median and near disparity and its share of confirmed cells,
    /// and a scene that is not flat.
    pub fn checked_summary(mut self) -> Summary<NoClock> {
        self.summary.finish();
        assert_eq!(self.rows.len(), FRAME_HEIGHT);
        assert_eq!(self.summary.refined_rows(), FRAME_HEIGHT);
        let mut crc = Crc32::new();
        for d in self.rows.iter().flatten() {
            crc.update(&d.to_le_bytes());
        }
        assert_eq!(self.summary.refined_crc(), crc.finish());

        let sectors = self.summary.sectors();
        let sector_px = FRAME_WIDTH / SECTORS;
        let cols = FRAME_WIDTH / 4 / SECTORS;
        for (s, got) in sectors.iter().enumerate() {
            let mut px: Vec<u16> = self
                .rows
                .iter()
                .flat_map(|r| r[s * sector_px..(s + 1) * sector_px].iter().map(|d| (d >> 8).min(64)))
                .collect();
            px.sort_unstable();
            let rank = |pct: usize| px[(px.len() * pct).div_ceil(100) - 1];
            assert_eq!(got.median_px, rank(50), "sector {s} median");
            assert_eq!(got.near_px, rank(90), "sector {s} near");
            let (ok, all) = self.masks.iter().fold((0, 0), |(ok, all), m| {
                let part = &m[s * cols..(s + 1) * cols];
                (ok + part.iter().filter(|&&c| c != 0).count(), all + part.len())
            });
            assert!(all > 0, "sector {s}: no checked cells");
            assert_eq!(usize::from(got.consistent_permille), ok * 1000 / all, "sector {s}");
        }
        // The scene is not flat: the summary must see different depths across the sectors.
        assert!(
            sectors.iter().any(|s| s.median_px != sectors[0].median_px),
            "{sectors:?}"
        );
        self.summary
    }
}

impl Sink for Tee {
    fn matched(&mut self, row: &MatchedRow<'_>) {
        self.summary.matched(row);
    }
    fn head_checked(&mut self, row: &HeadChecked<'_>) {
        self.masks.push(row.consistent.to_vec());
        self.summary.head_checked(row);
    }
    fn census(&mut self, row: &CensusRow<'_>) {
        self.masks.push(row.consistent.to_vec());
        self.summary.census(row);
    }
    fn refined(&mut self, row: usize, disparity_q8: &[u16]) {
        self.rows.push(disparity_q8.to_vec());
        self.summary.refined(row, disparity_q8);
    }
}

/// The `refined` digest of the run `pathway` (`census`: the fast preset's frame; `frame`: the
/// learned preset's) a committed QEMU run on `core` recorded, which the firmware checked against
/// the host's run of `firmware-sim/src/workload.rs` (its JSON, read line by line: the outputs
/// are pretty-printed one field a line).
pub fn firmware_refined(core: &str, pathway: &str) -> u32 {
    let text = String::from_utf8(read(&format!("firmware-sim/measured/{core}.json"))).unwrap();
    let lines: Vec<&str> = text.lines().map(str::trim).collect();
    let field = |line: &str, key: &str| -> Option<String> {
        let value = line.strip_prefix(&format!("\"{key}\": "))?;
        Some(value.trim_end_matches(',').trim_matches('"').to_string())
    };
    let at = lines
        .windows(5)
        .find(|w| {
            field(w[0], "pathway").as_deref() == Some(pathway) && field(w[1], "name").as_deref() == Some("refined")
        })
        .unwrap_or_else(|| panic!("{core}.json: no {pathway} refined digest"));
    let digest = field(at[2], "digest").unwrap_or_else(|| panic!("{core}.json: {:?}", at[2]));
    let expected = field(at[3], "expected").unwrap_or_else(|| panic!("{core}.json: {:?}", at[3]));
    // The firmware matched the host's digest: the recorded one is the host's too.
    assert_eq!(digest, expected, "{core}.json: {pathway} refined");
    assert_eq!(field(at[4], "match").as_deref(), Some("true"), "{core}.json: {pathway}");
    u32::from_str_radix(&digest, 16).unwrap_or_else(|e| panic!("{core}.json: {digest:?}: {e}"))
}
