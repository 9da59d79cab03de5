//! Picks the board from the target, hands the linker its memory map, and runs the firmware's
//! workload on the host (the same `bino-core`, the same `src/workload.rs`, the shipped blob, the
//! embedded band) to bake the expected per-stage digests into the firmware.
//!
//! Band: `48x160` by default, `48x32` with the `small-band` feature (a quick check). The fast
//! preset's census run and the learned preset's frame run read the `160x120` frame (with
//! `small-band`, the small band again). With the `frame320` feature (the Cortex-M55 only) both
//! presets also run the Alif E7's `320x240` frame with the options of that width, and their
//! refined rows' digests and arena must be the ones `bino run` gives for it
//! (`measured/host-frame-320x240.json`): the build fails otherwise, and the firmware checks its
//! own rows against that file's digests.

use std::env;
use std::fmt::Write as _;
use std::fs;
use std::path::{Path, PathBuf};

#[path = "src/workload.rs"]
#[allow(dead_code)]
mod workload;

#[path = "src/equalise_case.rs"]
mod equalise_case;

#[path = "build/host_frame.rs"]
mod host_frame;

use bino_core::pipeline::SlicePair;
use workload::{Hooks, Run, Stage, OUTPUTS};

/// The host run needs no hooks.
struct Quiet;

impl Hooks for Quiet {
    fn enter(&mut self, _stage: Stage) {}
    fn pause(&mut self) {}
    fn resume(&mut self, _stage: Stage) {}
    fn finish(&mut self) {}
}

