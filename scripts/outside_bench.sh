#!/usr/bin/env bash
# Times bino-core's int8 encoder from a crate OUTSIDE this repository (no .cargo/config.toml, no
# -C target-cpu): the measurement behind "a crate that depends on bino-core gets the fast x86
# kernels without flags". Builds the same tiny program twice, once as an outside crate gets it
# and once with the workspace's x86-64-v3 flags, and runs `bino bench`'s int8 work on each
# (Encoder::describe on one 48x160 band on (I, I), the firmware band's left view) for every
# kernel cap: the fastest the CPU has, AVX2, portable. Prints min / median and the descriptors'
# CRC, which must be the same on every line.
#
#   scripts/outside_bench.sh [RUNS]     (default 20 runs a line)
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
runs="${1:-20}"
work="$(mktemp -d /tmp/bino-outside.XXXXXX)"
trap 'rm -rf "$work"' EXIT
mkdir -p "$work/src"
cat >"$work/Cargo.toml" <<TOML
[package]
name = "bino-outside-bench"
version = "0.1.0"
edition = "2021"
publish = false

[dependencies]
bino-core = { path = "$root/core" }

[profile.release]
debug = 1
TOML
cat >"$work/src/main.rs" <<'RS'
use bino_core::blob::Blob;
use bino_core::crc32::Crc32;
use bino_core::kernels::dispatch::{limit, Isa};
use bino_core::model::encoder::{arena_bytes, Encoder, GrayBand};
use bino_core::model::probe::NoProbe;

fn main() {
    let mut args = std::env::args().skip(1);
    let root = std::path::PathBuf::from(args.next().expect("repository root"));
    let runs: usize = args.next().map_or(20, |s| s.parse().expect("runs"));
    let cap = args.next().unwrap_or_default();
    match cap.as_str() {
        "avx2" => drop(limit(Isa::Avx2)),
        "portable" => drop(limit(Isa::Portable)),
        _ => {}
    }
    let blob = std::fs::read(root.join("weights/bino_int8.bin")).expect("weights/bino_int8.bin");
    let left = std::fs::read(root.join("firmware-sim/assets/band_48x160_left.gray")).expect("band");
    let encoder = Encoder::new(Blob::parse(&blob).expect("blob")).expect("encoder");
    let band = GrayBand::new(&left, 160, 48).expect("band size");
    let mut arena = vec![0u8; arena_bytes(48, 160)];
    let mut out = vec![0i8; 12 * 40 * 128];
    encoder.describe(band, &mut arena, &mut out, &mut NoProbe).expect("warm-up");
    let mut ms = Vec::with_capacity(runs);
    for _ in 0..runs {
        let t = std::time::Instant::now();
        encoder.describe(band, &mut arena, &mut out, &mut NoProbe).expect("describe");
        ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    ms.sort_by(f64::total_cmp);
    let bytes: Vec<u8> = out.iter().map(|&c| c as u8).collect();
    let mut crc = Crc32::new();
    crc.update(&bytes);
    println!(
        "kernels {:<12} min {:7.1} ms  median {:7.1} ms  ({runs} runs)  descriptors crc {:08x}",
        bino_core::kernels::dispatch::active().name(),
        ms[0],
        ms[runs / 2],
        crc.finish()
    );
}
RS
build() { (cd "$work" && CARGO_TARGET_DIR="$work/target-$1" RUSTFLAGS="$2" cargo build -q --release); }
build outside ""
build workspace "-C target-cpu=x86-64-v3"
for cap in fastest avx2 portable; do
  for kind in outside workspace; do
    printf '%-26s ' "$kind build, cap $cap:"
    "$work/target-$kind/release/bino-outside-bench" "$root" "$runs" "$cap"
  done
done
