//! One readout, one number, down to the firmware: on the firmware's embedded 48x160 band pair,
//! the learned readout each pathway of the firmware runs (export: fuse-all+lr+ref, native, the
//! board's preset: fuse-census+lr+ref) comes out of `bino run` (its `disparity.pfm`) and
//! `bino sim` (its refined rows' digest) with the CRC-32 the firmware checks its own rows
//! against: the digest `firmware-sim/build.rs` bakes in from a host run of the firmware's
//! workload (`firmware-sim/src/workload.rs`), which the Cortex-M firmwares reproduced under QEMU
//! (`firmware-sim/measured/*.json`). No QEMU here: the expected digest is computed on the host,
//! as the firmware's build does.

use std::path::{Path, PathBuf};

mod firmware;

use bino_core::crc32::Crc32;
use bino_core::pipeline::{Pathway, Refine, SlicePair};
use bino_host::demo::{DEFAULT_BLOB, DEFAULT_PENALTIES};
use bino_host::int8::pipeline_maps::{readout_options, streamed_input};
use bino_host::readout::pathway::Pathway as HostPathway;
use bino_host::readout::Readout;
use bino_host::run::{run_pair, InvalidPixels, RunOptions};
use bino_host::sim::display::DisplaySize;
use bino_host::sim::{run_sim, SimOptions};
use bino_tests::repo;
use firmware::workload::{self, OUTPUTS};
use firmware::Quiet;

const HEIGHT: usize = 48;
const WIDTH: usize = 160;

/// The firmware's band-pair run of `pathway`.
fn run_of(pathway: Pathway) -> workload::Run {
    match pathway {
        Pathway::Export => workload::Run::Export,
        Pathway::Native => workload::Run::Native,
    }
}

/// The digest the firmware checks its refined rows against on `pathway`: `build.rs`'s host run
/// of the workload.
fn expected_refined_digest(pathway: Pathway, left: &[u8], right: &[u8]) -> u32 {
    let blob = std::fs::read(repo().join("weights/bino_int8.bin")).unwrap();
    let mut arena = vec![0u8; workload::arena_bytes(HEIGHT, WIDTH)];
    let mut source = SlicePair::new(left, right, WIDTH, HEIGHT).unwrap();
    let outcome = workload::run(&blob, run_of(pathway), &mut source, &mut arena, &mut Quiet).unwrap();
    let refined = OUTPUTS.iter().position(|&n| n == "refined").unwrap();
    outcome.digests[refined]
}

/// The refined digest a QEMU run of the firmware logged for `pathway` (`scripts/firmware.sh
/// --profile --out firmware-sim/measured`).
fn measured_refined_digest(core: &str, pathway: Pathway) -> u32 {
    let path = repo().join(format!("firmware-sim/measured/{core}.json"));
    let run: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    assert_eq!(run["band"]["width"], WIDTH, "{}: the 48x160 band", path.display());
    let output = (run["outputs"].as_array().unwrap().iter())
        .find(|o| o["pathway"] == pathway.pathway() && o["name"] == "refined")
        .unwrap_or_else(|| panic!("{}: no refined output of the {pathway:?} pathway", path.display()));
    u32::from_str_radix(output["digest"].as_str().unwrap(), 16).unwrap()
}

/// CRC-32 of a pixel map in Q8 px, little-endian, row by row: the firmware's digest of its
/// refined rows. Every value must be a whole Q8 step (the core's rows, written as floats).
fn q8_digest(values: &[f32]) -> u32 {
    let mut crc = Crc32::new();
    for &v in values {
        let q8 = v * 256.0;
        assert!(
            q8.fract() == 0.0 && (0.0..=65535.0).contains(&q8),
            "{v} is not a Q8 step"
        );
        crc.update(&(q8 as u16).to_le_bytes());
    }
    crc.finish()
}

/// A binary PGM of `pixels` (`bino run` and `bino sim` read PGM).
fn write_pgm(path: &Path, pixels: &[u8]) {
    let mut bytes = format!("P5\n{WIDTH} {HEIGHT}\n255\n").into_bytes();
    bytes.extend_from_slice(pixels);
    std::fs::write(path, bytes).unwrap();
}

