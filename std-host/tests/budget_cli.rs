//! `bino budget` end to end on the committed firmware measurements (`firmware-sim/measured/`,
//! written by `scripts/firmware.sh --out firmware-sim/measured --profile`).

use std::process::Command;

use serde_json::Value;

mod common;
use common::repo;

fn measured(core: &str) -> Value {
    let path = repo().join(format!("firmware-sim/measured/{core}.json"));
    serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap()
}

#[test]
fn budget_reports_the_committed_runs() {
    let out = std::env::temp_dir().join(format!("bino-budget-cli-{}", std::process::id()));
    let (json, md, png) = (out.join("budget.json"), out.join("budget.md"), out.join("budget.png"));
    let run = Command::new(env!("CARGO_BIN_EXE_bino"))
        .args(["budget", "--firmware", "firmware-sim/measured", "--json"])
        .arg(&json)
        .arg("--md")
        .arg(&md)
        .arg("--png")
        .arg(&png)
        .current_dir(repo())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{stdout}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert_eq!(
        std::fs::read_to_string(&md).unwrap(),
        stdout,
        "--md holds what was printed"
    );
    assert!(stdout.contains("not cycles"), "{stdout}");

    let report: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    for (i, core) in ["m55", "m7"].iter().enumerate() {
        let run = measured(core);
        let got = &report["cores"][i];
        assert_eq!(got["core"], *core);
        // The export band pair is every stage the plugin counted except blob loading at boot, the
        // native run's stages and the whole frames'; the native band pair is the native ones.
        let stages = run["stages"].as_array().unwrap();
        let of = |prefix: &str| -> u64 {
            stages
                .iter()
                .filter(|s| s["name"].as_str().unwrap().starts_with(prefix))
                .map(|s| s["instructions"].as_u64().unwrap())
                .sum()
        };
        let sum = |native: bool| -> u64 {
            match native {
                true => of("native_"),
                false => {
                    let frames: u64 = ["census_", "frame_", "census320_", "frame320_"].map(of).iter().sum();
                    of("") - of("native_") - frames - of("load")
                }
            }
        };
        let band_pair = sum(false);
        assert_eq!(got["band_pair_instructions"], band_pair);
        assert_eq!(got["native_band_pair_instructions"], sum(true));
        // One pass with the head's check read from it: the native band pair is the whole of it.
        let native = sum(true);
        assert!(
            (native as f64) < 0.55 * band_pair as f64,
            "{core}: the native band pair {native} against the export band pair {band_pair}"
        );
        let mhz = if *core == "m55" { 400.0 } else { 480.0 };
        let ms = got["band_pair_estimated_ms"].as_f64().unwrap();
        assert!((ms - band_pair as f64 / (mhz * 1e3)).abs() < 1e-6, "{core}: {ms} ms");
        assert_eq!(got["weights_flash_bytes"], run["elf_sections"][".weights"]["size"]);
        assert_eq!(got["arena_high_water_bytes"], run["arena_used"]);
        assert_eq!(got["outputs_bit_identical"], true, "{core}: the committed run passed");
        // The fast preset's 160x120 frame: its census_* stages as counted, at the core's clock.
        let fast = report["presets"]["frames"]
            .as_array()
            .unwrap()
            .iter()
            .find(|p| p["core"] == *core && p["preset"] == "fast" && p["source"] == "measured_frame")
            .unwrap_or_else(|| panic!("{core}: no measured fast frame"));
        assert_eq!(
            fast["frame"],
            serde_json::json!({"height": 120, "width": 160}),
            "{core}"
        );
        assert_eq!(fast["instructions"], of("census_"), "{core}");
        assert_eq!(fast["instructions"], run["census"]["frame_instructions"], "{core}");
        assert_eq!(fast["arena_bytes"], run["census"]["arena_bytes"], "{core}");
        let fps = fast["frames_per_s_ipc1"].as_f64().unwrap();
        let mhz = if *core == "m55" { 400.0 } else { 480.0 };
        assert!(
            (fps - mhz * 1e6 / of("census_") as f64).abs() < 1e-3,
            "{core}: {fps} fps"
        );
        // The learned preset's 160x120 frame: its frame_* stages as counted, in its arena.
        let learned = report["presets"]["frames"]
            .as_array()
            .unwrap()
            .iter()
            .find(|p| p["core"] == *core && p["preset"] == "learned" && p["frame"]["width"] == 160)
            .unwrap_or_else(|| panic!("{core}: no learned 160x120 frame"));
        assert_eq!(learned["source"], "measured_frame", "{core}");
        assert_eq!(learned["instructions"], of("frame_"), "{core}");
        assert_eq!(learned["instructions"], run["frame"]["frame_instructions"], "{core}");
        assert_eq!(learned["arena_bytes"], run["frame"]["arena_bytes"], "{core}");
        assert!(
            stdout.contains(&bino_host::budget::grouped(band_pair)),
            "{core}: {stdout}"
        );
        // The E7's 320x240 frame: counted where the core ran it (the M55, `--frame320`: its
        // census320_* and frame320_* stages, in their arena), scaled where it did not (the M7).
        for (preset, key) in [("fast", "census320"), ("learned", "frame320")] {
            let row = report["presets"]["frames"]
                .as_array()
                .unwrap()
                .iter()
                .find(|p| p["core"] == *core && p["preset"] == preset && p["frame"]["width"] == 320)
                .unwrap_or_else(|| panic!("{core}: no {preset} 320x240 frame"));
            if *core == "m55" {
                assert_eq!(row["source"], "measured_frame", "{core} {preset}");
                assert_eq!(row["instructions"], of(&format!("{key}_")), "{core} {preset}");
                assert_eq!(row["instructions"], run[key]["frame_instructions"], "{core} {preset}");
                assert_eq!(row["arena_bytes"], run[key]["arena_bytes"], "{core} {preset}");
            } else {
                assert_ne!(row["source"], "measured_frame", "{core} {preset}");
                assert!(run[key].is_null(), "{core}: {key}");
            }
        }
    }
    assert!(stdout.contains("Scaled, as no frame of that size was measured on that core: M7 320x240"));
    // The cycle model: per stage, modelled cycles = sum over classes and adjustments of count x
    // cost, from the run's own counts; the classes add up to the stage's instructions.
    assert!(stdout.contains("Cycle model (a model, not a measurement)"), "{stdout}");
    assert!(
        stdout.contains("M55 ms IPC 1 | M55 modelled cycles | M55 modelled ms"),
        "{stdout}"
    );
    for (i, core) in ["m55", "m7"].iter().enumerate() {
        let run = measured(core);
        let got = &report["cores"][i];
        let model = &got["cycle_model"];
        assert!(model.is_object(), "{core}: the committed run has class counts: {model}");
        let costs = model["costs"].as_object().unwrap();
        let mut band_pair = 0.0;
        // The report leaves out the stages the firmware never entered (the other pathway's).
        let entered: Vec<&Value> = run["stages"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|r| r["name"] == "load" || r["instructions"].as_u64().unwrap() > 0)
            .collect();
        assert_eq!(got["stages"].as_array().unwrap().len(), entered.len(), "{core}");
        for (s, r) in got["stages"].as_array().unwrap().iter().zip(entered) {
            assert_eq!(s["name"], r["name"], "{core}");
            let classes = r["classes"].as_object().unwrap();
            let sum: u64 = classes.values().map(|v| v.as_u64().unwrap()).sum();
            assert_eq!(sum, r["instructions"].as_u64().unwrap(), "{core} {}", r["name"]);
            let counts = classes.iter().chain(r["cycle_adjustments"].as_object().unwrap());
            let want: f64 = counts
                .map(|(k, v)| v.as_u64().unwrap() as f64 * costs[k].as_f64().unwrap())
                .sum();
            let cycles = s["modelled_cycles"].as_f64().unwrap();
            assert!((cycles - want).abs() < 1e-6, "{core} {}: {cycles} vs {want}", r["name"]);
            let mhz = if *core == "m55" { 400.0 } else { 480.0 };
            let ms = s["modelled_ms"].as_f64().unwrap();
            assert!((ms - cycles / (mhz * 1e3)).abs() < 1e-9, "{core} {}", r["name"]);
            // The model's band pair is the export pathway's.
            let name = r["name"].as_str().unwrap();
            let other_run = ["native_", "census_", "frame_", "census320_", "frame320_"]
                .iter()
                .any(|p| name.starts_with(p));
            if name != "load" && !other_run {
                band_pair += cycles;
            }
        }
        let total = model["band_pair_modelled_cycles"].as_f64().unwrap();
        assert!((total - band_pair).abs() < 1e-3, "{core}: {total} vs {band_pair}");
        assert!(
            stdout.contains(&bino_host::budget::grouped(total.round() as u64)),
            "{core}: {stdout}"
        );
    }
    // MVE exists only on the M55, so only its run counts vector instructions.
    assert!(
        report["cores"][0]["cycle_model"]["class_counts"]["mve"]
            .as_u64()
            .unwrap()
            > 0
    );
    assert_eq!(report["cores"][1]["cycle_model"]["class_counts"]["mve"], 0);

    let targets = report["targets"].as_array().unwrap();
    // Weights (the firmware's, both heads; the learned preset's, the native head only), arena,
    // then per core its band-pair instructions, the native band pair's share and its
    // refinement's share, the fast preset's frame rate on the M55, and the export ceilings.
    assert_eq!(targets.len(), 12);
    let learned_weights = targets
        .iter()
        .find(|t| t["target"].as_str().unwrap().contains("learned preset"))
        .unwrap_or_else(|| panic!("no learned preset weights target in {targets:?}"));
    assert_eq!(learned_weights["met"], true, "{learned_weights}");
    let fast = targets
        .iter()
        .find(|t| t["target"].as_str().unwrap().contains("fast preset"))
        .unwrap_or_else(|| panic!("no fast preset target in {targets:?}"));
    assert_eq!(fast["met"], true, "{fast}");
    for core in ["Cortex-M55", "Cortex-M7"] {
        let refinement = targets
            .iter()
            .find(|t| {
                let name = t["target"].as_str().unwrap();
                name.starts_with(core) && name.contains("refinement")
            })
            .unwrap_or_else(|| panic!("{core}: no refinement target in {targets:?}"));
        assert_eq!(refinement["met"], true, "{core}: {refinement}");
        let native = targets
            .iter()
            .find(|t| {
                let name = t["target"].as_str().unwrap();
                name.starts_with(core) && name.contains("native band pair")
            })
            .unwrap_or_else(|| panic!("{core}: no native pathway target in {targets:?}"));
        assert_eq!(native["met"], true, "{core}: {native}");
    }
    // Frames: 160x120 and 320x240 on both cores and pathways, and the rule's check against the
    // committed 48x32 run.
    let frames = &report["frames"];
    let estimates = frames["estimates"].as_array().unwrap();
    assert_eq!(estimates.len(), 8, "{frames}");
    for e in estimates {
        let (w, h) = (
            e["frame"]["width"].as_u64().unwrap(),
            e["frame"]["height"].as_u64().unwrap(),
        );
        assert!(matches!((w, h), (160, 120) | (320, 240)), "{e}");
        assert_eq!(e["bands"], if h == 120 { 4 } else { 7 }, "{e}");
        let want = match e["pathway"].as_str().unwrap() {
            "export" => bino_core::preset::export_arena_bytes(h as usize, w as usize),
            _ => bino_core::preset::arena_bytes(h as usize, w as usize),
        };
        assert_eq!(e["arena_bytes"], want as u64, "{e}");
        assert!(e["modelled_seconds"].as_f64().unwrap() > 0.0, "{e}");
        assert!(e["fitted_instructions"].as_u64().unwrap() > 0, "{e}");
    }
    let check = frames["scaling_check"].as_array().unwrap();
    assert_eq!(check.len(), 2, "both cores checked against firmware-sim/measured/small");
    assert!(stdout.contains("### Frames (scaled from the band pair)"), "{stdout}");
    assert!(stdout.contains("the 48x160 band pair scaled to 48x32"), "{stdout}");

    let png_bytes = std::fs::read(&png).unwrap();
    assert_eq!(&png_bytes[1..4], b"PNG");
    let _ = std::fs::remove_dir_all(&out);
}

