//! `bino bench`: tract-onnx (f32), onnxruntime and the int8 engine on one band, single-threaded,
//! and the int8 engine on every core.

use std::path::PathBuf;

use anyhow::Result;
use bino_host::bench::{bench, BenchOptions};
use bino_host::data::profile::Profile;
use bino_host::io::checkout;
use clap::Args;

use super::progress::Progress;

/// Time the int8 engine against tract-onnx and onnxruntime on one band.
///
/// One 48-row band of the built-in scene at the profile's width, encoded on (I, I) by each
/// (the descriptor pathway); one warm-up run each, then --runs rounds in which every engine
/// runs once (onnxruntime: f32 and dynamic int8, in the project's Python environment). Every
/// engine runs on one thread: this tract-onnx is built single-threaded, and so is the int8
/// engine's pass. Then the int8 engine on every core at once (--threads bands a round): the
/// host's throughput. Prints medians, minima, GMAC/s and the ratio. Build with --release: a
/// debug build's timings mean little.
#[derive(Args)]
pub struct BenchArgs {
    /// Float encoder (`python -m bino_train.export`); the default is the checkout's shipped one.
    #[arg(long, default_value_os_t = checkout::path(checkout::ENCODER_ONNX))]
    onnx: PathBuf,
    /// Int8 weight blob (`bino quantize`); the default is the checkout's shipped one.
    #[arg(long, default_value_os_t = checkout::path(checkout::BLOB))]
    blob: PathBuf,
    /// Profile giving the band width: w160 or w320; the default is the board's band width.
    #[arg(long, default_value = "w160")]
    profile: Profile,
    /// Timed runs per engine.
    #[arg(long, default_value_t = 10)]
    runs: usize,
    /// Skip onnxruntime (timed by default in the project's Python environment).
    ///
    /// onnxruntime is timed f32 and dynamic int8, one thread each.
    #[arg(long)]
    no_onnxruntime: bool,
    /// Keep the int8 engine on its AVX2 kernels where the CPU also has AVX-512 VNNI.
    ///
    /// The results are the same; this measures the AVX2 path.
    #[arg(long)]
    no_vnni: bool,
    /// Threads of the all-cores figure (default: every core; 1 leaves it out).
    ///
    /// The int8 engine encodes that many bands at once, one a thread, after the one-thread
    /// comparison.
    #[arg(long, default_value_t = bino_host::bench::all_cores::default_threads())]
    threads: usize,
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
        runs: args.runs,
        onnxruntime: !args.no_onnxruntime,
        no_vnni: args.no_vnni,
        threads: args.threads,
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
