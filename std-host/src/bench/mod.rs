//! `bino bench`: the float encoder run by tract-onnx against the int8 engine, timed on the same
//! band in one process.
//!
//! Both compute the descriptor pathway's encoder pass, the encoder on (I, I) of one
//! `48 x width` band of the built-in synthetic scene: tract its `tokens` output (f32 pixels
//! p / 255), the int8 engine [`bino_core::model::encoder::Encoder::describe`] on the same 8-bit pixels, its arena
//! allocated before timing. Each gets one warm-up run, then `runs` timed runs. tract's time
//! includes copying its output out of the tensor (about 0.5 MB, negligible next to the pass).
//!
//! With `onnxruntime` (the default), the project's Python environment also times onnxruntime's
//! float session and its dynamic int8 quantisation on the same pixels, one thread each
//! ([`crate::bench::ort`]). The engines take turns: every round runs each engine once, so the
//! drift of a shared machine reaches them all alike.
//!
//! Threads: this build of tract-onnx lacks the `multithread-mm` feature (no rayon), so its
//! only executor is `Executor::SingleThread`; the int8 engine never spawns threads within a
//! pass. The comparison therefore runs every engine on the calling thread (the report counts
//! the process's threads after the runs, Linux, as evidence). With `threads > 1` the int8
//! engine is also timed on every core at once, one band per thread ([`all_cores`]): the
//! host's throughput, as `bino run` uses it.

pub mod all_cores;
pub mod ort;

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{bail, ensure, Context, Result};
use bino_core::config::{BAND_ROWS, DEPTH, DIM, MLP_HIDDEN, PATCH_H, PATCH_W};
use bino_core::model::encoder::{arena_bytes, GrayBand};
use bino_core::model::probe::NoProbe;
use bino_core::model::weights::AttentionSpan;
use serde::Serialize;
use tract_onnx::prelude::{tract_ndarray, Tensor};

use crate::bench::all_cores::{AllCores, Round};
use crate::bench::ort::{OrtServer, OrtSession};
use crate::data::profile::Profile;
use crate::data::synthetic;
use crate::float::onnx::OnnxModel;
use crate::int8::Int8Model;
use crate::io::files::sha256_hex;
use crate::io::train_python::TrainPython;

/// What to time.
#[derive(Debug, Clone)]
pub struct BenchOptions {
    /// Float encoder (ONNX).
    pub onnx: PathBuf,
    /// Int8 weight blob.
    pub blob: PathBuf,
    /// Profile giving the band width (w160: 160 px).
    pub profile: Profile,
    /// Timed runs per engine, after one warm-up run.
    pub runs: usize,
    /// Also time onnxruntime (f32 and dynamic int8) through the project's Python environment.
    pub onnxruntime: bool,
    /// Keep the int8 engine on its AVX2 kernels where the CPU also has AVX-512 VNNI.
    pub no_vnni: bool,
    /// Threads of the all-cores figure (one band each, at once); 1 leaves it out.
    pub threads: usize,
}

/// Timed runs of one engine, in seconds.
#[derive(Debug, Clone, PartialEq)]
pub struct Timing {
    /// Every timed run, in order.
    pub runs: Vec<f64>,
}

impl Timing {
    /// Median run (mean of the middle two for an even count).
    pub fn median(&self) -> f64 {
        let mut sorted = self.runs.clone();
        sorted.sort_by(f64::total_cmp);
        let n = sorted.len();
        if n == 0 {
            f64::NAN
        } else if n % 2 == 1 {
            sorted[n / 2]
        } else {
            0.5 * (sorted[n / 2 - 1] + sorted[n / 2])
        }
    }

    /// Fastest run.
    pub fn min(&self) -> f64 {
        self.runs.iter().copied().fold(f64::INFINITY, f64::min)
    }

    pub(crate) fn json(&self, macs: u64) -> TimingJson<'_> {
        TimingJson {
            median_s: self.median(),
            min_s: self.min(),
            gmac_per_s: macs as f64 / self.median() / 1e9,
            runs_s: &self.runs,
        }
    }
}

// The JSON of a timing: the runs with what is derived from them.
#[derive(Serialize)]
pub(crate) struct TimingJson<'a> {
    median_s: f64,
    min_s: f64,
    gmac_per_s: f64,
    runs_s: &'a [f64],
}

