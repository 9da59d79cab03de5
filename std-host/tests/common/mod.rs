//! Helpers the CLI test files share (each test file is its own crate and uses a subset).
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// The repository root.
pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

/// A per-process folder under the system's temp dir, created if missing (contents kept).
pub fn scratch_dir(label: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("bino-{label}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Runs the `bino` binary from the repository root.
pub fn bino(args: &[&str]) -> Output {
    bino_in(&repo(), args)
}

/// Runs the `bino` binary from `dir`, as an installed `bino` runs from wherever its user is.
pub fn bino_in(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_bino"))
        .args(args)
        .current_dir(dir)
        .output()
        .unwrap()
}

/// CRC-32 of a `disparity.pfm` of `size` (width, height) in Q8 pixels, rows top to bottom, as
/// the firmware and the boards digest their refined rows (`u16` little-endian).
pub fn q8_crc(pfm: &Path, size: (usize, usize)) -> u32 {
    let map = bino_host::io::pfm::load(pfm, "run's disparity").unwrap();
    assert_eq!((map.width, map.height), size);
    let mut crc = bino_core::crc32::Crc32::new();
    for (i, &v) in map.values.iter().enumerate() {
        let q8 = v * 256.0;
        assert!(
            q8.fract() == 0.0 && (0.0..=u16::MAX as f32).contains(&q8),
            "pixel {i}: {v} is no Q8 value"
        );
        crc.update(&(q8 as u16).to_le_bytes());
    }
    crc.finish()
}

/// A path as a command-line argument.
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Whether a test must fail instead of skipping when an input outside the repository is missing
/// (`../shared/data`, the project's Python environment): under `CI=true` or `BINO_REQUIRE_DATA=1`
/// (which `scripts/test.sh` sets). The same rule as `bino_tests::inputs_required`.
pub fn inputs_required() -> bool {
    let set = |name: &str, values: &[&str]| std::env::var(name).is_ok_and(|v| values.contains(&v.as_str()));
    set("CI", &["true", "1"]) || set("BINO_REQUIRE_DATA", &["1", "true"])
}

/// `present`, after a `skipped:` note on stderr when it is false; panics instead when
/// [`inputs_required`], so a missing input never passes in CI.
pub fn available(what: &str, present: bool) -> bool {
    if !present {
        assert!(
            !inputs_required(),
            "{what} is missing (CI=true or BINO_REQUIRE_DATA=1: not skipped)"
        );
        eprintln!("skipped: {what} is missing (set BINO_REQUIRE_DATA=1 to fail instead)");
    }
    present
}
