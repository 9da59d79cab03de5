//! One readout, one number (issue 13): `bino run`, `bino eval` and `bino sim` give a readout's
//! pixel disparities the same way, through the core's streaming pipeline. On a multi-band eval
//! pair (mb2005_Art at w160: 31 token rows, three bands), the EVAL.md epe of run's
//! `disparity.pfm` equals eval's per-pair epe for the same readout and options
//! (`run --readout R --refine off` is eval's `R`, `run --readout R` (refined by default) is
//! eval's `R+ref`), and for a `+ref` readout the core streams, sim's refined rows are run's,
//! bit for bit (their CRC-32). The readouts the core does not stream are host-only analysis in
//! eval (`host_only`) and in run, refused by sim. The reference: the host's whole-map
//! refinement of each streamed readout's grid equals the core's streamed rows on this pair.

use std::path::{Path, PathBuf};

use bino_core::crc32::Crc32;
use bino_core::pipeline::Refine;
use bino_host::data::pairs::read_index;
use bino_host::data::profile::Profile;
use bino_host::demo::{DEFAULT_BLOB, DEFAULT_PENALTIES};
use bino_host::eval::{load_eval_item, score, DisparityMap, EvalItem};
use bino_host::int8::pipeline_maps::{readout_options, run_census_stream, run_pipeline_refined, streamed_input};
use bino_host::int8::Int8Model;
use bino_host::readout::pathway::Pathway;
use bino_host::readout::{Method, Readout};

mod common;
use common::{bino, repo, s, scratch_dir};

/// Reads a grayscale PFM (`Pf`, little-endian, rows bottom-up) as a map.
fn read_pfm(path: &Path) -> DisparityMap {
    let bytes = std::fs::read(path).unwrap();
    let mut fields = Vec::new();
    let mut at = 0;
    while fields.len() < 4 {
        let end = at + bytes[at..].iter().position(|b| b.is_ascii_whitespace()).unwrap();
        if end > at {
            fields.push(std::str::from_utf8(&bytes[at..end]).unwrap().to_string());
        }
        at = end + 1;
    }
    assert_eq!(fields[0], "Pf");
    let (width, height): (usize, usize) = (fields[1].parse().unwrap(), fields[2].parse().unwrap());
    assert_eq!(fields[3], "-1.0", "little-endian");
    let floats: Vec<f32> = bytes[at..]
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    assert_eq!(floats.len(), width * height);
    let values = floats.chunks_exact(width).rev().flatten().copied().collect();
    DisparityMap { width, height, values }
}

#[test]
fn run_writes_what_eval_scores_on_a_multi_band_pair() {
    let readouts = [
        "nolink+lr",
        "sgm",
        "head",
        "head+lr",
        "sgm+ref",
        "head+lr+ref",
        "fuse+lr",
        "fuse+lr+ref",
    ];
    let report = run_matches_eval(Profile::W160, &readouts, &[]);
    // The refinement changes the map (and, on this pair, lowers the head's error).
    let epe = |r: &str| {
        report["per_pair"][0]["readouts"][format!("int8_{r}")]["metrics"]["epe"]
            .as_f64()
            .unwrap()
    };
    assert_ne!(epe("sgm"), epe("sgm+ref"));
    assert!(
        epe("head+lr+ref") < epe("head+lr"),
        "{} vs {}",
        epe("head+lr+ref"),
        epe("head+lr")
    );
}

/// At w320 the head searches 16 candidates in both commands (`readout::head_candidates`).
#[test]
fn run_writes_what_eval_scores_at_w320() {
    let report = run_matches_eval(Profile::W320, &["head", "head+lr+ref"], &[]);
    assert!(report["per_pair"][0]["readouts"]["int8_head"]["metrics"]["epe"].is_number());
}