/// Multiply-accumulates of one encoder pass over a band of `rows` token rows of `fused_cols`
/// tokens: the embedding (16 inputs per token), per block qkv, proj, fc1 and fc2 per token, and
/// attention (scores and weighted sum, `2 x DIM` per query and key it reads: every token of the
/// band, or of its own row, per `span`).
pub fn encoder_macs(rows: usize, fused_cols: usize, span: AttentionSpan) -> u64 {
    let n = (rows * fused_cols) as u64;
    let (dim, hidden) = (DIM as u64, MLP_HIDDEN as u64);
    let embed = n * (PATCH_H * PATCH_W) as u64 * dim;
    let per_token = dim * 3 * dim + dim * dim + 2 * dim * hidden;
    let keys = match span {
        AttentionSpan::Band => n,
        AttentionSpan::Row => fused_cols as u64,
    };
    let attention = 2 * n * keys * dim;
    embed + DEPTH as u64 * (n * per_token + attention)
}

/// What `bino bench` measured, and on what.
#[derive(Debug, Clone)]
pub struct BenchReport {
    /// `bino` version.
    pub version: String,
    /// Float encoder file.
    pub onnx: PathBuf,
    /// Int8 blob file.
    pub blob: PathBuf,
    /// SHA-256 of the blob.
    pub blob_sha256: String,
    /// Band width in pixels.
    pub width: usize,
    /// Band height in pixels.
    pub height: usize,
    /// Tokens per pass (token rows x fused columns).
    pub tokens: usize,
    /// Multiply-accumulates per pass ([`encoder_macs`]).
    pub macs: u64,
    /// Host CPU model, from `/proc/cpuinfo`.
    pub cpu: Option<String>,
    /// Whether the binary was compiled with AVX2 enabled.
    pub built_with_avx2: bool,
    /// Whether the CPU has AVX2 (x86-64 only).
    pub cpu_has_avx2: bool,
    /// The int8 engine's x86 kernels: `avx512-vnni`, `avx2` or `portable`.
    pub x86_kernels: &'static str,
    /// Whether debug assertions are on (a dev build: timings are not meaningful).
    pub debug_build: bool,
    /// Threads of the process after the timed runs (Linux), expected 1.
    pub process_threads: Option<usize>,
    /// tract-onnx f32.
    pub tract: Timing,
    /// The int8 engine.
    pub int8: Timing,
    /// onnxruntime, when it was timed.
    pub onnxruntime: Option<OrtTimings>,
    /// The int8 engine on several threads at once, when it was timed.
    pub all_cores: Option<AllCores>,
}

/// onnxruntime's sessions, one thread each.
#[derive(Debug, Clone)]
pub struct OrtTimings {
    /// The float graph.
    pub f32: Timing,
    /// Its dynamic int8 quantisation.
    pub int8_dynamic: Timing,
}

impl BenchReport {
    /// tract median over int8 median: how many times faster the int8 engine is.
    pub fn speedup(&self) -> f64 {
        self.tract.median() / self.int8.median()
    }

    /// onnxruntime int8 (dynamic) median over the int8 engine's: above 1, the engine is faster.
    pub fn ort_int8_speedup(&self) -> Option<f64> {
        self.onnxruntime
            .as_ref()
            .map(|ort| ort.int8_dynamic.median() / self.int8.median())
    }

    fn engines(&self) -> Vec<(&'static str, &Timing)> {
        let mut engines = vec![("tract f32", &self.tract), ("int8", &self.int8)];
        if let Some(ort) = &self.onnxruntime {
            engines.push(("onnxruntime f32", &ort.f32));
            engines.push(("onnxruntime int8 (dynamic)", &ort.int8_dynamic));
        }
        engines
    }

