//! `bino_dsp`: Armv7E-M targets (Cortex-M7, `thumbv7em-*`), which have the 16x16 DSP
//! multiply-accumulates but no vector unit; the int8 dot products take a two-row path there
//! (`kernels::matmul::dot4_pairs`). Stable Rust has no `cfg` for this, so it comes from the
//! target triple.
fn main() {
    println!("cargo::rustc-check-cfg=cfg(bino_dsp)");
    println!("cargo::rerun-if-changed=build.rs");
    let target = std::env::var("TARGET").unwrap_or_default();
    if target.starts_with("thumbv7em") {
        println!("cargo::rustc-cfg=bino_dsp");
    }
}