fn main() {
    let root = PathBuf::from(env::var("CARGO_MANIFEST_DIR").unwrap());
    let out = PathBuf::from(env::var("OUT_DIR").unwrap());
    let target = env::var("TARGET").unwrap();

    // Board from the target: the M55's v8-M Mainline or the M7's v7E-M.
    println!("cargo::rustc-check-cfg=cfg(board, values(\"an547\", \"an500\"))");
    let board = match target.as_str() {
        "thumbv8m.main-none-eabihf" => Some("an547"),
        "thumbv7em-none-eabihf" => Some("an500"),
        _ => None,
    };
    let frame320 = env::var_os("CARGO_FEATURE_FRAME320").is_some();
    assert!(
        !(frame320 && board == Some("an500")),
        "feature frame320: the E7's 320x240 frame runs on the Cortex-M55 (mps3-an547) only"
    );
    if let Some(board) = board {
        println!("cargo::rustc-cfg=board=\"{board}\"");
        copy(&root.join(format!("memory/{board}.x")), &out.join("memory.x"));
        copy(&root.join("memory/stack.x"), &out.join("stack.x"));
        println!("cargo::rustc-link-search={}", out.display());
    }
    println!("cargo::rerun-if-changed=memory");
    println!("cargo::rerun-if-changed=build");
    println!("cargo::rerun-if-changed=src/workload.rs");
    println!("cargo::rerun-if-changed=src/equalise_case.rs");
    println!("cargo::rerun-if-changed=../core/src");

    let (height, width) = if env::var_os("CARGO_FEATURE_SMALL_BAND").is_some() {
        (48, 32)
    } else {
        (48, 160)
    };
    let blob_path = root.join("../weights/bino_int8.bin");
    let (frame_kind, frame_height) = if height == 48 && width == 32 {
        ("band", 48)
    } else {
        ("frame", 120)
    };
    let left_path = root.join(format!("assets/band_{height}x{width}_left.gray"));
    let right_path = root.join(format!("assets/band_{height}x{width}_right.gray"));
    let frame_left_path = root.join(format!("assets/{frame_kind}_{frame_height}x{width}_left.gray"));
    let frame_right_path = root.join(format!("assets/{frame_kind}_{frame_height}x{width}_right.gray"));
    for p in [&blob_path, &left_path, &right_path, &frame_left_path, &frame_right_path] {
        println!("cargo::rerun-if-changed={}", p.display());
    }
    let blob = read(&blob_path);
    let left = read(&left_path);
    let right = read(&right_path);
    let frame_left = read(&frame_left_path);
    let frame_right = read(&frame_right_path);

    // The E7's frame, read only for the frame320 feature.
    let (e7_height, e7_width) = workload::E7_FRAME;
    let e7_path = |view: &str| root.join(format!("assets/frame_{e7_height}x{e7_width}_{view}.gray"));
    let (e7_left, e7_right) = if frame320 {
        println!("cargo::rerun-if-changed={}", e7_path("left").display());
        println!("cargo::rerun-if-changed={}", e7_path("right").display());
        (read(&e7_path("left")), read(&e7_path("right")))
    } else {
        (Vec::new(), Vec::new())
    };

    // Each run in an arena of exactly the size the firmware gives it.
    let run = |run: Run| {
        let (l, r, h, w) = match run {
            Run::Census | Run::Frame => (&frame_left, &frame_right, frame_height, width),
            Run::Census320 | Run::Frame320 => (&e7_left, &e7_right, e7_height, e7_width),
            Run::Export | Run::Native => (&left, &right, height, width),
        };
        let mut arena = vec![0u8; workload::run_arena_bytes(run, h, w)];
        let mut source = SlicePair::new(l, r, w, h).unwrap_or_else(|e| panic!("{}: {e}", left_path.display()));
        workload::run(&blob, run, &mut source, &mut arena, &mut Quiet)
            .unwrap_or_else(|e| panic!("the host run of the firmware workload ({run:?}) failed: {e}"))
    };
    let outcome = run(Run::Export);
    let native = run(Run::Native);
    let census = run(Run::Census);
    let frame = run(Run::Frame);

    let mut code = String::new();
    let _ = writeln!(code, "// Generated by build.rs from a host run of src/workload.rs.");
    let _ = writeln!(code, "/// Band height in pixels.\npub const HEIGHT: usize = {height};");
    let _ = writeln!(code, "/// Band width in pixels.\npub const WIDTH: usize = {width};");
    let _ = writeln!(
        code,
        "/// Left view.\npub static LEFT: [u8; {}] = *include_bytes!({:?});",
        left.len(),
        left_path
    );
    let _ = writeln!(
        code,
        "/// Right view.\npub static RIGHT: [u8; {}] = *include_bytes!({:?});",
        right.len(),
        right_path
    );
    let _ = writeln!(
        code,
        "/// Rows of the fast preset's frame (its width is the band's).\npub const FRAME_HEIGHT: usize = {frame_height};"
    );
    let _ = writeln!(
        code,
        "/// The frame's left view.\npub static FRAME_LEFT: [u8; {}] = *include_bytes!({:?});",
        frame_left.len(),
        frame_left_path
    );
    let _ = writeln!(
        code,
        "/// The frame's right view.\npub static FRAME_RIGHT: [u8; {}] = *include_bytes!({:?});",
        frame_right.len(),
        frame_right_path
    );
    let _ = writeln!(
        code,
        "/// Weight blob bytes.\npub const BLOB_LEN: usize = {};",
        blob.len()
    );
    let _ = writeln!(
        code,
        "/// The weight blob file.\npub const BLOB_BYTES: &[u8; {}] = include_bytes!({:?});",
        blob.len(),
        blob_path
    );
    for (name, pathway, o) in [
        ("EXPORT", "export", &outcome),
        ("NATIVE", "native", &native),
        ("CENSUS", "census", &census),
        ("FRAME", "learned frame", &frame),
    ] {
        write_digests(&mut code, name, pathway, o);
    }
    if frame320 {
        let host_frame = root.join("measured/host-frame-320x240.json");
        println!("cargo::rerun-if-changed={}", host_frame.display());
        let e7 = [Run::Census320, Run::Frame320].map(|r| (r, run(r)));
        e7_frame_code(
            &mut code,
            &host_frame,
            (e7_height, e7_width),
            [e7_path("left"), e7_path("right")],
            &e7,
        );
    }
    // The defocused pair of the kernel tests: it must blur some rows and not others.
    let (l, r) = equalise_case::views().unwrap();
    let blurred = equalise_case::blurred_rows(&l, &r).unwrap();
    assert!(
        blurred > 0 && blurred < equalise_case::HEIGHT,
        "equalise_case blurs {blurred} of {} rows",
        equalise_case::HEIGHT
    );
    let mut eq = String::new();
    let _ = writeln!(eq, "// Generated by build.rs from a host run of src/equalise_case.rs.");
    let _ = writeln!(
        eq,
        "/// The host's CRC-32 of the equalised refinement of `equalise_case`.\npub const EQUALISED_CRC: u32 = 0x{:08x};",
        equalise_case::refined_crc().unwrap()
    );
    let _ = writeln!(
        eq,
        "/// Rows of `equalise_case` the host blurred.\npub const EQUALISED_BLURRED_ROWS: usize = {blurred};"
    );
    fs::write(out.join("equalised.rs"), eq).unwrap();
    fs::write(out.join("expected.rs"), code).unwrap();
}

