//! Profiling aid: the int8 encoder's `describe` on one 48x160 band, repeated, with nothing else
//! in the process (no tract, no onnxruntime), so `perf record` sees the engine alone.
//!
//! ```sh
//! cargo run --release -p bino-core --example encode_profile -- weights/bino_int8.bin 40 [--no-vnni]
//! ```
//! Prints the median and minimum time of a pass and a checksum of the descriptors (the same
//! whichever kernels ran).

use bino_core::blob::Blob;
use bino_core::config::DIM;
use bino_core::model::encoder::{arena_bytes, Encoder, GrayBand};
use bino_core::model::probe::NoProbe;
use std::time::Instant;

fn main() -> Result<(), String> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let path = args.first().ok_or("usage: encode_profile BLOB [RUNS] [--no-vnni]")?;
    let runs: usize = match args.get(1).filter(|a| !a.starts_with("--")) {
        Some(n) => n.parse().map_err(|e| format!("RUNS {n}: {e}"))?,
        None => 30,
    };
    #[cfg(target_arch = "x86_64")]
    if args.iter().any(|a| a == "--no-vnni") {
        bino_core::kernels::arch::x86::vnni::enable(false);
    }
    let bytes = std::fs::read(path).map_err(|e| format!("{path}: {e}"))?;
    let blob = Blob::parse(&bytes).map_err(|e| format!("{path}: {e}"))?;
    let encoder = Encoder::new(blob).map_err(|e| format!("{path}: {e}"))?;
    let (height, width) = (48, 160);
    let pixels: Vec<u8> = (0..height * width).map(|i| ((i * 7919) % 251) as u8).collect();
    let band = GrayBand::new(&pixels, width, height).map_err(|e| e.to_string())?;
    let mut arena = vec![0u8; arena_bytes(height, width)];
    let mut out = vec![0i8; (height / 4) * (width / 4) * DIM];
    let mut times = Vec::with_capacity(runs);
    for _ in 0..runs.max(1) {
        let start = Instant::now();
        encoder
            .describe(band, &mut arena, &mut out, &mut NoProbe)
            .map_err(|e| e.to_string())?;
        times.push(start.elapsed().as_secs_f64() * 1e3);
    }
    times.sort_by(f64::total_cmp);
    let checksum: i64 = out.iter().map(|&v| i64::from(v)).sum();
    println!(
        "median {:.2} ms, min {:.2} ms over {} passes; descriptor checksum {checksum}",
        times[times.len() / 2],
        times[0],
        times.len()
    );
    Ok(())
}