    /// The report as text for people.
    pub fn text(&self) -> String {
        let mut lines = Vec::new();
        if self.debug_build {
            lines.push(
                "WARNING: this is a debug build (debug assertions on): timings are only meaningful \
                 from `cargo build --release`"
                    .to_string(),
            );
        }
        lines.push(format!(
            "bino {} bench: one {}x{} band on (I, I), {} tokens, {:.3} GMAC per encoder pass",
            self.version,
            self.width,
            self.height,
            self.tokens,
            self.macs as f64 / 1e9
        ));
        lines.push(format!(
            "cpu: {}; AVX2: cpu {}, binary {}; int8 kernels: {}; threads: 1 (process threads after runs: {})",
            self.cpu.as_deref().unwrap_or("unknown"),
            yes_no(self.cpu_has_avx2),
            yes_no(self.built_with_avx2),
            self.x86_kernels,
            self.process_threads.map_or("unknown".to_string(), |n| n.to_string())
        ));
        for (name, timing) in self.engines() {
            lines.push(format!(
                "{name:<26} median {:>9.2} ms  min {:>9.2} ms  {:>6.2} GMAC/s  ({} runs)",
                timing.median() * 1e3,
                timing.min() * 1e3,
                self.macs as f64 / timing.median() / 1e9,
                timing.runs.len()
            ));
        }
        if let Some(all) = &self.all_cores {
            lines.push(format!(
                "{:<26} median {:>9.2} ms a round of {} bands: {:.2} ms a band, {:.2} GMAC/s",
                format!("int8, {} threads at once", all.threads),
                all.rounds.median() * 1e3,
                all.threads,
                all.per_band() * 1e3,
                all.gmac_per_s(self.macs)
            ));
        }
        lines.push(format!("tract / int8 (medians): {:.2}x", self.speedup()));
        if let Some(ratio) = self.ort_int8_speedup() {
            lines.push(format!("onnxruntime int8 / int8 (medians): {ratio:.2}x"));
        }
        lines.join("\n")
    }

    /// The report as JSON.
    pub fn to_json(&self) -> String {
        let json = BenchJson {
            tool: "bino bench",
            version: &self.version,
            onnx: self.onnx.display().to_string(),
            blob: self.blob.display().to_string(),
            blob_sha256: &self.blob_sha256,
            width: self.width,
            height: self.height,
            tokens: self.tokens,
            macs: self.macs,
            cpu: self.cpu.as_deref(),
            built_with_avx2: self.built_with_avx2,
            cpu_has_avx2: self.cpu_has_avx2,
            x86_kernels: self.x86_kernels,
            debug_build: self.debug_build,
            threads: 1,
            process_threads: self.process_threads,
            tract_f32: self.tract.json(self.macs),
            int8: self.int8.json(self.macs),
            tract_over_int8: self.speedup(),
            onnxruntime_f32: self.onnxruntime.as_ref().map(|o| o.f32.json(self.macs)),
            onnxruntime_int8_dynamic: self.onnxruntime.as_ref().map(|o| o.int8_dynamic.json(self.macs)),
            onnxruntime_int8_over_int8: self.ort_int8_speedup(),
            int8_all_cores: self.all_cores.as_ref().map(|a| a.json(self.macs)),
        };
        serde_json::to_string_pretty(&json).expect("plain structs serialise")
    }
}

// The report's JSON: provenance, then each engine's timing (field order is the file's order).
#[derive(Serialize)]
struct BenchJson<'a> {
    tool: &'static str,
    version: &'a str,
    onnx: String,
    blob: String,
    blob_sha256: &'a str,
    width: usize,
    height: usize,
    tokens: usize,
    macs: u64,
    cpu: Option<&'a str>,
    built_with_avx2: bool,
    cpu_has_avx2: bool,
    x86_kernels: &'a str,
    debug_build: bool,
    threads: usize,
    process_threads: Option<usize>,
    tract_f32: TimingJson<'a>,
    int8: TimingJson<'a>,
    tract_over_int8: f64,
    onnxruntime_f32: Option<TimingJson<'a>>,
    onnxruntime_int8_dynamic: Option<TimingJson<'a>>,
    onnxruntime_int8_over_int8: Option<f64>,
    int8_all_cores: Option<all_cores::AllCoresJson<'a>>,
}

fn yes_no(v: bool) -> &'static str {
    if v {
        "yes"
    } else {
        "no"
    }
}

/// The host CPU's model name from `/proc/cpuinfo`, if there is one.
pub fn cpu_model() -> Option<String> {
    let info = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    info.lines()
        .find(|l| l.starts_with("model name") || l.starts_with("Model"))
        .and_then(|l| l.split_once(':'))
        .map(|(_, v)| v.trim().to_string())
}

/// The kernels the int8 engine runs now: `avx512-vnni`, `avx2` or `portable` on x86 (chosen
/// at run time from the CPU), `dsp` / `mve` on Cortex-M.
pub fn x86_kernels() -> &'static str {
    bino_core::kernels::dispatch::active().name()
}

