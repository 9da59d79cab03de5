//! Hostile files at the command line (issue 12): decompression bombs, truncated and empty
//! images, directories and FIFOs where files belong, malformed pair indexes, ground truth of
//! the wrong size, an output folder that cannot be made. Each must end the command with one
//! line on stderr naming the file and the problem, exit code 1 (2 for a usage error), no
//! panic, and no output left behind.

use std::path::{Path, PathBuf};
use std::process::Output;

mod common;
use common::{bino, s, scratch_dir};

/// A fresh, empty scratch folder for one test.
fn scratch(name: &str) -> PathBuf {
    let dir = scratch_dir(&format!("hostile-{name}"));
    std::fs::remove_dir_all(&dir).unwrap();
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Exit code 1, one stderr line starting with `error:` holding every needle, no panic.
fn assert_refused(out: &Output, needles: &[&str]) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "exit code; stderr: {stderr}");
    let lines: Vec<&str> = stderr.lines().filter(|l| !l.trim().is_empty()).collect();
    let error_lines: Vec<&&str> = lines.iter().filter(|l| l.starts_with("error:")).collect();
    assert_eq!(error_lines.len(), 1, "one error line: {stderr}");
    let line = error_lines[0];
    assert!(!stderr.contains("panicked"), "must not panic: {stderr}");
    for needle in needles {
        assert!(line.contains(needle), "error line lacks {needle:?}: {line}");
    }
}

fn write_png(path: &Path, width: u32, height: u32) {
    image::GrayImage::from_fn(width, height, |x, y| image::Luma([((x * 7 + y * 13) % 256) as u8]))
        .save(path)
        .unwrap();
}

/// `bino run` on (left, right) into `out`, on the small profile.
fn run(left: &Path, right: &Path, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec![
        "run",
        "--left",
        s(left),
        "--right",
        s(right),
        "--profile",
        "w160",
        "--readout",
        "nolink",
        "--out",
        s(out),
    ];
    args.extend_from_slice(extra);
    bino(&args)
}

/// The whole contents of `dir`, to show nothing new appeared.
fn listing(dir: &Path) -> Vec<PathBuf> {
    let mut all: Vec<PathBuf> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).collect();
    all.sort();
    all
}

/// A PNG whose header declares `width x height` pixels, followed by a few bytes of data.
fn png_declaring(width: u32, height: u32) -> Vec<u8> {
    let mut ihdr = b"IHDR".to_vec();
    ihdr.extend_from_slice(&width.to_be_bytes());
    ihdr.extend_from_slice(&height.to_be_bytes());
    ihdr.extend_from_slice(&[8, 0, 0, 0, 0]); // 8-bit gray, deflate, no filter, no interlace
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    png.extend_from_slice(&13u32.to_be_bytes());
    png.extend_from_slice(&ihdr);
    png.extend_from_slice(&crc32fast::hash(&ihdr).to_be_bytes());
    // An IDAT of a zlib stream that would inflate to gigabytes of zeros, cut short.
    let idat = b"IDAT\x78\x9c\xed\xc1\x01\x0d\x00\x00\x00\xc2\xa0";
    png.extend_from_slice(&((idat.len() - 4) as u32).to_be_bytes());
    png.extend_from_slice(idat);
    png.extend_from_slice(&crc32fast::hash(idat).to_be_bytes());
    png
}

/// A real 16x16 JPEG whose frame header (SOF0) is patched to declare `width x height`.
fn jpeg_declaring(width: u16, height: u16) -> Vec<u8> {
    let mut jpeg = Vec::new();
    image::GrayImage::from_pixel(16, 16, image::Luma([90]))
        .write_to(&mut std::io::Cursor::new(&mut jpeg), image::ImageFormat::Jpeg)
        .unwrap();
    let sof = jpeg.windows(2).position(|m| m == [0xFF, 0xC0]).expect("baseline JPEG");
    // Marker, length (2), precision (1), then height and width.
    jpeg[sof + 5..sof + 7].copy_from_slice(&height.to_be_bytes());
    jpeg[sof + 7..sof + 9].copy_from_slice(&width.to_be_bytes());
    jpeg
}

