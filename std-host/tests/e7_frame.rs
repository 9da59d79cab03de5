//! One readout, one number, on the Alif E7 board's 320x240 frame
//! (`firmware-sim/assets/frame_240x320_*.gray`, the built-in scene): `bino run --profile native`
//! runs each board preset there with the options and the refinement the board runs at that width
//! (`bino_core::preset::options_for_width`, `refine_for_width`), and writes the pixels whose
//! CRC-32 (in Q8, as the boards digest their refined rows) and arena
//! `firmware-sim/measured/host-frame-320x240.json` records; `boards/common/tests/e7_frame.rs`
//! holds the board's code to the same digests and arena. After changing the engine, rewrite the
//! file with `cargo test -p bino-host --test e7_frame -- --ignored`.

use std::path::PathBuf;

use bino_core::pipeline::Refine;
use bino_core::preset::{census_refine_for_width, options_for_width, refine_for_width};
use bino_host::demo::DEFAULT_PENALTIES;
use bino_host::int8::pipeline_maps::{readout_options, streamed_input};
use bino_host::readout::pathway::Pathway;
use bino_host::readout::Readout;
use serde_json::{json, Value};

mod common;
use common::{bino, q8_crc, repo, s, scratch_dir};

/// The E7's frame, (width, height).
const FRAME: (usize, usize) = (320, 240);
/// Where the host's digests of the frame are recorded.
const MEASURED: &str = "firmware-sim/measured/host-frame-320x240.json";

/// A board preset as `bino run` runs it.
struct Preset {
    name: &'static str,
    readout: &'static str,
    args: &'static [&'static str],
}

const PRESETS: [Preset; 2] = [
    Preset {
        name: "fast",
        readout: "census+lr+ref",
        args: &[],
    },
    Preset {
        name: "learned",
        readout: "fuse-census+lr+ref",
        args: &["--pathway", "native", "--blob", "weights/bino_int8_native.bin"],
    },
];

/// What `bino run` gives for `preset` on the frame: (refined digest, arena bytes, arena used).
fn run(preset: &Preset, dir: &std::path::Path) -> (u32, u64, u64) {
    let (w, h) = FRAME;
    let out = dir.join(preset.name);
    let (left, right) = (dir.join("l.png"), dir.join("r.png"));
    let mut args = vec!["run", "--left", s(&left), "--right", s(&right), "--profile", "native"];
    args.extend_from_slice(preset.args);
    args.extend_from_slice(&["--out", s(&out)]);
    let run = bino(&args);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let expected = format!("bino run: {} readout", preset.readout);
    assert!(stdout.contains(&expected), "{}: {stdout}", preset.name);
    assert!(stdout.contains(&format!("computed at {w}x{h}")), "{stdout}");
    // "arena: <used> bytes used of <bytes>"
    let arena = stdout
        .lines()
        .find_map(|l| l.strip_prefix("arena: "))
        .unwrap_or_else(|| panic!("no arena line: {stdout}"));
    let words: Vec<&str> = arena.split_whitespace().collect();
    let (used, bytes) = (words[0].parse().unwrap(), words[4].parse().unwrap());
    (q8_crc(&out.join("disparity.pfm"), FRAME), bytes, used)
}

/// Runs both presets on the frame, views written as PNG into a fresh folder.
fn run_both() -> Vec<(u32, u64, u64)> {
    let (w, h) = FRAME;
    let dir = scratch_dir("e7-frame");
    let assets = repo().join("firmware-sim/assets");
    for (view, png) in [("left", "l.png"), ("right", "r.png")] {
        let pixels = std::fs::read(assets.join(format!("frame_{h}x{w}_{view}.gray"))).unwrap();
        image::GrayImage::from_raw(w as u32, h as u32, pixels)
            .unwrap()
            .save(dir.join(png))
            .unwrap();
    }
    let runs = PRESETS.iter().map(|p| run(p, &dir)).collect();
    let _ = std::fs::remove_dir_all(&dir);
    runs
}

fn measured_path() -> PathBuf {
    repo().join(MEASURED)
}

#[test]
fn the_commands_run_the_board_presets_options_at_320_px() {
    let (w, _) = FRAME;
    let learned = Pathway::Native.default_readout().refined(true);
    assert_eq!(learned.to_string(), PRESETS[1].readout);
    let options = readout_options(learned, Pathway::Native, 16, DEFAULT_PENALTIES, 1.0, w);
    assert_eq!(options, options_for_width(w));
    let input = streamed_input(learned, Pathway::Native).unwrap();
    assert_eq!(Refine::for_width(input, w), refine_for_width(w));

    let fast: Readout = PRESETS[0].readout.parse().unwrap();
    let census = readout_options(fast, Pathway::Export, 16, DEFAULT_PENALTIES, 1.0, w);
    // The census SGM searches as far as the board's preset and checks with its tolerance.
    assert_eq!(census.head_candidates, options_for_width(w).head_candidates);
    assert_eq!(census.lr_max_diff_q8, options_for_width(w).lr_max_diff_q8);
    let input = streamed_input(fast, Pathway::Export).unwrap();
    assert_eq!(Refine::for_width(input, w), census_refine_for_width(w));
    // Wider than the 160-px presets: more candidates, a wider refinement.
    assert!(options_for_width(w).head_candidates > bino_core::preset::OPTIONS.head_candidates);
}

#[test]
fn run_writes_the_recorded_pixels_of_both_presets_on_the_e7_frame() {
    let path = measured_path();
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let recorded: Value = serde_json::from_str(&text).unwrap();
    let (w, h) = FRAME;
    assert_eq!(recorded["frame"], json!({"width": w, "height": h}));
    for (preset, (digest, bytes, used)) in PRESETS.iter().zip(run_both()) {
        let entry = recorded["runs"]
            .as_array()
            .unwrap()
            .iter()
            .find(|r| r["preset"] == preset.name)
            .unwrap_or_else(|| panic!("{}: no {} run", path.display(), preset.name));
        assert_eq!(
            entry["refined"].as_str(),
            Some(format!("{digest:08x}").as_str()),
            "{}: bino run's digest (rewrite with -- --ignored after changing the engine)",
            preset.name
        );
        assert_eq!(
            (&entry["arena_bytes"], &entry["arena_used"]),
            (&json!(bytes), &json!(used))
        );
    }
}

#[test]
#[ignore = "writes firmware-sim/measured/host-frame-320x240.json; run on purpose after changing the engine"]
fn write_the_host_digests_of_the_e7_frame() {
    let (w, h) = FRAME;
    let runs: Vec<Value> = PRESETS
        .iter()
        .zip(run_both())
        .map(|(p, (digest, bytes, used))| {
            let mut command = vec!["bino", "run", "--profile", "native"];
            command.extend_from_slice(p.args);
            json!({
                "preset": p.name,
                "readout": p.readout,
                "command": command.join(" "),
                "refined": format!("{digest:08x}"),
                "arena_bytes": bytes,
                "arena_used": used,
            })
        })
        .collect();
    let record = json!({
        "schema": "bino-host-frame/1",
        "what": "bino run on the E7 board's test frame: CRC-32 of disparity.pfm in Q8 px (u16 little-endian, rows top to bottom), the arena it reports",
        "views": [format!("firmware-sim/assets/frame_{h}x{w}_left.gray"), format!("firmware-sim/assets/frame_{h}x{w}_right.gray")],
        "frame": {"width": w, "height": h},
        "runs": runs,
    });
    let text = serde_json::to_string_pretty(&record).unwrap() + "\n";
    std::fs::write(measured_path(), text).unwrap();
}