/// `--frame` and `--clock-mhz`: one more frame at the asked clock, and one-line errors that
/// name the flag.
#[test]
fn budget_frames_take_a_size_and_a_clock() {
    let bino = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_bino"))
            .args(["budget", "--firmware", "firmware-sim/measured"])
            .args(args)
            .current_dir(repo())
            .output()
            .unwrap()
    };
    let run = bino(&["--frame", "640x480", "--clock-mhz", "200"]);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let arena = bino_host::budget::grouped(bino_core::preset::export_arena_bytes(480, 640) as u64);
    assert!(
        stdout.contains("| 640x480 | 15 | M55 at 200 MHz | export |"),
        "{stdout}"
    );
    assert!(stdout.contains(&arena), "{stdout}");
    assert!(stdout.contains("every core at 200 MHz"), "{stdout}");
    for (args, want) in [
        (["--frame", "640x"], "'--frame <WxH>': expected WxH"),
        (["--frame", "642x480"], "width 642 is not a multiple of 4"),
        (["--clock-mhz", "0"], "'--clock-mhz <F>'"),
        (["--clock-mhz", "-5"], "expected a clock above 0 MHz"),
        (["--clock-mhz", "NaN"], "expected a clock above 0 MHz"),
    ] {
        let run = bino(&args);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(!run.status.success(), "{args:?}");
        assert!(stderr.contains(want), "{args:?}: {stderr}");
        assert_eq!(stderr.lines().filter(|l| l.starts_with("error")).count(), 1, "{stderr}");
    }
}

#[test]
fn budget_without_runs_is_a_clear_error() {
    let empty = std::env::temp_dir().join(format!("bino-budget-empty-{}", std::process::id()));
    std::fs::create_dir_all(&empty).unwrap();
    let run = Command::new(env!("CARGO_BIN_EXE_bino"))
        .args(["budget", "--firmware"])
        .arg(&empty)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success());
    assert!(stderr.contains("scripts/firmware.sh"), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    let _ = std::fs::remove_dir_all(&empty);
}