/// The census readouts on the native pathway (one encoder pass; the census SGM reads the
/// pixels): `run` writes what `eval` scores, and fusing the head changes the census map.
#[test]
fn run_writes_what_eval_scores_for_the_census_readouts() {
    let readouts = ["census+lr", "fuse-census+lr", "fuse-census+lr+ref"];
    let report = run_matches_eval(Profile::W160, &readouts, &["--pathway", "native"]);
    let epe = |r: &str| {
        report["per_pair"][0]["readouts"][format!("int8_{r}")]["metrics"]["epe"]
            .as_f64()
            .unwrap()
    };
    assert_ne!(epe("census+lr"), epe("fuse-census+lr"));
}

/// The encoder-free census readouts: `run` streams them through the core's census run (no blob,
/// no encoder; `+ref` refined in the core) and writes what `eval` scores from the whole-map
/// refinement of the same grid, across the pair's three bands.
#[test]
fn run_writes_what_eval_scores_for_the_encoder_free_census() {
    let readouts = ["census", "census+lr", "census+ref", "census+lr+ref"];
    let report = run_matches_eval(Profile::W160, &readouts, &[]);
    let epe = |r: &str| {
        report["per_pair"][0]["readouts"][format!("int8_{r}")]["metrics"]["epe"]
            .as_f64()
            .unwrap()
    };
    assert_ne!(epe("census+lr"), epe("census+lr+ref"));
}

/// The three-way fusion on the export pathway: `run` writes what `eval` scores, and it differs
/// from the head fused with the SGM alone.
#[test]
fn run_writes_what_eval_scores_for_the_three_way_fusion() {
    let report = run_matches_eval(Profile::W160, &["fuse+lr", "fuse-all+lr", "fuse-all+lr+ref"], &[]);
    let epe = |r: &str| {
        report["per_pair"][0]["readouts"][format!("int8_{r}")]["metrics"]["epe"]
            .as_f64()
            .unwrap()
    };
    assert_ne!(epe("fuse+lr"), epe("fuse-all+lr"));
}

/// The guided SGM (`--sgm-edge`): its guide rows come from each band's pixel buffer in the
/// pipeline, so the three bands of this pair check the guide across band seams; and it changes
/// the map (the option is not ignored).
#[test]
fn run_writes_what_eval_scores_with_the_guided_sgm() {
    let guided = run_matches_eval(Profile::W160, &["sgm", "sgm+lr+ref"], &["--sgm-edge", "8"]);
    assert_eq!(guided["sgm_edge"], 8);
    let plain = run_matches_eval(Profile::W160, &["sgm"], &["--sgm-edge", "0"]);
    let epe = |r: &serde_json::Value| {
        r["per_pair"][0]["readouts"]["int8_sgm"]["metrics"]["epe"]
            .as_f64()
            .unwrap()
    };
    assert_ne!(epe(&guided), epe(&plain));
}

/// The host-only readouts: eval marks them, run writes what eval scores (fused and refined on
/// the whole map), sim refuses them.
#[test]
fn run_writes_what_eval_scores_for_the_host_only_readouts() {
    let report = run_matches_eval(
        Profile::W160,
        &["fuse", "fuse+ref", "fuse-census+lr+ref", "sgm+ref"],
        &[],
    );
    let row = |r: &str| &report["per_pair"][0]["readouts"][format!("int8_{r}")];
    for host in ["fuse", "fuse+ref", "fuse-census+lr+ref"] {
        assert_eq!(row(host)["host_only"], true, "{host}");
        assert_eq!(report["mean"][format!("int8_{host}")]["host_only"], true, "{host}");
    }
    assert!(row("sgm+ref").get("host_only").is_none(), "the core streams sgm+ref");
    for readout in ["fuse+ref", "fuse-census+lr+ref"] {
        let sim = bino(&[
            "sim",
            "--readout",
            readout,
            "--out",
            s(&scratch_dir("one-number-sim-refused")),
        ]);
        let stderr = String::from_utf8_lossy(&sim.stderr);
        assert!(
            !sim.status.success() && stderr.contains("bino run and bino eval only"),
            "{readout}: {stderr}"
        );
    }
}