/// The E7 frame's part of `expected.rs`: its views (in the flash-like region, `.frame320_views`),
/// the host's digests and arena of both runs on it, and the refined digest `bino run` gives for
/// each preset (`host_frame`), which must be the workload's: one readout, one number.
fn e7_frame_code(
    code: &mut String,
    host_frame: &Path,
    (height, width): (usize, usize),
    [left, right]: [PathBuf; 2],
    runs: &[(Run, workload::Outcome); 2],
) {
    let text = fs::read_to_string(host_frame).unwrap_or_else(|e| panic!("{}: {e}", host_frame.display()));
    let recorded = host_frame::runs(&text).unwrap_or_else(|e| panic!("{}: {e}", host_frame.display()));
    let refined = OUTPUTS.iter().position(|&n| n == "refined").unwrap();
    let _ = writeln!(
        code,
        "/// The E7 frame's rows.\npub const FRAME320_HEIGHT: usize = {height};"
    );
    let _ = writeln!(
        code,
        "/// The E7 frame's columns.\npub const FRAME320_WIDTH: usize = {width};"
    );
    for (name, path) in [("LEFT", left), ("RIGHT", right)] {
        let _ = writeln!(
            code,
            "/// The E7 frame's {} view.\n#[link_section = \".frame320_views\"]\npub static FRAME320_{name}: [u8; {}] = *include_bytes!({path:?});",
            name.to_lowercase(),
            height * width
        );
    }
    for (run, o) in runs {
        let preset = match run {
            Run::Census320 => "fast",
            _ => "learned",
        };
        let Some(bino_run) = recorded.iter().find(|r| r.preset == preset) else {
            panic!("{}: no {preset} run", host_frame.display());
        };
        let bytes = workload::run_arena_bytes(*run, height, width);
        assert!(
            (bino_run.refined, bino_run.arena_bytes, bino_run.arena_used)
                == (o.digests[refined], bytes, o.report.arena_used),
            "{}: the {preset} preset's refined digest {:08x}, arena {} B, {} B used; the firmware's workload gives \
             {:08x}, {bytes} B, {} B used (one readout, one number: rewrite the file with `cargo test -p bino-host \
             --test e7_frame -- --ignored` after changing the engine)",
            host_frame.display(),
            bino_run.refined,
            bino_run.arena_bytes,
            bino_run.arena_used,
            o.digests[refined],
            o.report.arena_used
        );
        let upper = run.name().to_uppercase();
        let _ = writeln!(
            code,
            "/// `bino run`'s refined digest of the E7 frame, {preset} preset ({}).\npub const {upper}_BINO_RUN_REFINED: u32 = 0x{:08x};",
            host_frame.display(),
            bino_run.refined
        );
        write_digests(code, &upper, run.name(), o);
    }
}

/// The host's digests and arena high-water of run `pathway` as `<NAME>_DIGESTS` and
/// `<NAME>_ARENA_USED`.
fn write_digests(code: &mut String, name: &str, pathway: &str, o: &workload::Outcome) {
    let _ = writeln!(
        code,
        "/// The host's digest of each output (`workload::OUTPUTS`), {pathway} pathway."
    );
    let _ = writeln!(code, "pub const {name}_DIGESTS: [u32; {}] = [", OUTPUTS.len());
    for (output, digest) in OUTPUTS.iter().zip(o.digests) {
        let _ = writeln!(code, "    0x{digest:08x}, // {output}");
    }
    let _ = writeln!(code, "];");
    let _ = writeln!(
        code,
        "/// The host's arena high-water, {pathway} pathway.\npub const {name}_ARENA_USED: usize = {};",
        o.report.arena_used
    );
}

fn read(path: &Path) -> Vec<u8> {
    fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

fn copy(from: &Path, to: &Path) {
    fs::copy(from, to).unwrap_or_else(|e| panic!("{} -> {}: {e}", from.display(), to.display()));
}
