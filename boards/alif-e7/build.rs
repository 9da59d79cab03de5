//! Hands the linker the board's memory map and bakes in the summary a host run of its 320x240
//! test frame gives, in the build's preset (`bino_board::bake`).

use std::env;
use std::fs;
use std::path::{Path, PathBuf};

use bino_board::bake;

fn main() {
    let root = PathBuf::from(env::var("CARGO_MANIFEST_DIR").unwrap());
    let out = PathBuf::from(env::var("OUT_DIR").unwrap());
    fs::copy(root.join("memory.x"), out.join("memory.x")).unwrap_or_else(|e| panic!("memory.x: {e}"));
    println!("cargo::rustc-link-search={}", out.display());
    println!("cargo::rerun-if-changed=memory.x");
    bake(&root.join("../.."), &out);
}

/// Writes `OUT_DIR/expected.rs` from a host run of the test frame.
fn bake(repo: &Path, out: &Path) {
    let read = |rel: &str| {
        let path = repo.join(rel);
        println!("cargo::rerun-if-changed={}", path.display());
        fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
    };
    // The learned preset (feature `learned`) reads the blob; the fast preset no weights.
    let fast = env::var_os("CARGO_FEATURE_LEARNED").is_none();
    let blob = (!fast).then(|| read("weights/bino_int8_native.bin"));
    let frame = bino_board::options::ALIF_E7;
    let left = read(&bake::test_frame_path(frame, "left"));
    let right = read(&bake::test_frame_path(frame, "right"));
    let code = bake::expected_rs(blob.as_deref(), frame, &left, &right)
        .unwrap_or_else(|e| panic!("the host run of the test frame failed: {e}"));
    fs::write(out.join("expected.rs"), code).unwrap();
}