#[test]
fn decompression_bombs_are_refused_from_their_header() {
    let dir = scratch("bomb");
    let right = dir.join("r.png");
    write_png(&right, 200, 60);
    let png = dir.join("bomb.png");
    std::fs::write(&png, png_declaring(100_000, 100_000)).unwrap();
    let jpeg = dir.join("bomb.jpg");
    std::fs::write(&jpeg, jpeg_declaring(65_000, 65_000)).unwrap();
    let before = listing(&dir);
    let out = dir.join("out");
    assert_refused(&run(&png, &right, &out, &[]), &["bomb.png", "100000x100000", "limit"]);
    assert_refused(&run(&jpeg, &right, &out, &[]), &["bomb.jpg", "65000x65000", "limit"]);
    assert_eq!(listing(&dir), before, "no output");
}

#[test]
fn truncated_empty_and_non_file_images_are_named() {
    let dir = scratch("images");
    let right = dir.join("r.png");
    write_png(&right, 200, 60);
    let good = std::fs::read(&right).unwrap();
    let truncated = dir.join("truncated.png");
    std::fs::write(&truncated, &good[..good.len() / 2]).unwrap();
    let empty = dir.join("empty.png");
    std::fs::write(&empty, b"").unwrap();
    let folder = dir.join("folder.png");
    std::fs::create_dir(&folder).unwrap();
    let before = listing(&dir);
    let out = dir.join("out");
    assert_refused(&run(&truncated, &right, &out, &[]), &["truncated.png", "cannot decode"]);
    assert_refused(&run(&empty, &right, &out, &[]), &["empty.png", "empty (0 bytes)"]);
    assert_refused(&run(&right, &folder, &out, &[]), &["folder.png", "is a directory"]);
    assert_eq!(listing(&dir), before, "no output");
}

/// Opening a FIFO blocks until a writer comes: the command must refuse it without opening it.
#[cfg(unix)]
#[test]
fn a_fifo_given_as_an_image_is_refused_without_blocking() {
    let dir = scratch("fifo");
    let right = dir.join("r.png");
    write_png(&right, 200, 60);
    let fifo = dir.join("camera.png");
    let made = std::process::Command::new("mkfifo").arg(&fifo).status().unwrap();
    assert!(made.success());
    assert_refused(
        &run(&fifo, &right, &dir.join("out"), &[]),
        &["camera.png", "named pipe"],
    );
    assert!(!dir.join("out").exists());
}

#[test]
fn a_blob_path_that_is_a_directory_is_named() {
    let dir = scratch("blob");
    let (left, right) = (dir.join("l.png"), dir.join("r.png"));
    write_png(&left, 200, 60);
    write_png(&right, 200, 60);
    let blob = dir.join("weights.bin");
    std::fs::create_dir(&blob).unwrap();
    let out = dir.join("out");
    assert_refused(
        &run(&left, &right, &out, &["--blob", s(&blob)]),
        &["weight blob", "weights.bin", "is a directory"],
    );
    assert!(!out.exists());
}

/// Issue 15: the native pathway asked of a blob without the native head (any blob quantised
/// before it) names the blob and the quantiser flag that adds it, before any output.
#[test]
fn the_native_pathway_on_a_blob_without_its_head_is_named() {
    use bino_core::blob::Blob;
    use bino_core::model::ids;
    let dir = scratch("native-blob");
    let (left, right) = (dir.join("l.png"), dir.join("r.png"));
    write_png(&left, 200, 60);
    write_png(&right, 200, 60);
    let shipped = std::fs::read(bino_host::demo::DEFAULT_BLOB).unwrap();
    let shipped = Blob::parse(&shipped).unwrap();
    let mut writer = bino_host::int8::blob_writer::BlobWriter::new();
    let native_norm = ids::id(ids::kind::LAYERNORM, ids::HeadKind::Native.layernorm());
    for t in shipped.tensors().filter(|t| t.id != native_norm) {
        let (dtype, bytes) = shipped.raw(t.id).unwrap();
        writer.add_raw(t.id, dtype, t.elements, bytes.to_vec()).unwrap();
    }
    let blob = dir.join("export_only.bin");
    std::fs::write(&blob, writer.finish()).unwrap();
    let out = dir.join("out");
    let args = |pathway: &'static str| {
        let pair = ["run", "--left", s(&left), "--right", s(&right), "--profile", "w160"];
        let rest = ["--blob", s(&blob), "--out", s(&out), "--pathway", pathway];
        bino(&[&pair[..], &rest[..]].concat())
    };
    assert_refused(
        &args("native"),
        &["export_only.bin", "no usable native pathway head", "--native-head"],
    );
    assert!(!out.exists());
    // The export pathway still runs on it.
    let export = args("export");
    assert!(export.status.success(), "{}", String::from_utf8_lossy(&export.stderr));
}