/// The reference: for every `+ref` readout the core streams, on both pathways, the host's
/// whole-map refinement ([`bino_host::readout::MethodMaps::pixels`]) of the grid the core's
/// run gathered equals the pixel rows the core refined as it streamed, across three bands.
#[test]
fn the_whole_map_refinement_equals_the_streamed_one_on_an_eval_pair() {
    let item = eval_pair(Profile::W160);
    let model = Int8Model::load(Path::new(DEFAULT_BLOB)).unwrap();
    let width = item.left.width;
    let mut checked = 0;
    for pathway in [Pathway::Export, Pathway::Native] {
        for readout in pathway.readouts() {
            let Some(input) = streamed_input(readout, pathway).filter(|_| readout.refine) else {
                continue;
            };
            let opts = readout_options(readout, pathway, 16, DEFAULT_PENALTIES, 1.0, width);
            let maps = match readout.method {
                Method::Census => run_census_stream(&item.left, &item.right, &opts, readout).unwrap(),
                _ => {
                    let refine = Refine::for_width(input, width);
                    run_pipeline_refined(&model, &item.left, &item.right, &opts, Some(&refine), &mut |_, _| {}).unwrap()
                }
            };
            let streamed = maps.refined.expect("the core refined the readout");
            let whole_map = maps.methods.pixels(readout).unwrap();
            let differ = streamed
                .values
                .iter()
                .zip(&whole_map.values)
                .filter(|(a, b)| a != b)
                .count();
            assert_eq!(
                (differ, streamed.width, streamed.height),
                (0, whole_map.width, whole_map.height),
                "{pathway} {readout}: streamed against whole-map pixels"
            );
            checked += 1;
        }
    }
    // export: nolink, sgm, head (each unchecked and +lr), fuse+lr, fuse-all+lr, census and
    // census+lr; native: head, head+lr, census, census+lr, fuse-census+lr.
    assert_eq!(checked, 15);
}

/// mb2005_Art at `profile`: a pair of several bands.
fn eval_pair(profile: Profile) -> EvalItem {
    let data = repo().join("../shared/data");
    let record = read_index(&data)
        .unwrap()
        .into_iter()
        .find(|r| r.pair_id == "mb2005_Art")
        .expect("mb2005_Art in the eval split");
    let item = load_eval_item(&record, profile).unwrap();
    assert!(item.left.height / 4 > 12, "more than one band");
    item
}

/// CRC-32 of a pixel map in Q8 px, little-endian, row by row (what `bino sim` prints for the
/// refined rows it drew).
fn q8_digest(map: &DisparityMap) -> u32 {
    let mut crc = Crc32::new();
    for &v in &map.values {
        assert_eq!((v * 256.0).fract(), 0.0, "{v} is not a Q8 step");
        crc.update(&((v * 256.0) as u16).to_le_bytes());
    }
    crc.finish()
}

