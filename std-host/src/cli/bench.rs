//! `bino bench`: tract-onnx (f32), onnxruntime and the int8 engine on one band, single-threaded.

use std::path::PathBuf;

use anyhow::Result;
use bino_host::bench::{bench, BenchOptions};
use bino_host::data::profile::Profile;
use clap::Args;

use super::progress::Progress;

/// Time tract-onnx (f32), the int8 engine and onnxruntime on the same band, single-threaded.
///
/// One 48-row band of the built-in scene at the profile's width, encoded on (I, I) by each
/// (the descriptor pathway); one warm-up run each, then --runs rounds in which every engine
/// runs once (onnxruntime: f32 and dynamic int8, through `python -m bino_train.ort_bench`
/// in the project's Python environment). Prints medians,
/// minima, GMAC/s and the ratio. Build with --release: a debug build's timings mean little.
#[derive(Args)]
pub struct BenchArgs {
    /// Float encoder (`python -m bino_train.export`).
    #[arg(long, default_value = "weights/bino_encoder.onnx")]
    onnx: PathBuf,
    /// Int8 weight blob (`bino quantize`).
    #[arg(long, default_value = "weights/bino_int8.bin")]
    blob: PathBuf,
    /// Profile giving the band width: w160 or w320.
    #[arg(long, default_value = "w160")]
    profile: Profile,
    /// Threads: only 1 (tract is built single-threaded; so is the int8 engine).
    #[arg(long, default_value_t = 1)]
    threads: usize,
    /// Timed runs per engine.
    #[arg(long, default_value_t = 10)]
    runs: usize,
    /// Skip onnxruntime (timed by default through the project's Python environment, f32 and
    /// dynamic int8, one thread each).
    #[arg(long)]
    no_onnxruntime: bool,
    /// Keep the int8 engine on its AVX2 kernels where the CPU also has AVX-512 VNNI (the
    /// results are the same; this measures the AVX2 path).
    #[arg(long)]
    no_vnni: bool,
    /// Also write the timings as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
}

/// Runs the verb.
pub fn run(args: BenchArgs) -> Result<()> {
    let opts = BenchOptions {
        onnx: args.onnx,
        blob: args.blob,
        profile: args.profile,
        threads: args.threads,
        runs: args.runs,
        onnxruntime: !args.no_onnxruntime,
        no_vnni: args.no_vnni,
    };
    let progress = Progress::new(args.json.is_some());
    let report = bench(&opts, |what| progress.note(&format!("timing {what}")))?;
    progress.finish();
    if report.debug_build {
        eprintln!("WARNING: debug build: timings are only meaningful with --release");
    }
    println!("{}", report.text());
    super::write_json(args.json.as_deref(), || report.to_json())
}
