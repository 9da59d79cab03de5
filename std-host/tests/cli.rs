//! The `bino` binary end to end: good input gives the documented archive, every bad input a
//! clear error naming the file, a non-zero exit and no panic.

use std::path::{Path, PathBuf};
use std::process::Output;

use bino_host::io::npz;

mod common;
use common::{bino, bino_in, repo, s, scratch_dir};

fn random_onnx() -> PathBuf {
    repo().join("tests/fixtures/encoder_random_seed0.onnx")
}

fn scratch(name: &str) -> PathBuf {
    scratch_dir(&format!("cli-{name}"))
}

fn assert_fails_with(out: &Output, needles: &[&str]) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "expected failure, stderr: {stderr}");
    assert!(!stderr.contains("panicked"), "must not panic: {stderr}");
    for needle in needles {
        assert!(stderr.contains(needle), "stderr lacks {needle:?}: {stderr}");
    }
}

fn write_png(path: &Path, width: u32, height: u32) {
    image::GrayImage::from_fn(width, height, |x, y| image::Luma([((x * 7 + y * 13) % 256) as u8]))
        .save(path)
        .unwrap();
}

/// `bino reference` with `flags` on `dir`'s `l.png` / `r.png` (random encoder) into `o.npz`.
fn reference_on_pair(dir: &Path, flags: &[&str]) -> Output {
    let (left, right, out) = (dir.join("l.png"), dir.join("r.png"), dir.join("o.npz"));
    let mut args = vec!["reference"];
    args.extend_from_slice(flags);
    let onnx = random_onnx();
    args.extend_from_slice(&[
        "--left",
        s(&left),
        "--right",
        s(&right),
        "--onnx",
        s(&onnx),
        "--out",
        s(&out),
    ]);
    bino(&args)
}

