//! Hands the linker the memory map of the target's board: `memory/<board>.x` as the `memory.x`
//! that cortex-m-rt's `link.x` includes, and `memory/weights.x`, which that includes. Host builds
//! need none.

use std::{env, fs, path::PathBuf};

fn main() {
    let board = match env::var("TARGET").unwrap().as_str() {
        "thumbv8m.main-none-eabihf" => "m55",
        "thumbv7em-none-eabihf" => "m7",
        _ => return,
    };
    let out = PathBuf::from(env::var("OUT_DIR").unwrap());
    fs::copy(format!("memory/{board}.x"), out.join("memory.x")).unwrap();
    fs::copy("memory/weights.x", out.join("weights.x")).unwrap();
    println!("cargo::rustc-link-search={}", out.display());
    println!("cargo::rerun-if-changed=memory");
}
