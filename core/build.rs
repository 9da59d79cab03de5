//! Instruction-set cfgs of the kernels. Stable Rust has no `cfg` for these, so they come from
//! the target triple and, for MVE, from the target CPU the build names:
//! - `bino_dsp`: Armv7E-M targets (Cortex-M7, `thumbv7em-*`), which have the 16x16 DSP
//!   multiply-accumulates but no vector unit: the `smlad` GEMM tile (`kernels::arch::dsp`) and
//!   the two-row dot products (`kernels::reference::matmul::dot4_pairs`).
//! - `bino_mve`: `thumbv8m.main-*` built with `-C target-cpu=cortex-m55` (or
//!   `-C target-feature=+mve`), whose assembler takes Helium: the `vmladava` GEMM tiles
//!   (`kernels::arch::mve`). A plain `thumbv8m.main` build (no MVE) gets the portable kernels.
fn main() {
    println!("cargo::rustc-check-cfg=cfg(bino_dsp)");
    println!("cargo::rustc-check-cfg=cfg(bino_mve)");
    println!("cargo::rerun-if-changed=build.rs");
    println!("cargo::rerun-if-env-changed=CARGO_ENCODED_RUSTFLAGS");
    let target = std::env::var("TARGET").unwrap_or_default();
    let flags = std::env::var("CARGO_ENCODED_RUSTFLAGS").unwrap_or_default();
    if target.starts_with("thumbv7em") {
        println!("cargo::rustc-cfg=bino_dsp");
    }
    let mve = flags.contains("target-cpu=cortex-m55") || flags.contains("+mve");
    if target.starts_with("thumbv8m.main") && mve {
        println!("cargo::rustc-cfg=bino_mve");
    }
}