/// Runs `bino eval` on mb2005_Art at `profile` for `readouts`, then `bino run` for each, and
/// checks run's `disparity.pfm` scores eval's per-pair epe, and for a `+ref` readout the core
/// streams that `bino sim` draws run's pixels (their digest); returns eval's report.
fn run_matches_eval(profile: Profile, readouts: &[&str], extra: &[&str]) -> serde_json::Value {
    let profile_name = profile.to_string();
    let data = repo().join("../shared/data");
    let record = read_index(&data)
        .unwrap()
        .into_iter()
        .find(|r| r.pair_id == "mb2005_Art")
        .expect("mb2005_Art in the eval split");
    let item = eval_pair(profile);

    // A data folder holding only this pair (links to the shared files), for `bino eval`.
    let dir = scratch_dir(&format!("one-number-{profile_name}{}", extra.join("")));
    let link = |name: &str, target: &Path| -> PathBuf {
        let path = dir.join(name);
        let _ = std::fs::remove_file(&path);
        std::os::unix::fs::symlink(target, &path).unwrap();
        path
    };
    let gt = record.gt.as_ref().unwrap();
    link("l.png", &record.left);
    link("r.png", &record.right);
    link("gt.pgm", &gt.path);
    std::fs::write(
        dir.join("PAIRS.tsv"),
        format!(
            "pair_id\tsplit\tdataset\tleft\tright\tgt\tgt_format\tgt_scale\tgt_invalid\twidth\theight\n\
             mb2005_Art\teval\tmiddlebury2005\tl.png\tr.png\tgt.pgm\t{}\t{}\t{}\t{}\t{}\n",
            gt.format,
            gt.scale,
            gt.invalid.map_or(String::new(), |v| v.to_string()),
            record.width,
            record.height
        ),
    )
    .unwrap();
    let json = dir.join("eval.json");
    let joined = readouts.join(",");
    let mut eval_args = vec![
        "eval",
        "--data",
        s(&dir),
        "--profile",
        &profile_name,
        "--precision",
        "int8",
        "--readout",
        &joined,
        "--no-sgbm",
        "--json",
        s(&json),
    ];
    eval_args.extend(extra);
    let eval = bino(&eval_args);
    assert!(eval.status.success(), "{}", String::from_utf8_lossy(&eval.stderr));
    let report: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let max_cols = report["max_cols"].as_u64().unwrap().to_string();

    // `bino run` answers at the input's size and eval scores at the profile's: run reads the
    // pair as the profile made it (its 8-bit views, the pipeline's input) with --profile native.
    let save = |name: &str, view: &bino_host::data::profile::View| -> PathBuf {
        let path = dir.join(name);
        let pixels = bino_host::int8::to_u8(&view.pixels);
        image::GrayImage::from_raw(view.width as u32, view.height as u32, pixels)
            .unwrap()
            .save(&path)
            .unwrap();
        path
    };
    let (left, right) = (save("profiled_l.png", &item.left), save("profiled_r.png", &item.right));
    let native = "native".to_string();
    for &readout in readouts {
        let out = dir.join(format!("run-{readout}"));
        // The refined readouts by run's default, the others with --refine off.
        let (name, refine) = match readout.strip_suffix("+ref") {
            Some(base) => (base, "on"),
            None => (readout, "off"),
        };
        let mut args = vec![
            "run",
            "--left",
            s(&left),
            "--right",
            s(&right),
            "--profile",
            &native,
            "--readout",
            name,
            "--max-cols",
            &max_cols,
            "--out",
            s(&out),
        ];
        if refine == "off" {
            args.extend(["--refine", "off"]);
        }
        args.extend(extra);
        let run = bino(&args);
        assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
        let stdout = String::from_utf8_lossy(&run.stdout);
        assert!(stdout.contains(&format!("bino run: {readout} readout")), "{stdout}");
        let written = read_pfm(&out.join("disparity.pfm"));
        assert!(written.values.iter().all(|v| v.is_finite()), "{readout}: a dense map");
        let run_epe = score(&written, &item.gt).unwrap().epe;
        let eval_epe = report["per_pair"][0]["readouts"][format!("int8_{readout}")]["metrics"]["epe"]
            .as_f64()
            .unwrap();
        assert!(
            (run_epe - eval_epe).abs() < 1e-9,
            "{readout}: run {run_epe} vs eval {eval_epe}"
        );
        let parsed: Readout = readout.parse().unwrap();
        let pathway = match extra.windows(2).any(|w| w == ["--pathway", "native"]) {
            true => Pathway::Native,
            false => Pathway::Export,
        };
        if parsed.refine && streamed_input(parsed, pathway).is_some() {
            // sim draws the refined rows as the core streams them: run's, bit for bit.
            let sim_out = dir.join(format!("sim-{readout}"));
            let mut args = vec!["sim", "--left", s(&left), "--right", s(&right), "--profile", &native];
            args.extend(["--readout", readout, "--max-cols", &max_cols, "--out", s(&sim_out)]);
            args.extend(extra);
            let sim = bino(&args);
            assert!(sim.status.success(), "{}", String::from_utf8_lossy(&sim.stderr));
            let stdout = String::from_utf8_lossy(&sim.stdout);
            let digest = format!("refined rows digest {:08x}", q8_digest(&written));
            assert!(
                stdout.contains(&digest),
                "{readout}: sim against run's {digest}: {stdout}"
            );
        }
    }
    report
}