#[test]
fn an_unwritable_output_folder_is_named_and_nothing_is_left() {
    let dir = scratch("out");
    let (left, right) = (dir.join("l.png"), dir.join("r.png"));
    write_png(&left, 200, 60);
    write_png(&right, 200, 60);
    // A regular file where a folder is needed: refused even for root, before any work.
    let blocker = dir.join("blocker");
    std::fs::write(&blocker, b"a file").unwrap();
    let before = listing(&dir);
    let out = blocker.join("out");
    assert_refused(
        &run(&left, &right, &out, &[]),
        &["--out", "blocker/out", "cannot create the folder", "blocker is a file"],
    );
    assert_eq!(listing(&dir), before, "no output, no partial file");
    assert_eq!(
        std::fs::read(&blocker).unwrap(),
        b"a file",
        "the file in the way is untouched"
    );
}

#[test]
fn a_usage_error_exits_with_2() {
    let out = bino(&["run", "--left", "l.png"]);
    assert_eq!(out.status.code(), Some(2), "{}", String::from_utf8_lossy(&out.stderr));
    let out = bino(&["run", "--left", "l.png", "--right", "r.png", "--readout", "psychic"]);
    assert_eq!(out.status.code(), Some(2), "{}", String::from_utf8_lossy(&out.stderr));
    let out = bino(&["pairs", "--split", "test"]);
    assert_eq!(out.status.code(), Some(2), "{}", String::from_utf8_lossy(&out.stderr));
    let pair = ["--left", "l.png", "--right", "r.png"];
    for bad in [
        &["--refine", "maybe"][..],
        &["--refine", "Off"],
        &["--readout", "sgm+ref+lr"],
        &["--readout", "sgm+ref", "--refine", "off"],
    ] {
        let out = bino(&[&["run"][..], &pair, bad].concat());
        assert_eq!(
            out.status.code(),
            Some(2),
            "{bad:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    }
    let out = bino(&["eval", "--readout", "head,head+lr+ref,head+ref+lr"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("then optionally +ref"), "{stderr}");
}

const HEADER: &str = "pair_id\tsplit\tdataset\tleft\tright\tgt\tgt_format\tgt_scale\tgt_invalid\twidth\theight\n";

/// A data folder whose PAIRS.tsv is `index` (raw bytes), with a 200x60 pair and ground truth.
fn data_folder(name: &str, index: &[u8], gt_size: (u32, u32)) -> PathBuf {
    let dir = scratch(name);
    write_png(&dir.join("l.png"), 200, 60);
    write_png(&dir.join("r.png"), 200, 60);
    image::GrayImage::from_pixel(gt_size.0, gt_size.1, image::Luma([40]))
        .save(dir.join("gt.png"))
        .unwrap();
    std::fs::write(dir.join("PAIRS.tsv"), index).unwrap();
    dir
}

/// `bino eval` (int8 nolink, no SGBM) on the folder `dir`, its JSON to `json`.
fn eval_into(dir: &Path, json: &Path) -> Output {
    bino(&[
        "eval",
        "--data",
        s(dir),
        "--readout",
        "nolink",
        "--precision",
        "int8",
        "--no-sgbm",
        "--json",
        s(json),
    ])
}

fn eval_row() -> String {
    "p\teval\tsynthetic\tl.png\tr.png\tgt.png\tpng_u8\t4\t0\t200\t60\n".to_string()
}

#[test]
fn malformed_pair_indexes_are_refused_with_file_and_line() {
    let cases: [(&str, Vec<u8>, &[&str]); 6] = [
        (
            "missing-columns",
            format!("{HEADER}p\teval\tsynthetic\tl.png\tr.png\n").into_bytes(),
            &["line 2", "5 tab-separated fields"],
        ),
        (
            "missing-header-column",
            "pair_id\tsplit\tleft\tright\np\teval\tl.png\tr.png\n"
                .as_bytes()
                .to_vec(),
            &["lacks column \"dataset\""],
        ),
        (
            "unknown-split",
            format!("{HEADER}{}", eval_row().replace("\teval\t", "\ttest\t")).into_bytes(),
            &["line 2", "split \"test\" is none of train, eval, val"],
        ),
        (
            "outside",
            format!("{HEADER}{}", eval_row().replace("\tl.png", "\t../../l.png")).into_bytes(),
            &["line 2", "leaves the index's folder"],
        ),
        (
            "non-utf8",
            [HEADER.as_bytes(), b"p\teval\tsynth\xe9tic\tl.png\n"].concat(),
            &["line 2 is not UTF-8"],
        ),
        (
            "crlf",
            format!("{HEADER}{}", eval_row()).replace('\n', "\r\n").into_bytes(),
            &["line 1 ends in CR LF"],
        ),
    ];
    for (name, index, needles) in cases {
        let dir = data_folder(name, &index, (200, 60));
        let before = listing(&dir);
        let mut all = vec!["PAIRS.tsv"];
        all.extend_from_slice(needles);
        assert_refused(&bino(&["pairs", "--data", s(&dir)]), &all);
        let json = dir.join("eval.json");
        let eval = eval_into(&dir, &json);
        assert_refused(&eval, &all);
        assert_eq!(listing(&dir), before, "{name}: no output");
    }
}

#[test]
fn ground_truth_of_the_wrong_size_is_refused() {
    // 400x120 resizes to the same 160x48 at w160 as the 200x60 views: it must be caught at
    // the stored resolution.
    for (name, size) in [("gt-small", (100, 30)), ("gt-scaled", (400, 120))] {
        let dir = data_folder(name, format!("{HEADER}{}", eval_row()).as_bytes(), size);
        let before = listing(&dir);
        let eval = eval_into(&dir, &dir.join("eval.json"));
        let stated = format!("{}x{}", size.0, size.1);
        assert_refused(&eval, &["ground truth", "gt.png", &stated, "200x60"]);
        assert_eq!(listing(&dir), before, "{name}: no output");
    }
}

#[test]
fn a_well_formed_index_of_the_same_shape_is_accepted() {
    // The control for the cases above: the same folder with a sound index evaluates.
    let dir = data_folder("sound", format!("{HEADER}{}", eval_row()).as_bytes(), (200, 60));
    let json = dir.join("eval.json");
    let eval = eval_into(&dir, &json);
    assert!(eval.status.success(), "{}", String::from_utf8_lossy(&eval.stderr));
    assert!(json.is_file());
}

/// A little-endian grayscale PFM of `values` (top row first), as Middlebury 2014 writes it.
fn pfm_bytes(width: usize, values: &[f32]) -> Vec<u8> {
    let mut bytes = format!("Pf\n{width} {}\n-1\n", values.len() / width).into_bytes();
    for row in values.chunks_exact(width).rev() {
        for v in row {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    bytes
}

/// `eval_row` with the ground truth `gt` in `format`, `scale` and `invalid`.
fn eval_row_with(gt: &str, format: &str, scale: &str, invalid: &str) -> String {
    format!("p\teval\tsynthetic\tl.png\tr.png\t{gt}\t{format}\t{scale}\t{invalid}\t200\t60\n")
}

#[test]
fn hostile_pfm_ground_truth_is_refused_before_allocating() {
    let sound = pfm_bytes(200, &[10.0; 200 * 60]);
    let cases: [(&str, Vec<u8>, &[&str]); 4] = [
        (
            "pfm-truncated",
            sound[..sound.len() / 2].to_vec(),
            &["truncated", "200x60 needs 48000"],
        ),
        // 40 GB of floats if believed: refused from the header (the file is 24 bytes).
        (
            "pfm-bomb",
            b"Pf\n100000 100000\n-1\n\0\0\0\0".to_vec(),
            &["100000x100000", "limit"],
        ),
        (
            "pfm-colour",
            [b"PF\n200 60\n-1\n".as_slice(), &[0; 12 * 200 * 60]].concat(),
            &["colour PFM"],
        ),
        ("pfm-small", pfm_bytes(100, &[10.0; 100 * 30]), &["is 100x30", "200x60"]),
    ];
    for (name, pfm, needles) in cases {
        let row = eval_row_with("gt.pfm", "pfm", "1", "");
        let dir = data_folder(name, format!("{HEADER}{row}").as_bytes(), (200, 60));
        std::fs::write(dir.join("gt.pfm"), pfm).unwrap();
        let before = listing(&dir);
        // The pair is named as well as the file (`pair p: ...`).
        let mut all = vec!["pair p", "ground truth", "gt.pfm"];
        all.extend_from_slice(needles);
        assert_refused(&eval_into(&dir, &dir.join("eval.json")), &all);
        assert_eq!(listing(&dir), before, "{name}: no output");
    }
}

#[test]
fn the_same_ground_truth_in_every_format_scores_the_same() {
    // End to end, the formats' scale and unknown-value rules agree: one map stored four ways
    // scores the same. (Row order is checked by the unit tests of `pfm` and `eval::gt`: these
    // views give every row the same prediction, so a row flip would not show here.)
    let (w, h) = (200usize, 60usize);
    let quarter = |i: usize| -> u8 {
        let (x, y) = (i % w, i / w);
        if y < 15 && x % 3 == 0 {
            0
        } else {
            1 + (y * 39 / (h - 1)) as u8 + (x % 2) as u8
        }
    };
    let stored: Vec<u8> = (0..w * h).map(quarter).collect();
    let pixels: Vec<f32> = stored
        .iter()
        .map(|&v| if v == 0 { f32::INFINITY } else { f32::from(v) / 4.0 })
        .collect();
    // (case, file, gt_format, gt_scale, gt_invalid).
    let cases = [
        ("pgm", "gt.pgm", "pgm_u8", "4", "0"),
        ("png8", "gt.png", "png_u8", "4", "0"),
        ("png16", "gt16.png", "png_u16", "256", "0"),
        ("pfm", "gt.pfm", "pfm", "1", ""),
    ];
    let mut means = Vec::new();
    for (case, file, format, scale, invalid) in cases {
        let row = eval_row_with(file, format, scale, invalid);
        let dir = data_folder(
            &format!("formats-{case}"),
            format!("{HEADER}{row}").as_bytes(),
            (200, 60),
        );
        let path = dir.join(file);
        match case {
            "pgm" | "png8" => image::GrayImage::from_raw(w as u32, h as u32, stored.clone())
                .unwrap()
                .save(&path)
                .unwrap(),
            "png16" => {
                let wide: Vec<u16> = stored.iter().map(|&v| u16::from(v) * 64).collect();
                image::ImageBuffer::<image::Luma<u16>, _>::from_raw(w as u32, h as u32, wide)
                    .unwrap()
                    .save(&path)
                    .unwrap()
            }
            _ => std::fs::write(&path, pfm_bytes(w, &pixels)).unwrap(),
        }
        let json = dir.join("eval.json");
        let eval = eval_into(&dir, &json);
        assert!(
            eval.status.success(),
            "{case}: {}",
            String::from_utf8_lossy(&eval.stderr)
        );
        let report: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
        means.push((case, report["mean"].clone()));
    }
    for (case, mean) in &means[1..] {
        assert_eq!(mean, &means[0].1, "{case} against {}", means[0].0);
    }
    // The control: the same PFM read with another gt_scale scores otherwise.
    let row = eval_row_with("gt.pfm", "pfm", "2", "");
    let dir = data_folder("formats-pfm-scale-2", format!("{HEADER}{row}").as_bytes(), (200, 60));
    std::fs::write(dir.join("gt.pfm"), pfm_bytes(w, &pixels)).unwrap();
    let json = dir.join("eval.json");
    assert!(eval_into(&dir, &json).status.success());
    let report: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_ne!(report["mean"], means[0].1, "gt_scale must divide a PFM too");
}
