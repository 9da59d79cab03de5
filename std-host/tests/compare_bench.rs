//! `bino compare` and `bino bench` end to end on the random-init encoder fixture, with a blob
//! this test quantises itself (one train pair of ../shared/data). They check that the commands
//! run and write sane JSON, not how fast or how close the engines are.

use std::path::{Path, PathBuf};
use std::process::Output;
use std::sync::OnceLock;

use serde_json::Value;

mod common;
use common::{available, bino, repo, s, scratch_dir};

fn fixture_onnx() -> PathBuf {
    repo().join("tests/fixtures/encoder_random_seed0.onnx")
}

fn data_dir() -> PathBuf {
    repo().join("../shared/data")
}

fn scratch() -> PathBuf {
    scratch_dir("compare-bench")
}

fn assert_ok(out: &Output) {
    assert!(
        out.status.success(),
        "stdout: {}\nstderr: {}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

// The fixture's blob, quantised once for all tests of this file; `None` without the data.
fn blob() -> Option<&'static Path> {
    static BLOB: OnceLock<Option<PathBuf>> = OnceLock::new();
    BLOB.get_or_init(|| {
        if !available(
            &format!("data at {}", data_dir().display()),
            data_dir().join("PAIRS.tsv").is_file(),
        ) {
            return None;
        }
        let out = scratch().join("fixture_int8.bin");
        let run = bino(&[
            "quantize",
            "--onnx",
            s(&fixture_onnx()),
            "--calib",
            s(&data_dir()),
            "--calib-pairs",
            "1",
            "--max-width",
            "640",
            "--out",
            s(&out),
            // The scratch folder outlives a test run.
            "--force",
        ]);
        assert_ok(&run);
        Some(out)
    })
    .as_deref()
}

fn read_json(path: &Path) -> Value {
    let text = std::fs::read_to_string(path).unwrap();
    serde_json::from_str(&text).unwrap_or_else(|e| panic!("{} is not JSON ({e}): {text}", path.display()))
}

fn number(v: &Value, what: &str) -> f64 {
    v.as_f64().unwrap_or_else(|| panic!("{what} is not a number: {v}"))
}

#[test]
fn compare_on_two_eval_pairs_writes_sane_json() {
    let Some(blob) = blob() else {
        return;
    };
    let json = scratch().join("compare.json");
    let run = bino(&[
        "compare",
        "--onnx",
        s(&fixture_onnx()),
        "--blob",
        s(blob),
        "--data",
        s(&data_dir()),
        "--split",
        "eval",
        "--limit",
        "2",
        "--json",
        s(&json),
    ]);
    assert_ok(&run);
    let stdout = String::from_utf8_lossy(&run.stdout);
    for needle in ["descriptors", "WTA agreement", "epe (px)", "block6", "targets met"] {
        assert!(stdout.contains(needle), "table lacks {needle:?}: {stdout}");
    }
    assert!(
        String::from_utf8_lossy(&run.stderr).contains("[2/2]"),
        "no progress lines"
    );

    let v = read_json(&json);
    assert_eq!(v["tool"], "bino compare");
    assert_eq!(v["blob_sha256"].as_str().unwrap().len(), 64);
    assert_eq!(v["embed_value"], "embed", "the fixture has the `embed` output");
    let pairs = v["pairs"].as_array().unwrap();
    assert_eq!(pairs.len(), 2);
    assert_eq!(v["mean"]["pairs"], 2);
    let stages = v["stages"].as_array().unwrap();
    assert_eq!(stages.len(), 15);
    for summary in pairs.iter().chain([&v["mean"]]) {
        for stage in stages {
            let cos = number(&summary["stage_cosine"][stage.as_str().unwrap()], "stage cosine");
            assert!(cos > 0.9 && cos <= 1.0 + 1e-9, "stage {stage}: cosine {cos}");
        }
        let desc = number(&summary["descriptor_cosine"], "descriptor cosine");
        assert!(desc > 0.9 && desc <= 1.0 + 1e-9, "descriptor cosine {desc}");
        let wta = number(&summary["wta_agreement_pct"], "WTA agreement");
        assert!((0.0..=100.0).contains(&wta), "WTA agreement {wta}");
        for model in ["float", "int8"] {
            let epe = number(&summary[model]["epe"], "epe");
            assert!(epe > 0.0 && epe < 100.0, "{model} epe {epe}");
        }
        assert!(summary["head"].is_null());
    }
    let mean_epe: f64 = pairs.iter().map(|p| number(&p["int8"]["epe"], "epe")).sum::<f64>() / 2.0;
    assert!((mean_epe - number(&v["mean"]["int8"]["epe"], "epe")).abs() < 1e-9);
    let targets = v["targets"].as_array().unwrap();
    assert_eq!(targets.len(), 3);
    assert!(targets.iter().all(|t| t["pass"].is_boolean()));
}

#[test]
fn bench_runs_once_and_writes_sane_json() {
    let Some(blob) = blob() else {
        return;
    };
    let json = scratch().join("bench.json");
    let run = bino(&[
        "bench",
        "--onnx",
        s(&fixture_onnx()),
        "--blob",
        s(blob),
        "--runs",
        "1",
        "--threads",
        "2",
        "--json",
        s(&json),
    ]);
    assert_ok(&run);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(stdout.contains("tract / int8"), "{stdout}");
    let v = read_json(&json);
    assert_eq!(v["tool"], "bino bench");
    assert_eq!((v["width"].as_u64(), v["height"].as_u64()), (Some(160), Some(48)));
    assert_eq!(v["tokens"], 960);
    assert_eq!(v["macs"], 2_919_628_800u64);
    assert_eq!(v["threads"], 1);
    assert_eq!(v["debug_build"], cfg!(debug_assertions));
    for engine in ["tract_f32", "int8"] {
        assert_eq!(v[engine]["runs_s"].as_array().unwrap().len(), 1);
        let median = number(&v[engine]["median_s"], "median");
        assert!(median > 0.0 && median < 60.0, "{engine} median {median} s");
        assert!(number(&v[engine]["gmac_per_s"], "GMAC/s") > 0.0);
    }
    assert!(number(&v["tract_over_int8"], "ratio") > 0.0);
    // Every core at once: two bands a round, one round.
    let all = &v["int8_all_cores"];
    assert_eq!(all["threads"], 2);
    assert_eq!(all["rounds"]["runs_s"].as_array().unwrap().len(), 1);
    let round = number(&all["rounds"]["median_s"], "round");
    assert!((number(&all["per_band_s"], "per band") - round / 2.0).abs() < 1e-9);
    assert!(stdout.contains("int8, 2 threads at once"), "{stdout}");
}

#[test]
fn compare_refuses_the_train_split_and_bench_zero_threads() {
    let run = bino(&["compare", "--split", "train"]);
    assert!(!run.status.success());
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(
        stderr.contains("ground truth") && stderr.contains("--split eval"),
        "{stderr}"
    );

    // No threads at all is refused, before anything is loaded or timed.
    let run = bino(&["bench", "--threads", "0", "--blob", "/nonexistent/blob.bin"]);
    assert!(!run.status.success());
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(
        stderr.contains("--threads must be at least 1") && !stderr.contains("panicked"),
        "{stderr}"
    );
}
