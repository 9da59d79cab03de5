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
    Command::new(env!("CARGO_BIN_EXE_bino"))
        .args(args)
        .current_dir(repo())
        .output()
        .unwrap()
}

/// A path as a command-line argument.
pub fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}
