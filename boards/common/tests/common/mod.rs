//! What the host tests of both presets and both boards' frames share: the committed files, the
//! test frame side by side as a camera captures it, a camera that stops mid-frame, a sink that
//! keeps the refined rows, the summary checked against those rows, and the recorded digests of
//! the QEMU firmware (160x120) and of `bino run` (320x240).
#![allow(dead_code)]

use bino_board::options::Frame;
use bino_board::run::Preset;
use bino_board::side_by_side::{interleave, SideBySide};
use bino_board::summary::{NoClock, Summary, SECTORS};
use bino_core::crc32::Crc32;
use bino_core::pipeline::{CensusRow, HeadChecked, MatchedRow, RowSource, Sink};
use bino_core::Error;

/// A committed file of the repository.
pub fn read(rel: &str) -> Vec<u8> {
    let path = format!("{}/../../{rel}", env!("CARGO_MANIFEST_DIR"));
    std::fs::read(&path).unwrap_or_else(|e| panic!("{path}: {e}"))
}

/// The committed test frame of `frame`'s size (the built-in scene), (left, right): what the
/// board's `build.rs` reads (`bino_board::bake::test_frame_path`).
pub fn test_frame(frame: Frame) -> (Vec<u8>, Vec<u8>) {
    let view = |v: &str| {
        read(&format!(
            "firmware-sim/assets/frame_{}x{}_{v}.gray",
            frame.height, frame.width
        ))
    };
    let (left, right) = (view("left"), view("right"));
    assert_eq!((left.len(), right.len()), (frame.pixels(), frame.pixels()));
    (left, right)
}

/// The two views side by side, line by line, as a camera interface captures a stereo module.
pub fn side_by_side(left: &[u8], right: &[u8], width: usize) -> Vec<u8> {
    let mut frame = vec![0u8; 2 * left.len()];
    interleave(left, right, width, &mut frame).unwrap();
    frame
}

/// Runs `preset` on the views of `frame` side by side, as a camera captures them, twice in the
/// same `arena`: each run's summary must be `views`' (a frame starts clean whatever the last one
/// left there).
pub fn run_side_by_side_twice(
    preset: &Preset<'_>,
    frame: Frame,
    arena: &mut [u8],
    (left, right): (&[u8], &[u8]),
    views: &Summary<NoClock>,
) {
    let (width, height) = (frame.width, frame.height);
    let whole = side_by_side(left, right, width);
    for _ in 0..2 {
        let mut camera = Summary::new(width, NoClock).unwrap();
        let mut source = SideBySide::new(&whole, width, height).unwrap();
        preset.run(&mut source, arena, &mut camera).unwrap();
        assert_eq!(camera.refined_crc(), views.refined_crc());
        assert_eq!(camera.sectors(), views.sectors());
    }
}