/// Keeps the int8 engine on its AVX2 kernels (`off`), or lets it use AVX-512 VNNI where the
/// CPU has it, for this process.
pub fn allow_vnni(on: bool) {
    use bino_core::kernels::dispatch::{limit, Isa};
    limit(if on { Isa::Avx512Vnni } else { Isa::Avx2 });
}

fn cpu_has_avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

// Threads of this process (Linux: entries of /proc/self/task).
fn process_threads() -> Option<usize> {
    std::fs::read_dir("/proc/self/task").ok().map(|d| d.count())
}

// One warm-up run of every engine, then `runs` rounds in which every engine runs once. Each
// engine returns its run's seconds.
type Engine<'a> = Box<dyn FnMut() -> Result<f64> + 'a>;

fn time_rounds(runs: usize, engines: &mut [(&str, Engine<'_>)]) -> Result<Vec<Timing>> {
    for (name, engine) in engines.iter_mut() {
        engine().with_context(|| format!("{name}: warm-up run"))?;
    }
    let mut timings = vec![
        Timing {
            runs: Vec::with_capacity(runs)
        };
        engines.len()
    ];
    for _ in 0..runs {
        for ((name, engine), timing) in engines.iter_mut().zip(timings.iter_mut()) {
            timing
                .runs
                .push(engine().with_context(|| format!("{name}: timed run"))?);
        }
    }
    Ok(timings)
}

pub(crate) fn timed(run: impl FnOnce() -> Result<()>) -> Result<f64> {
    let started = Instant::now();
    run()?;
    Ok(started.elapsed().as_secs_f64())
}

/// Times both engines; `note` is told what is being timed as it starts.
pub fn bench(opts: &BenchOptions, mut note: impl FnMut(&str)) -> Result<BenchReport> {
    ensure!(opts.runs >= 1, "--runs must be at least 1");
    ensure!(opts.threads >= 1, "--threads must be at least 1");
    if opts.no_vnni {
        allow_vnni(false);
    }
    let width = opts
        .profile
        .width()
        .with_context(|| format!("bench needs a fixed-width profile (w160 or w320), not {}", opts.profile))?;
    let height = BAND_ROWS;
    let pixels = synthetic::default_scene(width, height).left.pixels;

    let int8 = Int8Model::load(&opts.blob)?;
    let encoder = int8.encoder()?;
    ensure!(
        width <= encoder.max_width(),
        "the blob supports bands up to {} px wide, the profile needs {width}",
        encoder.max_width()
    );
    let mut tract = OnnxModel::load(&opts.onnx, "tokens", 2)
        .context("the encoder is exported by `python -m bino_train.export` (inputs left, right)")?;
    // The same pixels for both engines: the int8 codes p, tract p / 255.
    let input: Tensor = tract_ndarray::Array4::from_shape_fn((1, 3, height, width), |(_, _, y, x)| {
        pixels[y * width + x] as f32 / 255.0
    })
    .into();

    // The plan for this shape is built on the first call, before the warm-up.
    note("tract f32: plan");
    tract.run(vec![input.clone(), input.clone()])?;
    let band = GrayBand::new(&pixels, width, height).map_err(anyhow::Error::msg)?;
    let mut arena = vec![0u8; arena_bytes(height, width)];
    let out_len = (height / PATCH_H) * (width / PATCH_W) * DIM;
    let mut out = vec![0i8; out_len];
    let mut ort = if opts.onnxruntime {
        note("onnxruntime: load, quantise, warm up");
        let env = TrainPython::locate("onnxruntime", "--no-onnxruntime")?;
        Some(OrtServer::start(&env, &opts.onnx, &pixels, width, height)?)
    } else {
        None
    };
    let mut round = (opts.threads > 1).then(|| Round::new(encoder, opts.threads, arena_bytes(height, width), out_len));
    note("every engine: warm-up, then timed rounds");
    let mut engines: Vec<(&str, Engine<'_>)> = vec![
        (
            "tract f32",
            Box::new(|| {
                let inputs = vec![input.clone(), input.clone()];
                timed(|| tract.run(inputs).map(|_| ()))
            }),
        ),
        (
            "int8",
            Box::new(|| {
                timed(|| {
                    encoder
                        .describe(band, &mut arena, &mut out, &mut NoProbe)
                        .map(|_| ())
                        .map_err(anyhow::Error::msg)
                })
            }),
        ),
    ];
    if let Some(server) = ort.as_mut() {
        let server = std::cell::RefCell::new(server);
        let server = std::rc::Rc::new(server);
        let (f32_server, int8_server) = (server.clone(), server);
        engines.push((
            "onnxruntime f32",
            Box::new(move || f32_server.borrow_mut().time(OrtSession::F32)),
        ));
        engines.push((
            "onnxruntime int8",
            Box::new(move || int8_server.borrow_mut().time(OrtSession::Int8Dynamic)),
        ));
    }
    if let Some(round) = round.as_mut() {
        engines.push(("int8, all cores", Box::new(move || round.run(band))));
    }
    let mut timings = time_rounds(opts.runs, &mut engines)?;
    drop(engines);
    let all_cores = if opts.threads > 1 {
        timings.pop().map(|rounds| AllCores {
            threads: opts.threads,
            rounds,
        })
    } else {
        None
    };
    let mut timings = timings.into_iter();
    let (Some(tract_timing), Some(int8_timing)) = (timings.next(), timings.next()) else {
        bail!("bench: missing timings");
    };
    let onnxruntime = match (timings.next(), timings.next()) {
        (Some(f32), Some(int8_dynamic)) => Some(OrtTimings { f32, int8_dynamic }),
        _ => None,
    };
    drop(ort);

    let tokens = (height / PATCH_H) * 2 * (width / PATCH_W);
    Ok(BenchReport {
        version: env!("CARGO_PKG_VERSION").to_string(),
        onnx: opts.onnx.clone(),
        blob: opts.blob.clone(),
        blob_sha256: sha256_hex(int8.bytes()),
        width,
        height,
        tokens,
        macs: encoder_macs(height / PATCH_H, 2 * (width / PATCH_W), encoder.weights().span()),
        cpu: cpu_model(),
        built_with_avx2: cfg!(target_feature = "avx2"),
        cpu_has_avx2: cpu_has_avx2(),
        x86_kernels: x86_kernels(),
        debug_build: cfg!(debug_assertions),
        process_threads: process_threads(),
        tract: tract_timing,
        int8: int8_timing,
        onnxruntime,
        all_cores,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mac_count_of_a_48x160_band() {
        // 960 tokens: embed 960*16*128, per block 960*(49152+16384+122880) + 2*960^2*128.
        let n = 960u64;
        let expected = n * 16 * 128 + 7 * (n * (128 * 384 + 128 * 128 + 128 * 480 * 2) + 2 * n * n * 128);
        assert_eq!(encoder_macs(12, 80, AttentionSpan::Band), expected);
        assert_eq!(expected, 2_919_628_800);
        // Attention within each token row: every query reads its row's 80 keys, not 960.
        let saved = 7 * 2 * n * (960 - 80) * 128;
        assert_eq!(encoder_macs(12, 80, AttentionSpan::Row), expected - saved);
    }

    #[test]
    fn median_and_min() {
        let t = Timing {
            runs: vec![3.0, 1.0, 2.0, 10.0],
        };
        assert_eq!((t.median(), t.min()), (2.5, 1.0));
        let odd = Timing {
            runs: vec![5.0, 1.0, 4.0],
        };
        assert_eq!(odd.median(), 4.0);
    }

    #[test]
    fn rounds_take_turns_after_one_warm_up_each() {
        let order = std::cell::RefCell::new(Vec::new());
        let mut engines: Vec<(&str, Engine<'_>)> = vec![
            (
                "a",
                Box::new(|| {
                    order.borrow_mut().push('a');
                    Ok(1.0)
                }),
            ),
            (
                "b",
                Box::new(|| {
                    order.borrow_mut().push('b');
                    Ok(2.0)
                }),
            ),
        ];
        let timings = time_rounds(3, &mut engines).unwrap();
        drop(engines);
        assert_eq!(order.into_inner().iter().collect::<String>(), "abababab");
        assert_eq!(timings[0].runs, [1.0; 3]);
        assert_eq!(timings[1].runs, [2.0; 3]);
    }

    #[test]
    fn a_failing_engine_is_named() {
        let mut engines: Vec<(&str, Engine<'_>)> = vec![("flaky", Box::new(|| bail!("no device")))];
        let err = time_rounds(1, &mut engines).unwrap_err();
        assert_eq!(format!("{err:#}"), "flaky: warm-up run: no device");
    }
}