#[test]
fn reference_on_builtin_scene_writes_documented_arrays() {
    let dir = scratch("builtin");
    let out = dir.join("ref.npz");
    let run = bino(&["reference", "--onnx", s(&random_onnx()), "--out", s(&out)]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let arrays = npz::read(&std::fs::read(&out).unwrap()).unwrap();
    let shapes: Vec<(&str, &[usize])> = arrays.iter().map(|(n, a)| (n.as_str(), a.shape.as_slice())).collect();
    assert_eq!(
        shapes,
        [
            ("left", &[96, 160][..]),
            ("right", &[96, 160][..]),
            ("tokens", &[24, 80, 128][..]),
            ("desc_left", &[24, 40, 128][..]),
            ("desc_right", &[24, 40, 128][..]),
        ]
    );
    assert!(!dir.join("ref.npz.partial").exists());
}

#[test]
fn reference_runs_on_a_real_pair_at_w160() {
    let data = repo().join("../shared/data");
    let left = data.join("middlebury-2001-2003/scenes2001/barn1/im2.ppm");
    let right = data.join("middlebury-2001-2003/scenes2001/barn1/im6.ppm");
    let out = scratch("real").join("barn1.npz");
    let run = bino(&[
        "reference",
        "--left",
        s(&left),
        "--right",
        s(&right),
        "--onnx",
        s(&random_onnx()),
        "--out",
        s(&out),
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let arrays = npz::read(&std::fs::read(&out).unwrap()).unwrap();
    // 432x381 -> 160 x round(141.1) -> 140 rows: 35 token rows, 40 patch columns.
    assert_eq!(arrays[2].1.shape, [35, 80, 128]);
    assert_eq!(arrays[3].1.shape, [35, 40, 128]);
}

#[test]
fn missing_image_is_named() {
    let dir = scratch("missing");
    write_png(&dir.join("r.png"), 64, 48);
    let run = reference_on_pair(&dir, &[]);
    assert_fails_with(&run, &["l.png", "does not exist"]);
    assert!(!dir.join("o.npz").exists());
}

#[test]
fn unreadable_image_is_named() {
    let dir = scratch("garbage");
    std::fs::write(dir.join("l.png"), b"\x89PNG but truncated").unwrap();
    write_png(&dir.join("r.png"), 64, 48);
    let run = reference_on_pair(&dir, &[]);
    assert_fails_with(&run, &["l.png", "cannot decode"]);
}

#[test]
fn mismatched_pair_is_refused() {
    let dir = scratch("mismatch");
    write_png(&dir.join("l.png"), 64, 48);
    write_png(&dir.join("r.png"), 68, 48);
    let run = reference_on_pair(&dir, &[]);
    assert_fails_with(&run, &["l.png", "64x48", "68x48"]);
}

#[test]
fn size_off_the_profile_is_refused() {
    let dir = scratch("profile");
    write_png(&dir.join("l.png"), 66, 50);
    write_png(&dir.join("r.png"), 66, 50);
    let run = reference_on_pair(&dir, &["--profile", "native"]);
    assert_fails_with(&run, &["l.png", "66x50", "multiples of 4"]);
    // A sliver leaves no 4-row band at width 160.
    write_png(&dir.join("l.png"), 640, 3);
    write_png(&dir.join("r.png"), 640, 3);
    let run = reference_on_pair(&dir, &[]);
    assert_fails_with(&run, &["640x3", "w160"]);
}

#[test]
fn missing_onnx_is_named() {
    let dir = scratch("onnx");
    let run = bino(&[
        "reference",
        "--onnx",
        s(&dir.join("absent.onnx")),
        "--out",
        s(&dir.join("o.npz")),
    ]);
    assert_fails_with(&run, &["absent.onnx", "does not exist"]);
    std::fs::write(dir.join("broken.onnx"), b"not protobuf at all").unwrap();
    let run = bino(&[
        "reference",
        "--onnx",
        s(&dir.join("broken.onnx")),
        "--out",
        s(&dir.join("o.npz")),
    ]);
    assert_fails_with(&run, &["broken.onnx"]);
}

#[test]
fn pairs_lists_the_eval_split() {
    let run = bino(&["pairs", "--data", "../shared/data", "--split", "eval"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert_eq!(stdout.lines().count(), 16, "EVAL.md: 16 eval pairs");
    assert!(stdout.lines().all(|l| l.split('\t').nth(1) == Some("eval")));
    assert_fails_with(&bino(&["pairs", "--data", "/nonexistent-dir"]), &["nonexistent-dir"]);
}

#[test]
fn run_writes_disparity_pfm_and_mask() {
    let dir = scratch("run");
    let (left, right) = (dir.join("l.png"), dir.join("r.png"));
    write_png(&left, 200, 60);
    write_png(&right, 200, 60);
    let out = dir.join("out");
    let run = bino(&[
        "run",
        "--left",
        s(&left),
        "--right",
        s(&right),
        "--profile",
        "w160",
        "--out",
        s(&out),
    ]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let stdout = String::from_utf8_lossy(&run.stdout);
    // Computed at w160 (200x60 -> 160x48), answered at the input's size.
    assert!(
        stdout.contains("computed at 160x48 (w160), written at 200x60") && stdout.contains("% of pixels valid"),
        "{stdout}"
    );
    let mask = image::open(out.join("valid.png")).unwrap();
    assert_eq!((mask.width(), mask.height()), (200, 60));
    let pfm = std::fs::read(out.join("disparity.pfm")).unwrap();
    assert!(pfm.starts_with(b"Pf\n200 60\n-1.0\n"));
    assert_eq!(pfm.len(), b"Pf\n200 60\n-1.0\n".len() + 200 * 60 * 4);
    // The picture carries its colour bar below the map.
    let png = image::open(out.join("disparity.png")).unwrap();
    assert_eq!(png.width(), 200);
    assert!(png.height() > 60, "{}", png.height());
}

/// `--kernels` and `--threads` change the time, never the answer: the native pathway's PFM on a
/// two-band pair is the same bytes with the fastest kernels on every core, with AVX2 on one
/// thread and with the portable kernels.
#[test]
fn kernels_and_threads_give_the_same_answer() {
    let dir = scratch("kernels");
    let (left, right) = (dir.join("l.png"), dir.join("r.png"));
    write_png(&left, 160, 72);
    write_png(&right, 160, 72);
    let mut answers = Vec::new();
    for (i, flags) in [
        ["--kernels", "fastest", "--threads", "2"],
        ["--kernels", "avx2", "--threads", "1"],
        ["--kernels", "portable", "--threads", "2"],
    ]
    .iter()
    .enumerate()
    {
        let out = dir.join(format!("out{i}"));
        let mut args = vec![
            "run",
            "--left",
            s(&left),
            "--right",
            s(&right),
            "--profile",
            "native",
            "--pathway",
            "native",
            "--out",
            s(&out),
        ];
        args.extend_from_slice(flags);
        let run = bino(&args);
        assert!(
            run.status.success(),
            "{flags:?}: {}",
            String::from_utf8_lossy(&run.stderr)
        );
        answers.push(std::fs::read(out.join("disparity.pfm")).unwrap());
    }
    assert!(answers[1] == answers[0] && answers[2] == answers[0], "the PFMs differ");
}

/// A flat identical pair has nothing to match: the answer says so (almost every pixel invalid,
/// infinite with `--invalid inf`), and a tiny image upscaled to the profile gets a warning.
#[test]
fn a_flat_pair_is_mostly_invalid_and_a_tiny_one_is_warned_about() {
    let dir = scratch("run-flat");
    let (left, right) = (dir.join("l.png"), dir.join("r.png"));
    for path in [&left, &right] {
        image::GrayImage::from_pixel(320, 96, image::Luma([128]))
            .save(path)
            .unwrap();
    }
    for pathway in [&[][..], &["--pathway", "native"]] {
        let out = dir.join(format!("out{}", pathway.len()));
        let mut args = vec![
            "run",
            "--left",
            s(&left),
            "--right",
            s(&right),
            "--invalid",
            "inf",
            "--out",
            s(&out),
        ];
        args.extend(pathway);
        let run = bino(&args);
        assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
        let pfm = bino_host::io::pfm::load(&out.join("disparity.pfm"), "disparity").unwrap();
        let invalid = pfm.values.iter().filter(|v| v.is_infinite()).count();
        assert!(
            invalid * 10 >= pfm.values.len() * 9,
            "{pathway:?}: {invalid} of {} invalid",
            pfm.values.len()
        );
        let mask = image::open(out.join("valid.png")).unwrap().to_luma8();
        let zeros = mask.pixels().filter(|p| p.0[0] == 0).count();
        assert_eq!(zeros, invalid, "{pathway:?}: the mask and the PFM agree");
    }
    let (tiny_l, tiny_r) = (dir.join("tl.png"), dir.join("tr.png"));
    write_png(&tiny_l, 8, 8);
    write_png(&tiny_r, 8, 8);
    let run = bino(&[
        "run",
        "--left",
        s(&tiny_l),
        "--right",
        s(&tiny_r),
        "--out",
        s(&dir.join("tiny")),
    ]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{stderr}");
    assert!(stderr.contains("warning: the 8x8 input is upscaled 40.0x"), "{stderr}");
    assert!(stderr.contains("shorter than one 48-row band"), "{stderr}");
    let pfm = bino_host::io::pfm::load(&dir.join("tiny/disparity.pfm"), "disparity").unwrap();
    assert_eq!((pfm.width, pfm.height), (8, 8));
}

#[test]
fn run_refuses_views_of_different_sizes() {
    let dir = scratch("run-mismatch");
    let (left, right) = (dir.join("l.png"), dir.join("r.png"));
    write_png(&left, 200, 60);
    write_png(&right, 200, 64);
    let run = bino(&[
        "run",
        "--left",
        s(&left),
        "--right",
        s(&right),
        "--out",
        s(&dir.join("out")),
    ]);
    assert_fails_with(&run, &["differ in size", "l.png", "r.png"]);
    assert!(!dir.join("out").exists(), "nothing is written on bad input");
}

/// `--out` naming a file is refused before anything is loaded or computed, naming it.
#[test]
fn run_and_sim_refuse_an_output_that_is_a_file_before_any_work() {
    let dir = scratch("out-is-a-file");
    let (left, right) = (dir.join("l.png"), dir.join("r.png"));
    write_png(&left, 200, 60);
    write_png(&right, 200, 60);
    let taken = dir.join("taken.txt");
    std::fs::write(&taken, b"keep me").unwrap();
    for verb in ["run", "sim"] {
        let started = std::time::Instant::now();
        let out = bino(&[verb, "--left", s(&left), "--right", s(&right), "--out", s(&taken)]);
        assert_fails_with(&out, &["--out", "taken.txt", "is a file, not a folder"]);
        // Refused before the pipeline: the blob is not even loaded (a run takes seconds).
        assert!(started.elapsed().as_secs_f64() < 5.0, "{verb}: {:?}", started.elapsed());
        assert_eq!(std::fs::read(&taken).unwrap(), b"keep me", "{verb}");
    }
}

/// `bino --version` names the command users type; `quantize` never replaces an existing blob
/// (by default the shipped one) without `--force`, and says so before calibrating.
#[test]
fn version_names_bino_and_quantize_keeps_an_existing_blob() {
    let version = bino(&["--version"]);
    assert!(version.status.success());
    let stdout = String::from_utf8_lossy(&version.stdout);
    assert!(stdout.starts_with("bino 0."), "{stdout}");
    let dir = scratch("quantize-keep");
    let blob = dir.join("blob.bin");
    std::fs::write(&blob, b"not replaced").unwrap();
    let out = bino(&["quantize", "--onnx", s(&random_onnx()), "--out", s(&blob)]);
    assert_fails_with(&out, &["--out", "blob.bin", "exists", "--force"]);
    assert_eq!(std::fs::read(&blob).unwrap(), b"not replaced");
    let default = bino(&["quantize", "--onnx", s(&random_onnx())]);
    assert_fails_with(&default, &["bino_int8.bin", "exists", "--force"]);
}

/// `--refine off` writes the readout's token grid upsampled bilinearly, the formula `bino run`
/// used before the refinement existed; the default writes the readout's `+ref`, the core's
/// refinement of the same grid on the same 8-bit views. The mask is the method's either way.
#[test]
fn run_refine_off_is_the_upsampled_grid_and_the_default_its_refinement() {
    use bino_core::pipeline::Options;
    use bino_host::data::profile::{load_profiled_pair, Profile};
    use bino_host::eval::upsample_disparity;
    use bino_host::int8::pipeline_maps::run_pipeline;
    use bino_host::int8::Int8Model;
    use bino_host::readout::refine::{refine_pixels, GrayViews};
    use bino_host::readout::{Method, Readout};
    use bino_host::run::pfm_bytes;

    let dir = scratch("refine");
    let scene = bino_host::data::synthetic::default_scene(160, 48);
    let (left, right) = (dir.join("l.png"), dir.join("r.png"));
    for (view, path) in [(&scene.left, &left), (&scene.right, &right)] {
        image::GrayImage::from_raw(view.width as u32, view.height as u32, view.pixels.clone())
            .unwrap()
            .save(path)
            .unwrap();
    }
    let run = |out: &Path, extra: &[&str]| {
        let mut args = vec!["run", "--left", s(&left), "--right", s(&right), "--profile", "native"];
        args.extend(["--readout", "sgm+lr", "--out", s(out)]);
        args.extend(extra);
        let run = bino(&args);
        assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
        String::from_utf8_lossy(&run.stdout).into_owned()
    };
    let (on, off) = (dir.join("on"), dir.join("off"));
    assert!(run(&on, &[]).contains("bino run: sgm+lr+ref readout"));
    assert!(run(&off, &["--refine", "off"]).contains("bino run: sgm+lr readout"));

    // The same pipeline through the library, with run's defaults.
    let (l, r) = load_profiled_pair(&left, &right, Profile::Native).unwrap();
    let model = Int8Model::load(Path::new(bino_host::demo::DEFAULT_BLOB)).unwrap();
    let opts = Options {
        pathway: bino_core::pipeline::Pathway::Export,
        max_cols: 16,
        penalties: bino_host::demo::DEFAULT_PENALTIES,
        lr_max_diff_q8: 256,
        head: false,
        head_lr: false,
        head_candidates: bino_core::config::HEAD_MAX_DISP,
    };
    let maps = run_pipeline(&model, &l, &r, &opts, &mut |_, _| {}).unwrap().methods;
    let tokens = maps.tokens(Readout::new(Method::Sgm, true)).unwrap();
    let pfm = |dir: &Path| std::fs::read(dir.join("disparity.pfm")).unwrap();
    assert!(
        pfm(&off) == pfm_bytes(&upsample_disparity(&tokens)),
        "--refine off: the old output"
    );
    let kept = &maps.sgm_consistent;
    let refined = refine_pixels(&tokens, &GrayViews::from_views(&l, &r).unwrap(), Some(kept)).unwrap();
    assert!(
        pfm(&on) == pfm_bytes(&refined),
        "default: the refinement, rejected cells kept"
    );
    assert!(pfm(&on) != pfm(&off));
    let mask = |dir: &Path| std::fs::read(dir.join("valid.png")).unwrap();
    assert!(mask(&on) == mask(&off), "the method's mask either way");
}

/// A 200x60 textured pair, the right view the left shifted by 8 px, with its ground truth.
fn shifted_pair_folder(name: &str) -> PathBuf {
    let dir = scratch(name);
    let texture = |x: u32, y: u32| -> u8 {
        let h = (x.wrapping_mul(2_654_435_761) ^ y.wrapping_mul(40_503)).wrapping_mul(2_246_822_519);
        (h >> 24) as u8 / 2 + ((x / 3 + y / 2) % 2) as u8 * 100
    };
    image::GrayImage::from_fn(200, 60, |x, y| image::Luma([texture(x, y)]))
        .save(dir.join("l.png"))
        .unwrap();
    image::GrayImage::from_fn(200, 60, |x, y| image::Luma([texture(x + 8, y)]))
        .save(dir.join("r.png"))
        .unwrap();
    // png_u8 with scale 4: 32 means 8 px.
    image::GrayImage::from_pixel(200, 60, image::Luma([32]))
        .save(dir.join("gt.png"))
        .unwrap();
    std::fs::write(
        dir.join("PAIRS.tsv"),
        "pair_id\tsplit\tdataset\tleft\tright\tgt\tgt_format\tgt_scale\tgt_invalid\twidth\theight\n\
         p\teval\tsynthetic\tl.png\tr.png\tgt.png\tpng_u8\t4\t0\t200\t60\n",
    )
    .unwrap();
    dir
}

#[test]
fn eval_reports_every_readout_and_sgbm_clean_and_under_each_nuisance_reproducibly() {
    let dir = shifted_pair_folder("nuisance");
    // StereoSGBM where the project's Python environment is there (as the other eval tests).
    let sgbm = common::available(
        "the Python environment for StereoSGBM",
        bino_host::eval::sgbm::SgbmRunner::locate().is_ok(),
    );
    let readouts = ["nolink", "sgm+lr+ref", "head+lr+ref"];
    let nuisances = ["gain", "gamma", "noise", "blur", "occlude"];
    let eval = |json: &Path| {
        let readout = readouts.join(",");
        let nuisance = nuisances.join(",");
        let mut args = vec![
            "eval",
            "--data",
            s(&dir),
            "--precision",
            "int8",
            "--readout",
            &readout,
            "--nuisance",
            &nuisance,
            "--seed",
            "7",
            "--json",
            s(json),
        ];
        if !sgbm {
            args.push("--no-sgbm");
        }
        let run = bino(&args);
        assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
        let stdout = String::from_utf8_lossy(&run.stdout).to_string();
        let text = std::fs::read_to_string(json).unwrap();
        (stdout, text)
    };
    let (stdout, first) = eval(&dir.join("a.json"));
    assert!(stdout.contains("robust accuracy"), "{stdout}");
    for n in nuisances {
        assert!(stdout.contains(n), "table lacks {n}: {stdout}");
    }
    let v: serde_json::Value = serde_json::from_str(&first).unwrap();
    assert_eq!(v["seed"], 7);
    let epe = |section: &serde_json::Value, key: &str| -> f64 {
        let m = if key == "sgbm" {
            &section[key]
        } else {
            &section[key]["metrics"]
        };
        m["epe"]
            .as_f64()
            .unwrap_or_else(|| panic!("{key}: no epe in {section}"))
    };
    let mut keys: Vec<String> = readouts.iter().map(|r| format!("int8_{r}")).collect();
    if sgbm {
        keys.push("sgbm".into());
    }
    let names: Vec<&str> = v["nuisances"].as_object().unwrap().keys().map(|k| k.as_str()).collect();
    let mut sorted = nuisances.to_vec();
    sorted.sort();
    assert_eq!(names, sorted, "one section per nuisance");
    for key in &keys {
        let clean = epe(&v["mean"], key);
        assert!(clean.is_finite() && clean >= 0.0, "{key} clean epe {clean}");
        for n in nuisances {
            let section = &v["nuisances"][n];
            let under = epe(&section["mean"], key);
            assert!(under.is_finite() && under >= 0.0, "{key} under {n}: {under}");
            let rise = section["epe_rise"][key].as_f64().unwrap();
            assert!((rise - (under - clean)).abs() < 1e-9, "{key} under {n}: rise {rise}");
            assert_eq!(
                epe(&section["per_pair"][0]["readouts"], key),
                under,
                "one pair: mean = pair"
            );
            if sgbm && key != "sgbm" {
                assert!(section["rise_below_sgbm"][key].is_boolean());
            }
        }
    }
    // Occlusion of a fifth of the right view must cost something.
    assert!(epe(&v["nuisances"]["occlude"]["mean"], "int8_nolink") > epe(&v["mean"], "int8_nolink"));
    // Seeded: a second run gives the same numbers (only the timings may differ).
    let (_, second) = eval(&dir.join("b.json"));
    let numbers = |text: &str| -> serde_json::Value {
        let mut v: serde_json::Value = serde_json::from_str(text).unwrap();
        fn strip(v: &mut serde_json::Value) {
            match v {
                serde_json::Value::Object(map) => {
                    map.remove("seconds");
                    map.values_mut().for_each(strip);
                }
                serde_json::Value::Array(items) => items.iter_mut().for_each(strip),
                _ => {}
            }
        }
        strip(&mut v);
        v
    };
    assert_eq!(numbers(&first), numbers(&second));
}

#[test]
fn eval_scores_the_one_view_occlusion_benchmark_and_the_large_disparity_subset() {
    let dir = shifted_pair_folder("occlusion");
    let json = dir.join("occ.json");
    let run = bino(&[
        "eval",
        "--data",
        s(&dir),
        "--precision",
        "int8",
        "--readout",
        "nolink,sgm+lr+ref",
        "--no-sgbm",
        "--occlude",
        "10,40",
        "--json",
        s(&json),
    ]);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    for needle in ["one-view occlusion", "occ10", "occ40", "OccAUC", "delta40", "large epe"] {
        assert!(stdout.contains(needle), "table lacks {needle}: {stdout}");
    }
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let occ = &v["occlusion"];
    assert_eq!(occ["severities"], serde_json::json!([10, 40]));
    for key in ["int8_nolink", "int8_sgm+lr+ref"] {
        let row = &occ["summary"][key];
        let epe = |m: &serde_json::Value| m["epe"].as_f64().unwrap();
        let (clean, curve) = (
            epe(&row["clean"]),
            [epe(&row["severities"][0]), epe(&row["severities"][1])],
        );
        assert_eq!(clean, epe(&v["mean"][key]["metrics"]), "{key}: clean is the clean run");
        for (i, severity) in ["10", "40"].iter().enumerate() {
            assert_eq!(curve[i], epe(&occ["per_severity"][severity]["mean"][key]["metrics"]));
        }
        assert!((row["auc_epe"].as_f64().unwrap() - (curve[0] + curve[1]) / 2.0).abs() < 1e-9);
        assert!((row["delta_epe"].as_f64().unwrap() - (curve[1] - clean)).abs() < 1e-9);
        // The ground truth is 8 px everywhere: its top quartile is every pixel.
        assert_eq!(v["mean"][key]["large"], v["mean"][key]["metrics"], "{key}");
    }
    // Covering 40 % of the right view costs the no-linkage readout something.
    assert!(occ["summary"]["int8_nolink"]["delta_epe"].as_f64().unwrap() > 0.0);

    for (bad, why) in [("0", "from 1 to 90"), ("40,10", "must rise")] {
        let out = bino(&["eval", "--data", s(&dir), "--no-sgbm", "--occlude", bad]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(1), "{stderr}");
        assert!(stderr.contains(why), "--occlude {bad}: {stderr}");
    }
}

#[test]
fn unknown_or_repeated_nuisances_are_refused() {
    let out = bino(&["eval", "--nuisance", "gain,fog"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("fog") && stderr.contains("occlude"), "{stderr}");
    let dir = shifted_pair_folder("nuisance-twice");
    let out = bino(&[
        "eval",
        "--data",
        s(&dir),
        "--precision",
        "int8",
        "--readout",
        "nolink",
        "--no-sgbm",
        "--nuisance",
        "blur,blur",
    ]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && stderr.contains("given twice"), "{stderr}");
}

/// `bino --help`: one short line per verb, nothing that points inside the project, the developer
/// verbs labelled and listed after the user's.
#[test]
fn help_lists_each_verb_on_one_short_public_line_developer_verbs_last() {
    let run = bino(&["--help"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let help = String::from_utf8_lossy(&run.stdout);
    for line in help.lines() {
        assert!(line.len() <= 100, "{} chars: {line}", line.len());
        for word in ["EVAL.md", "paper", "issue", "session", "::"] {
            assert!(!line.contains(word), "cites {word:?}: {line}");
        }
    }
    let verbs: Vec<(&str, &str)> = help
        .lines()
        .skip_while(|l| !l.starts_with("Commands:"))
        .skip(1)
        .take_while(|l| l.starts_with("  "))
        .filter_map(|l| l.trim().split_once(' '))
        .map(|(verb, about)| (verb, about.trim()))
        .filter(|(verb, _)| *verb != "help")
        .collect();
    let names: Vec<&str> = verbs.iter().map(|(v, _)| *v).collect();
    assert_eq!(
        names,
        [
            "demo",
            "run",
            "sim",
            "eval",
            "bench",
            "budget",
            "reference",
            "pairs",
            "compare",
            "describe",
            "quantize"
        ]
    );
    for (verb, about) in &verbs {
        let developer = ["reference", "pairs", "compare", "describe", "quantize"].contains(verb);
        assert_eq!(about.starts_with("(developer)"), developer, "{verb}: {about}");
    }
}

/// `--threads 0` is refused with a one-line error naming the flag, before anything runs: `bino
/// run` as a usage error (exit 2), before the images are read.
#[test]
fn zero_threads_are_refused() {
    let run = bino(&[
        "run",
        "--left",
        "/nonexistent/l.png",
        "--right",
        "/nonexistent/r.png",
        "--threads",
        "0",
    ]);
    assert_eq!(run.status.code(), Some(2), "run --threads 0");
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(
        stderr.contains("--threads must be at least 1") && !stderr.contains("nonexistent"),
        "{stderr}"
    );
}

/// The default blob is the checkout's, found from any working directory (here a scratch folder,
/// where a relative `weights/bino_int8.bin` does not exist); a relative path given on the
/// command line is relative to the current directory.
#[test]
fn default_weights_resolve_from_another_working_directory() {
    let data = shifted_pair_folder("elsewhere");
    let cwd = scratch("elsewhere-cwd");
    assert!(!cwd.join("weights/bino_int8.bin").exists());
    let eval = |extra: &[&str]| {
        let mut args = vec![
            "eval",
            "--data",
            s(&data),
            "--precision",
            "int8",
            "--readout",
            "nolink",
            "--no-sgbm",
        ];
        args.extend_from_slice(extra);
        bino_in(&cwd, &args)
    };
    let run = eval(&[]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    // An explicit relative path is taken from the current directory, not the checkout.
    assert_fails_with(&eval(&["--blob", "weights/bino_int8.bin"]), &["weights/bino_int8.bin"]);
    std::fs::create_dir_all(cwd.join("weights")).unwrap();
    std::fs::copy(repo().join("weights/bino_int8.bin"), cwd.join("weights/bino_int8.bin")).unwrap();
    let run = eval(&["--blob", "weights/bino_int8.bin"]);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
}

#[test]
fn describe_writes_the_engines_maps_and_names_bad_crops() {
    use bino_host::io::npy::{self, Array};
    let dir = scratch("describe");
    let crops = dir.join("crops.npy");
    let pixels = (0..2 * 48 * 160).map(|i| ((i * 37) % 251) as f32 / 255.0).collect();
    std::fs::write(&crops, npy::encode(&Array::new(vec![1, 2, 48, 160], pixels).unwrap())).unwrap();
    let out = dir.join("maps.npy");
    for pathway in ["export", "native"] {
        let run = bino(&["describe", "--crops", s(&crops), "--pathway", pathway, "--out", s(&out)]);
        assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
        let maps = npy::decode(&std::fs::read(&out).unwrap()).unwrap();
        assert_eq!(maps.shape, [1, 2, 12, 40, 128], "{pathway}");
        assert!(maps.data.iter().any(|&v| v != 0.0), "{pathway}: all-zero maps");
    }

    let odd = dir.join("odd.npy");
    std::fs::write(
        &odd,
        npy::encode(&Array::new(vec![1, 2, 47, 160], vec![0.5; 2 * 47 * 160]).unwrap()),
    )
    .unwrap();
    let run = bino(&["describe", "--crops", s(&odd), "--out", s(&out)]);
    assert_fails_with(&run, &["odd.npy", "47"]);
    let flat = dir.join("flat.npy");
    std::fs::write(
        &flat,
        npy::encode(&Array::new(vec![48, 160], vec![0.5; 48 * 160]).unwrap()),
    )
    .unwrap();
    let run = bino(&["describe", "--crops", s(&flat), "--out", s(&out)]);
    assert_fails_with(&run, &["flat.npy", "(N, 2, H, W)"]);
}