/// A camera that stops sending after `rows` lines of the frame (a capture cut short).
pub struct Cut<S> {
    pub inner: S,
    pub rows: usize,
    pub sent: usize,
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

/// A frame one line short of `frame` and a capture cut off after `cut_rows` lines each give
/// `preset` one single-line error, the cut one mid-run in `arena` (left dirty); the next whole
/// frame in the same arena then refines to `expected`, the host's digest, bit for bit.
pub fn bad_frames_then_a_clean_one(
    preset: &Preset<'_>,
    frame: Frame,
    arena: &mut [u8],
    (left, right): (&[u8], &[u8]),
    cut_rows: usize,
    expected: u32,
) {
    let (width, height) = (frame.width, frame.height);
    let whole = side_by_side(left, right, width);

    // A frame of the wrong size never reaches the pipeline.
    let short = SideBySide::new(&whole[..whole.len() - 2 * width], width, height);
    let e = short.expect_err("a frame one line short");
    assert!(
        e.to_string().contains("side-by-side frame") && !e.to_string().contains('\n'),
        "{e}"
    );

    // A capture cut off mid-frame: an error mid-run, the arena left dirty.
    let mut summary = Summary::new(width, NoClock).unwrap();
    let mut cut = Cut {
        inner: SideBySide::new(&whole, width, height).unwrap(),
        rows: cut_rows,
        sent: 0,
    };
    let e = preset.run(&mut cut, arena, &mut summary).expect_err("a cut frame");
    assert!(!e.to_string().contains('\n'), "{e}");
    assert!(
        summary.refined_rows() > 0 && summary.refined_rows() < height,
        "{}",
        summary.refined_rows()
    );

    // The next whole frame in the same arena: the host's result, bit for bit.
    let mut summary = Summary::new(width, NoClock).unwrap();
    let mut source = SideBySide::new(&whole, width, height).unwrap();
    preset.run(&mut source, arena, &mut summary).unwrap();
    assert_eq!(summary.refined_rows(), height);
    assert_eq!(summary.refined_crc(), expected);
}

/// Forwards to a summary and keeps every refined row and the readout's left-right masks (the
/// head's, or the census SGM's).
pub struct Tee {
    pub frame: Frame,
    pub summary: Summary<NoClock>,
    pub rows: Vec<Vec<u16>>,
    pub masks: Vec<Vec<u8>>,
}

impl Tee {
    pub fn new(frame: Frame) -> Self {
        Self {
            frame,
            summary: Summary::new(frame.width, NoClock).unwrap(),
            rows: Vec::new(),
            masks: Vec::new(),
        }
    }

    /// The summary, finished, checked against the rows it saw: every refined row of the frame,
    /// their CRC-32, each sector's median and near disparity and its share of confirmed cells,
    /// and a scene that is not flat.
    pub fn checked_summary(mut self) -> Summary<NoClock> {
        self.summary.finish();
        let Frame { width, height } = self.frame;
        assert_eq!(self.rows.len(), height);
        assert!(self.rows.iter().all(|r| r.len() == width));
        assert_eq!(self.summary.refined_rows(), height);
        let mut crc = Crc32::new();
        for d in self.rows.iter().flatten() {
            crc.update(&d.to_le_bytes());
        }
        assert_eq!(self.summary.refined_crc(), crc.finish());

        let sectors = self.summary.sectors();
        let sector_px = width / SECTORS;
        let cols = width / 4 / SECTORS;
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

/// The `refined` digest, the arena and its use `bino run --profile native` recorded for the
/// board preset `preset` (`fast` or `learned`) on the Alif E7's 320x240 test frame
/// (`firmware-sim/measured/host-frame-320x240.json`, which `std-host/tests/e7_frame.rs` holds
/// `bino run` to; read line by line: the file is pretty-printed one field a line, each run a flat
/// object).
pub fn host_frame_run(preset: &str) -> (u32, usize, usize) {
    let rel = "firmware-sim/measured/host-frame-320x240.json";
    let text = String::from_utf8(read(rel)).unwrap();
    let mut fields: Vec<(String, String)> = Vec::new();
    for line in text.lines().map(str::trim) {
        if line.starts_with('}') {
            let get = |key: &str| fields.iter().find(|(k, _)| k == key).map(|(_, v)| v.clone());
            if get("preset").as_deref() == Some(preset) {
                let field = |key: &str| get(key).unwrap_or_else(|| panic!("{rel}: {preset}: no {key}"));
                let digest = u32::from_str_radix(&field("refined"), 16).unwrap();
                let number = |key: &str| field(key).parse().unwrap_or_else(|e| panic!("{rel}: {key}: {e}"));
                return (digest, number("arena_bytes"), number("arena_used"));
            }
            fields.clear();
        } else if let Some((key, value)) = line.split_once("\": ") {
            let value = value.trim_end_matches(',').trim_matches('"');
            fields.push((key.trim_start_matches('"').to_string(), value.to_string()));
        }
    }
    panic!("{rel}: no {preset} run")
}