/// A fresh folder for one command's outputs (the commands refuse to write into a file).
fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("bino-firmware-one-number-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

#[test]
fn run_and_sim_give_the_firmware_digest_of_its_readout_on_both_pathways() {
    let assets = repo().join("firmware-sim/assets");
    let left = std::fs::read(assets.join(format!("band_{HEIGHT}x{WIDTH}_left.gray"))).unwrap();
    let right = std::fs::read(assets.join(format!("band_{HEIGHT}x{WIDTH}_right.gray"))).unwrap();
    let views = scratch("views");
    std::fs::create_dir_all(&views).unwrap();
    let (left_path, right_path) = (views.join("left.pgm"), views.join("right.pgm"));
    write_pgm(&left_path, &left);
    write_pgm(&right_path, &right);

    for pathway in [HostPathway::Export, HostPathway::Native] {
        let core = pathway.core();
        let readout: Readout = pathway.default_readout().refined(true);
        // The commands run the readout with the firmware's options and refinement.
        let (options, refine) = workload::preset(run_of(core));
        let max_cols = options.max_cols;
        let ours = readout_options(readout, pathway, max_cols, DEFAULT_PENALTIES, 1.0, WIDTH);
        assert_eq!(ours, options, "{readout}: the commands' options are the firmware's");
        let input = streamed_input(readout, pathway).expect("the firmware's readout streams");
        assert_eq!(
            Refine::for_width(input, WIDTH),
            refine,
            "{readout}: the firmware's refinement"
        );

        let expected = expected_refined_digest(core, &left, &right);
        for qemu in ["m55", "m7"] {
            assert_eq!(
                measured_refined_digest(qemu, core),
                expected,
                "{qemu} {readout}: the firmware's measured digest against the host's (re-measure after changing the engine)"
            );
        }

        let out = scratch(&format!("run-{}", pathway.name()));
        let run = RunOptions {
            left: left_path.clone(),
            right: right_path.clone(),
            profile: bino_host::data::profile::Profile::Native,
            blob: PathBuf::from(DEFAULT_BLOB),
            readout,
            pathway,
            max_cols,
            penalties: DEFAULT_PENALTIES,
            lr_max_diff: 1.0,
            invalid: InvalidPixels::Keep,
            out: out.clone(),
        };
        let report = run_pair(&run, |_| {}).unwrap();
        assert_eq!(report.output, (WIDTH, HEIGHT));
        let written = bino_host::io::pfm::load(&out.join("disparity.pfm"), "run's disparity").unwrap();
        assert_eq!((written.width, written.height), (WIDTH, HEIGHT));
        assert_eq!(
            q8_digest(&written.values),
            expected,
            "{readout}: bino run's disparity.pfm against the firmware's digest"
        );

        let sim = SimOptions {
            pair: Some((left_path.clone(), right_path.clone())),
            profile: bino_host::data::profile::Profile::Native,
            blob: PathBuf::from(DEFAULT_BLOB),
            readout,
            pathway,
            max_cols,
            penalties: DEFAULT_PENALTIES,
            lr_max_diff: 1.0,
            display: DisplaySize::QVGA,
            frames: 1,
            out: scratch(&format!("sim-{}", pathway.name())),
        };
        let report = run_sim(&sim, |_| {}).unwrap();
        assert_eq!(
            report.refined_digest,
            Some(expected),
            "{readout}: bino sim's refined rows against the firmware's digest"
        );
        let _ = std::fs::remove_dir_all(&out);
        let _ = std::fs::remove_dir_all(&sim.out);
    }
    let _ = std::fs::remove_dir_all(&views);
}

/// The E7 frame: the refined digest the Cortex-M55 firmware logged for each preset on the Alif
/// E7's 320x240 frame (its `census320` and `frame320` runs, `scripts/firmware.sh --frame320`) is
/// the one `bino run` writes for that frame and preset (`firmware-sim/measured/host-frame-320x240.json`,
/// which `std-host/tests/e7_frame.rs` holds `bino run` to), and the firmware logged the match.
#[test]
fn the_m55_refines_the_e7_frame_as_bino_run_does() {
    let read = |rel: &str| -> serde_json::Value {
        let path = repo().join(rel);
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap_or_else(|e| panic!("{rel}: {e}"))
    };
    let (m55, host) = (
        read("firmware-sim/measured/m55.json"),
        read("firmware-sim/measured/host-frame-320x240.json"),
    );
    for (run, preset) in [(workload::Run::Census320, "fast"), (workload::Run::Frame320, "learned")] {
        let recorded = (host["runs"].as_array().unwrap().iter())
            .find(|r| r["preset"] == preset)
            .unwrap()["refined"]
            .clone();
        let logged = (m55["outputs"].as_array().unwrap().iter())
            .find(|o| o["pathway"] == run.name() && o["name"] == "refined")
            .unwrap_or_else(|| {
                panic!(
                    "m55.json: no refined output of {} (measure with --frame320)",
                    run.name()
                )
            });
        assert_eq!(
            logged["digest"], recorded,
            "{preset}: the M55's refined rows against bino run's"
        );
        assert_eq!(logged["match"], true);
        let frame = &m55[run.name()];
        assert_eq!(frame["frame"], serde_json::json!({"height": 240, "width": 320}));
        assert_eq!(frame["bino_run"]["bino_run_refined"], recorded);
        assert_eq!(frame["bino_run"]["match"], true);
        let (height, width) = workload::E7_FRAME;
        assert_eq!(frame["arena_bytes"], workload::run_arena_bytes(run, height, width));
    }
}
