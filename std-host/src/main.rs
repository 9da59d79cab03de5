//! `bino`: the BINO edge command line.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use anyhow::{bail, ensure, Context, Result};
use bino_host::bench::{bench, BenchOptions};
use bino_host::compare::{compare, CompareOptions};
use bino_host::eval::DEFAULT_MAX_COLS;
use bino_host::image_io::{load_gray, GrayImage};
use bino_host::int8::Int8Model;
use bino_host::npy::Array;
use bino_host::pairs::{read_index, Split};
use bino_host::profile::{Profile, View};
use bino_host::quantize::{quantize, QuantizeOptions};
use bino_host::reference::{FeatureMap, ReferenceEncoder};
use bino_host::reference_head::ReferenceHead;
use bino_host::{npz, synthetic};
use clap::error::ErrorKind;
use clap::{CommandFactory, Parser, Subcommand};

/// BINO edge: a binocular ViT stereo encoder for edge boards, host tools.
#[derive(Parser)]
#[command(version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Run the float ONNX reference on a pair; write tokens and descriptor maps as .npz.
    ///
    /// Arrays in the archive (float32, C order; open with numpy.load):
    /// `left`, `right` (H, W) the views after the profile, gray in [0, 1];
    /// `tokens` (H/4, W/2, 128) the de-positioned fused token grid of (left, right);
    /// `desc_left`, `desc_right` (H/4, W/4, 128) the descriptor maps (encoder on (I, I),
    /// phase-averaged); with --head also `disparity` (H/4, W/4) in patch columns. Without
    /// --left/--right a built-in procedural scene (160x96) is used.
    Reference {
        /// Left image (PNG, PPM/PGM or JPEG; gray or colour).
        #[arg(long, requires = "right")]
        left: Option<PathBuf>,
        /// Right image, the same size as the left.
        #[arg(long, requires = "left")]
        right: Option<PathBuf>,
        /// Resolution profile of EVAL.md: w160, w320 or native.
        #[arg(long, default_value = "w160")]
        profile: Profile,
        /// Encoder exported by `python -m bino_train.export`.
        #[arg(long, default_value = "weights/bino_encoder.onnx")]
        onnx: PathBuf,
        /// Shared head exported by `python -m bino_train.head`; adds `disparity` (H/4, W/4),
        /// in patch columns, to the archive.
        #[arg(long)]
        head: Option<PathBuf>,
        /// Output archive (.npz).
        #[arg(long)]
        out: PathBuf,
    },
    /// The int8 pipeline on the built-in stereo scene (no data needed): encoder on both views,
    /// no-linkage matching, SGM and the shared head (also head+lr and head+lr+ref, its pixel
    /// refinement), scored against the scene's known disparity;
    /// writes the pair, the disparity maps, the error maps and report.json to --out.
    Demo {
        /// Int8 weight blob (default: the one shipped in weights/).
        #[arg(long, default_value = bino_host::demo::DEFAULT_BLOB)]
        blob: PathBuf,
        /// Output folder.
        #[arg(long, default_value = "out/demo")]
        out: PathBuf,
        /// Scene width in pixels (multiple of 4).
        #[arg(long, default_value_t = 320)]
        width: usize,
        /// Scene height in pixels (multiple of 4; taller than 48 runs overlapping bands).
        #[arg(long, default_value_t = 96)]
        height: usize,
        /// Disparity candidates of the no-linkage readout, in patch columns.
        #[arg(long, default_value_t = DEFAULT_MAX_COLS)]
        max_cols: usize,
        /// SGM penalty for a one-column change (cost units: 4096 = cosine 1).
        #[arg(long, default_value_t = bino_host::demo::DEFAULT_PENALTIES.p1)]
        sgm_p1: u16,
        /// SGM penalty for a larger jump.
        #[arg(long, default_value_t = bino_host::demo::DEFAULT_PENALTIES.p2)]
        sgm_p2: u16,
    },
    /// The board, simulated: the pair is fed row by row into the band buffer as a camera
    /// delivers it, the int8 pipeline runs in one arena, and each disparity row is drawn
    /// (embedded-graphics) on an RGB565 display with a status line (host fps, arena use, image
    /// size); the display is saved as display.png in --out. Without --left/--right the
    /// built-in 320x96 scene is used.
    Sim {
        /// Left view (PNG, PPM/PGM or JPEG; colour becomes gray).
        #[arg(long, requires = "right")]
        left: Option<PathBuf>,
        /// Right view, same size.
        #[arg(long, requires = "left")]
        right: Option<PathBuf>,
        /// Resolution profile of --left/--right: w160, w320 or native.
        #[arg(long, default_value = "w320")]
        profile: Profile,
        /// Int8 weight blob.
        #[arg(long, default_value = bino_host::demo::DEFAULT_BLOB)]
        blob: PathBuf,
        /// Readout drawn: nolink, sgm or head (cells their left-right check rejects are dark),
        /// or nolink+lr, sgm+lr, head+lr (those cells filled from the left, as `bino eval`
        /// scores), each token row as the pipeline streams it; or a +ref readout, its refined
        /// pixel rows as the pipeline's refinement stage streams them. The default is `bino run`'s.
        #[arg(long, default_value = "sgm+lr+ref")]
        readout: bino_host::readout::Readout,
        /// Disparity candidates of nolink and sgm, in patch columns.
        #[arg(long, default_value_t = 16)]
        max_cols: usize,
        /// SGM penalty for a one-column change (cost units: 4096 = cosine 1).
        #[arg(long, default_value_t = bino_host::demo::DEFAULT_PENALTIES.p1)]
        sgm_p1: u16,
        /// SGM penalty for a larger jump.
        #[arg(long, default_value_t = bino_host::demo::DEFAULT_PENALTIES.p2)]
        sgm_p2: u16,
        /// Left-right check tolerance, in patch columns.
        #[arg(long, default_value_t = 1.0)]
        lr_max_diff: f32,
        /// Display size, WIDTHxHEIGHT.
        #[arg(long, default_value = "320x240")]
        display: bino_host::sim::display::DisplaySize,
        /// Frames to run (the camera delivers the pair again each time); fps from the median.
        #[arg(long, default_value_t = 1)]
        frames: usize,
        /// Output folder.
        #[arg(long, default_value = "out/sim")]
        out: PathBuf,
    },
    /// Quantise the float ONNX models into the int8 weight blob the engine runs.
    ///
    /// Weights: symmetric int8 per output channel. Activation formats come from the float
    /// encoder's intermediate tensors (tract) on bands of train-split pairs only: per-channel
    /// 0.01/99.99 percentiles for the residual stream, MSE-optimal clipping elsewhere
    /// (docs/int8-model.md).
    Quantize {
        /// Float encoder (`python -m bino_train.export`, with or without `--intermediates`):
        /// calibration reads its per-stage tensors by value name.
        #[arg(long, default_value = "weights/bino_encoder.onnx")]
        onnx: PathBuf,
        /// Float shared head (`python -m bino_train.head`); quantised into the same blob.
        #[arg(long)]
        head: Option<PathBuf>,
        /// Train pairs whose descriptor maps calibrate the head.
        #[arg(long, default_value_t = 16)]
        head_calib_pairs: usize,
        /// Folder with PAIRS.tsv; only `split = train` pairs are read.
        #[arg(long, default_value = "../shared/data")]
        calib: PathBuf,
        /// Train pairs to calibrate on (both views, one band each; spread over the split).
        #[arg(long, default_value_t = 64)]
        calib_pairs: usize,
        /// Resolution profile of the calibration bands.
        #[arg(long, default_value = "w160")]
        profile: Profile,
        /// Widest band the blob supports, in pixels.
        #[arg(long, default_value_t = 640)]
        max_width: usize,
        /// Output blob.
        #[arg(long, default_value = "weights/bino_int8.bin")]
        out: PathBuf,
    },
    /// List the pairs of a data folder's PAIRS.tsv.
    Pairs {
        /// Folder holding PAIRS.tsv.
        #[arg(long, default_value = "../shared/data")]
        data: PathBuf,
        /// Only this split (train or eval).
        #[arg(long)]
        split: Option<Split>,
    },
    /// Compare the float encoder (tract-onnx) with the int8 engine on eval pairs.
    ///
    /// Per view and band: the cosine of the residual stream after the embedding and after each
    /// block's attention and MLP halves (the float model runs on the engine's own 8-bit pixels
    /// / 255, so only the engines differ). Per view: the descriptor maps' cosine (float on the
    /// exact view). Per pair: integer WTA disparity agreement and the EVAL.md metrics of the
    /// no-linkage readout of both, upsampled and refined (nolink+ref; with --head also head and
    /// head+ref). Prints the means with the targets (descriptor cosine >= 0.99,
    /// WTA agreement >= 98 %, int8 epe at most 3 % above float); progress on stderr.
    Compare {
        /// Folder with PAIRS.tsv.
        #[arg(long, default_value = "../shared/data")]
        data: PathBuf,
        /// Split to compare on: only eval (the metrics need ground truth).
        #[arg(long, default_value = "eval")]
        split: String,
        /// Resolution profile of EVAL.md: w160, w320 or native.
        #[arg(long, default_value = "w160")]
        profile: Profile,
        /// Float encoder (`python -m bino_train.export`; `--intermediates` not required).
        #[arg(long, default_value = "weights/bino_encoder.onnx")]
        onnx: PathBuf,
        /// Int8 weight blob quantised from it (`bino quantize`).
        #[arg(long, default_value = "weights/bino_int8.bin")]
        blob: PathBuf,
        /// Float shared head: also compare the int8 head's logits and disparity with it.
        #[arg(long)]
        head: Option<PathBuf>,
        /// Also write every number (per pair and mean) and the inputs' provenance as JSON.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Disparity candidates of the no-linkage readout, in patch columns.
        #[arg(long, default_value_t = DEFAULT_MAX_COLS)]
        max_cols: usize,
        /// Only the first N pairs of the split.
        #[arg(long)]
        limit: Option<usize>,
    },
    /// Score the readouts (nolink, sgm, head, each also +lr, each of those also +ref) on the
    /// eval split, int8 (the core pipeline) and f32, EVAL.md metrics per pair and mean,
    /// StereoSGBM in the same run; with --nuisance also with the right view degraded.
    Eval {
        /// Folder with PAIRS.tsv.
        #[arg(long, default_value = "../shared/data")]
        data: PathBuf,
        /// Split: eval (the metrics need ground truth).
        #[arg(long, default_value = "eval")]
        split: String,
        /// Resolution profile of EVAL.md: w160, w320 or native.
        #[arg(long, default_value = "w160")]
        profile: Profile,
        /// Int8 weight blob.
        #[arg(long, default_value = "weights/bino_int8.bin")]
        blob: PathBuf,
        /// Float encoder (ONNX), for --precision f32.
        #[arg(long, default_value = "weights/bino_encoder.onnx")]
        onnx: PathBuf,
        /// Float shared head (ONNX), for --precision f32 with the head readout.
        #[arg(long, default_value = "weights/bino_head.onnx")]
        head_onnx: PathBuf,
        /// Precisions (repeat or comma-separate): int8 (the core pipeline), f32 (tract and the
        /// float twins of the readouts).
        #[arg(long, value_delimiter = ',', default_value = "int8,f32")]
        precision: Vec<bino_host::readout_eval::Precision>,
        /// Readouts to score (repeat or comma-separate): nolink, sgm, head, each optionally
        /// with +lr (cells the method's own left-right check rejects filled from the left),
        /// then optionally +ref (pixels by the integer refinement instead of bilinear
        /// upsampling). Default: all twelve, each unrefined then refined.
        #[arg(
            long,
            value_delimiter = ',',
            default_value = "nolink,nolink+ref,nolink+lr,nolink+lr+ref,sgm,sgm+ref,sgm+lr,sgm+lr+ref,head,head+ref,head+lr,head+lr+ref"
        )]
        readout: Vec<bino_host::readout::Readout>,
        /// Left-right check tolerance, in patch columns.
        #[arg(long, default_value_t = 1.0)]
        lr_max_diff: f32,
        /// Skip StereoSGBM (it runs in the project's Python environment, OpenCV).
        #[arg(long)]
        no_sgbm: bool,
        /// Disparity candidates of nolink and sgm, in patch columns.
        #[arg(long, default_value_t = DEFAULT_MAX_COLS)]
        max_cols: usize,
        /// SGM penalty for a one-column change (cost units: 4096 = cosine 1).
        #[arg(long, default_value_t = bino_host::demo::DEFAULT_PENALTIES.p1)]
        sgm_p1: u16,
        /// SGM penalty for a larger jump.
        #[arg(long, default_value_t = bino_host::demo::DEFAULT_PENALTIES.p2)]
        sgm_p2: u16,
        /// Also write every number as JSON.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Only the first N pairs of the split.
        #[arg(long)]
        limit: Option<usize>,
        /// Also score every readout and StereoSGBM with the RIGHT view degraded (repeat or
        /// comma-separate; the clean run is always reported too). Applied to the profile's
        /// 8-bit right view after resizing, the same images for every method: gain (v * 0.7 +
        /// 20, clamped), gamma (255 (v/255)^0.6), noise (gaussian, sigma 8 grey levels), blur
        /// (5x5 box, radius 2 px), occlude (mid-grey rectangles, each at most 1/5 of the width
        /// and height, until at least 20 % of the area is covered). The whole set runs once
        /// more per nuisance: five nuisances take six times as long.
        #[arg(long, value_delimiter = ',')]
        nuisance: Vec<bino_host::nuisance::Nuisance>,
        /// Seed of the nuisances' noise and occlusions (mixed with each pair's id).
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Also the one-view occlusion benchmark (the paper's): the RIGHT view covered by
        /// token-aligned mid-grey blocks over these % of its area (comma-separated, rising,
        /// nested: each severity's blocks contain the milder ones'), every readout and
        /// StereoSGBM scored at each; reports clean, each severity, OccAUC and the rise at the
        /// largest. The whole set runs once more per severity.
        #[arg(long, value_delimiter = ',')]
        occlude: Vec<u32>,
    },
    /// The int8 pipeline on a rectified pair of any size: writes disparity.png (colour),
    /// disparity.pfm (float32 pixel disparities, dense, the readout exactly as `bino eval` scores
    /// it: refined, the readout's +ref, unless --refine off) and lr_mask.png (pixels the
    /// readout's method keeps in its left-right check) to --out.
    Run {
        /// Left view (PNG, PPM/PGM or JPEG; colour becomes gray).
        #[arg(long)]
        left: PathBuf,
        /// Right view, same size.
        #[arg(long)]
        right: PathBuf,
        /// Resolution profile: w160, w320 or native (sides must be multiples of 4).
        #[arg(long, default_value = "w320")]
        profile: Profile,
        /// Int8 weight blob.
        #[arg(long, default_value = bino_host::demo::DEFAULT_BLOB)]
        blob: PathBuf,
        /// Readout: nolink, sgm or head, each optionally with +lr (cells the method's own
        /// left-right check rejects filled from the nearest kept cell to their left), then
        /// optionally +ref (the same as --refine on). The default, sgm+lr, has the lowest
        /// unrefined eval-split error at the default profile, w320 (head+lr at w160; README).
        #[arg(long, default_value = "sgm+lr")]
        readout: bino_host::readout::Readout,
        /// Pixel refinement of the readout: on (its +ref: census 5x5 search +-2 px around the
        /// upsampled token disparity, bino_core::refine) or off (the token grid upsampled
        /// bilinearly, as before the refinement).
        #[arg(long, value_enum, default_value = "on")]
        refine: bino_host::run::Refine,
        /// Disparity candidates of nolink and sgm, in patch columns.
        #[arg(long, default_value_t = 16)]
        max_cols: usize,
        /// SGM penalty for a one-column change (cost units: 4096 = cosine 1).
        #[arg(long, default_value_t = bino_host::demo::DEFAULT_PENALTIES.p1)]
        sgm_p1: u16,
        /// SGM penalty for a larger jump.
        #[arg(long, default_value_t = bino_host::demo::DEFAULT_PENALTIES.p2)]
        sgm_p2: u16,
        /// Left-right check tolerance, in patch columns.
        #[arg(long, default_value_t = 1.0)]
        lr_max_diff: f32,
        /// Output folder.
        #[arg(long, default_value = "out/run")]
        out: PathBuf,
    },
    /// Time tract-onnx (f32) and the int8 engine on the same band, single-threaded.
    ///
    /// One 48-row band of the built-in scene at the profile's width, encoded on (I, I) by both
    /// (the descriptor pathway); one warm-up run, then --runs timed runs each. Prints medians,
    /// minima, GMAC/s and the ratio. Build with --release: a debug build's timings mean little.
    Bench {
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
        /// Also write the timings as JSON.
        #[arg(long)]
        json: Option<PathBuf>,
    },
    /// The firmware's memory and compute budget (STM32Cube.AI / TFLite Micro style): weights and
    /// code flash, arena per stage, stack peak, RAM, executed instructions per stage per core and
    /// milliseconds at a stated clock (M55 400 MHz, M7 480 MHz, 1 instruction per cycle assumed),
    /// against the targets. Reads the runs of `scripts/firmware.sh` and the firmware ELF.
    Budget {
        /// Folder with the firmware runs (m55.json, m7.json).
        #[arg(long, default_value = "firmware-sim/measured")]
        firmware: PathBuf,
        /// Also write the report as JSON.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Also write the report as Markdown.
        #[arg(long)]
        md: Option<PathBuf>,
        /// Also draw a bar chart of memory and instructions per stage (PNG).
        #[arg(long)]
        png: Option<PathBuf>,
    },
}

fn main() -> ExitCode {
    match run(Cli::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: Cli) -> Result<()> {
    match cli.command {
        Command::Demo {
            blob,
            out,
            width,
            height,
            max_cols,
            sgm_p1,
            sgm_p2,
        } => demo_command(&bino_host::demo::DemoOptions {
            blob,
            out,
            width,
            height,
            max_cols,
            penalties: bino_core::sgm::Penalties { p1: sgm_p1, p2: sgm_p2 },
        }),
        Command::Sim {
            left,
            right,
            profile,
            blob,
            readout,
            max_cols,
            sgm_p1,
            sgm_p2,
            lr_max_diff,
            display,
            frames,
            out,
        } => sim_command(&bino_host::sim::SimOptions {
            pair: left.zip(right),
            profile,
            blob,
            readout,
            max_cols,
            penalties: bino_core::sgm::Penalties { p1: sgm_p1, p2: sgm_p2 },
            lr_max_diff,
            display,
            frames,
            out,
        }),
        Command::Run {
            left,
            right,
            profile,
            blob,
            readout,
            refine,
            max_cols,
            sgm_p1,
            sgm_p2,
            lr_max_diff,
            out,
        } => run_command(&bino_host::run::RunOptions {
            left,
            right,
            profile,
            blob,
            readout: refine.apply(readout).unwrap_or_else(|msg| usage_error("run", msg)),
            max_cols,
            penalties: bino_core::sgm::Penalties { p1: sgm_p1, p2: sgm_p2 },
            lr_max_diff,
            out,
        }),
        Command::Eval {
            data,
            split,
            profile,
            blob,
            onnx,
            head_onnx,
            precision,
            readout,
            lr_max_diff,
            no_sgbm,
            max_cols,
            sgm_p1,
            sgm_p2,
            json,
            limit,
            nuisance,
            seed,
            occlude,
        } => eval_command(
            &bino_host::readout_eval::EvalOptions {
                data,
                split,
                profile,
                blob,
                onnx,
                head_onnx,
                precisions: precision,
                readouts: readout,
                max_cols,
                penalties: bino_core::sgm::Penalties { p1: sgm_p1, p2: sgm_p2 },
                lr_max_diff,
                sgbm: !no_sgbm,
                limit,
                nuisances: nuisance,
                seed,
                occlusions: occlude,
            },
            json.as_deref(),
        ),
        Command::Compare {
            data,
            split,
            profile,
            onnx,
            blob,
            head,
            json,
            max_cols,
            limit,
        } => {
            let opts = CompareOptions {
                onnx,
                blob,
                head,
                data,
                split,
                profile,
                max_cols,
                limit,
            };
            compare_command(&opts, json.as_deref())
        }
        Command::Bench {
            onnx,
            blob,
            profile,
            threads,
            runs,
            json,
        } => {
            let opts = BenchOptions {
                onnx,
                blob,
                profile,
                threads,
                runs,
            };
            bench_command(&opts, json.as_deref())
        }
        Command::Reference {
            left,
            right,
            profile,
            onnx,
            head,
            out,
        } => reference(left.zip(right), profile, &onnx, head.as_deref(), &out),
        Command::Pairs { data, split } => list_pairs(&data, split),
        Command::Budget {
            firmware,
            json,
            md,
            png,
        } => {
            let report = bino_host::budget::run_budget(&bino_host::budget::BudgetOptions {
                firmware,
                json,
                md,
                png,
            })?;
            print!("{report}");
            Ok(())
        }
        Command::Quantize {
            onnx,
            head,
            head_calib_pairs,
            calib,
            calib_pairs,
            profile,
            max_width,
            out,
        } => {
            let opts = QuantizeOptions {
                encoder: onnx,
                head,
                head_calib_pairs,
                data: calib,
                profile,
                calib_pairs,
                max_width,
            };
            quantize_command(&opts, &out)
        }
    }
}

/// Exits with clap's usage error (code 2) for `subcommand`, as a bad value would.
fn usage_error(subcommand: &str, msg: String) -> ! {
    let mut cli = Cli::command().bin_name("bino");
    cli.build();
    match cli.find_subcommand_mut(subcommand) {
        Some(sub) => sub.error(ErrorKind::ArgumentConflict, msg).exit(),
        None => cli.error(ErrorKind::ArgumentConflict, msg).exit(),
    }
}

fn demo_command(opts: &bino_host::demo::DemoOptions) -> Result<()> {
    let started = std::time::Instant::now();
    let report = bino_host::demo::run_demo(opts, |step| {
        eprintln!("[{:5.1} s] {step} ...", started.elapsed().as_secs_f64());
    })?;
    println!(
        "BINO int8 demo: built-in scene {}x{}, blob {}",
        report.width,
        report.height,
        opts.blob.display()
    );
    println!("{:<12} {:>9} {:>9} {:>9}", "readout", "epe px", "bad1tok %", "bad2 %");
    for r in &report.readouts {
        println!(
            "{:<12} {:>9.3} {:>9.2} {:>9.2}",
            r.name, r.metrics.epe, r.metrics.bad1tok, r.metrics.bad2
        );
    }
    for (step, took) in &report.timings {
        println!("  {step}: {:.1} ms", took.as_secs_f64() * 1e3);
    }
    println!(
        "arena: encoder {} bytes per 48-row band, head {} bytes (both fixed, sized by const fn)",
        report.encoder_arena_bytes, report.head_arena_bytes
    );
    for file in &report.files {
        println!("wrote {}", file.display());
    }
    Ok(())
}

fn sim_command(opts: &bino_host::sim::SimOptions) -> Result<()> {
    let started = Instant::now();
    let report = bino_host::sim::run_sim(opts, |step| {
        eprintln!("[{:5.1} s] {step} ...", started.elapsed().as_secs_f64());
    })?;
    let stages: Vec<String> = report
        .stage_times
        .iter()
        .filter(|(_, took)| !took.is_zero())
        .map(|(name, took)| format!("{name} {:.1}", took.as_secs_f64() * 1e3))
        .collect();
    eprintln!("last frame, ms by stage: {}", stages.join(", "));
    let p = &report.pipeline;
    println!(
        "bino sim: {} at {}x{}, {} readout; sensor rows read {}/{} (each once), {} band(s), {} rows drawn; \
         host {:.2} fps ({:.1} ms/frame, median of {}; not a board figure); arena {} of {} bytes; display {} -> {}",
        report.source,
        report.width,
        report.height,
        opts.readout.name(),
        report.rows_delivered,
        report.height,
        p.bands,
        report.rows_drawn,
        report.host_fps(),
        report.frame_time().as_secs_f64() * 1e3,
        report.frame_times.len(),
        p.arena_used,
        report.arena_bytes,
        opts.display,
        report.png.display()
    );
    Ok(())
}

fn run_command(opts: &bino_host::run::RunOptions) -> Result<()> {
    let started = Instant::now();
    let report = bino_host::run::run_pair(opts, |step| {
        eprintln!("[{:5.1} s] {step} ...", started.elapsed().as_secs_f64());
    })?;
    println!(
        "bino run: {} readout at {}x{} ({}), {:.1} % of pixels left-right consistent",
        opts.readout.name(),
        report.width,
        report.height,
        opts.profile,
        report.density
    );
    for (step, took) in &report.timings {
        println!("  {step}: {:.1} ms", took.as_secs_f64() * 1e3);
    }
    let p = &report.pipeline;
    let kept = |cells: usize| 100.0 * cells as f64 / (p.rows * p.cols).max(1) as f64;
    println!(
        "  {} band(s); left-right check keeps {:.1} % of WTA and {:.1} % of SGM cells (LRkeep)",
        p.bands,
        kept(p.wta_kept),
        kept(p.sgm_kept)
    );
    println!("  time inside the pipeline by stage:");
    for (stage, took) in &report.stage_times {
        if !took.is_zero() {
            println!("    {:<12} {:8.1} ms", stage.name(), took.as_secs_f64() * 1e3);
        }
    }
    println!(
        "arena: {} bytes used of {} (pixel band {}, descriptors {}, encoder {}, readout streams {})",
        p.arena_used, report.arena_bytes, p.pixels, p.descriptors, p.encoder, p.streams
    );
    for file in &report.files {
        println!("wrote {}", file.display());
    }
    Ok(())
}

fn eval_command(opts: &bino_host::readout_eval::EvalOptions, json: Option<&Path>) -> Result<()> {
    let report = bino_host::readout_eval::evaluate(opts, |done, total, pair| {
        let mut epe: Vec<String> = opts
            .rows()
            .iter()
            .zip(&pair.scores)
            .map(|((p, r), s)| format!("{} {} {:.3}", p.name(), r.name(), s.metrics.epe))
            .collect();
        if let Some(m) = pair.sgbm {
            epe.push(format!("SGBM {:.3}", m.epe));
        }
        let under = pair.nuisance.map_or(String::new(), |n| format!(" under {}", n.name()));
        eprintln!(
            "[{done}/{total}] {}{under}: epe {} ({:.1} s)",
            pair.pair_id,
            epe.join(", "),
            pair.elapsed.as_secs_f64()
        );
    })?;
    println!("{}", report.table());
    if let Some(path) = json {
        bino_host::files::write_atomic(path, |file| Ok(file.write_all(report.to_json().as_bytes())?))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

fn compare_command(opts: &CompareOptions, json: Option<&Path>) -> Result<()> {
    let report = compare(opts, |done, total, pair| {
        let v = &pair.values;
        eprintln!(
            "[{done}/{total}] {}: descriptor cosine {:.4}, WTA agreement {:.1} %, epe {:.3} float / {:.3} int8 \
             ({:.1} s)",
            pair.pair_id,
            v.descriptor_cosine,
            v.wta_agreement,
            v.float.epe,
            v.int8.epe,
            pair.elapsed.as_secs_f64()
        );
    })?;
    println!("{}", report.table());
    if let Some(path) = json {
        bino_host::files::write_atomic(path, |file| Ok(file.write_all(report.to_json().as_bytes())?))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

fn bench_command(opts: &BenchOptions, json: Option<&Path>) -> Result<()> {
    let report = bench(opts, |what| eprintln!("timing {what}"))?;
    if report.debug_build {
        eprintln!("WARNING: debug build: timings are only meaningful with --release");
    }
    println!("{}", report.text());
    if let Some(path) = json {
        bino_host::files::write_atomic(path, |file| Ok(file.write_all(report.to_json().as_bytes())?))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

fn quantize_command(opts: &QuantizeOptions, out: &Path) -> Result<()> {
    let started = Instant::now();
    let (blob, report) = quantize(opts, |done, total| {
        eprint!("\rcalibrating: band {done}/{total}");
        if done == total {
            eprintln!();
        }
    })?;
    if let Some(choice) = &report.head_choice {
        eprintln!("head correlation format, mean |int8 - float| disparity on the calibration maps (train split):");
        for (i, (label, error)) in choice.tried.iter().enumerate() {
            let mark = if i == choice.chosen { "  <- chosen" } else { "" };
            eprintln!("  {label:<20} {error:.4} patch columns{mark}");
        }
    }
    // The blob must load in the engine before it is written.
    Int8Model::from_bytes(blob.clone(), &out.display().to_string())?;
    bino_host::files::write_atomic(out, |file| Ok(file.write_all(&blob)?))?;
    println!(
        "{}: {} bytes from {} ({} calibration bands, {:.1} s)",
        out.display(),
        blob.len(),
        opts.encoder.display(),
        report.bands,
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

fn reference(
    files: Option<(PathBuf, PathBuf)>,
    profile: Profile,
    onnx: &Path,
    head: Option<&Path>,
    out: &Path,
) -> Result<()> {
    ensure!(
        out.extension().is_some_and(|e| e == "npz"),
        "output {} must end in .npz (the reference writes a NumPy archive)",
        out.display()
    );
    let (left, right, source) = match files {
        Some((l, r)) => {
            let (left, right) = (load_gray(&l)?, load_gray(&r)?);
            let source = format!("{} + {}", l.display(), r.display());
            (left, right, source)
        }
        None => {
            let scene = synthetic::default_scene(160, 96);
            (scene.left, scene.right, "built-in procedural scene".to_string())
        }
    };
    let (left, right) = apply_profile(&left, &right, profile, &source)?;
    let mut encoder = ReferenceEncoder::load(onnx)?;
    let mut head = head.map(ReferenceHead::load).transpose()?;
    let started = Instant::now();
    let tokens = encoder.tokens(&left, &right)?;
    let desc_left = encoder.descriptors(&left)?;
    let desc_right = encoder.descriptors(&right)?;
    let elapsed = started.elapsed();
    let disparity = head
        .as_mut()
        .map(|h| h.disparity(&desc_left, &desc_right))
        .transpose()?;

    let view = |v: &View| Array::new(vec![v.height, v.width], v.pixels.clone());
    let map = |m: &FeatureMap| Array::new(vec![m.rows, m.cols, m.dim], m.data.clone());
    let mut arrays = vec![
        ("left", view(&left)?),
        ("right", view(&right)?),
        ("tokens", map(&tokens)?),
        ("desc_left", map(&desc_left)?),
        ("desc_right", map(&desc_right)?),
    ];
    if let Some(d) = &disparity {
        arrays.push(("disparity", Array::new(vec![d.rows, d.cols], d.data.clone())?));
    }
    let named: Vec<(&str, &Array)> = arrays.iter().map(|(n, a)| (*n, a)).collect();
    bino_host::files::write_atomic(out, |file| npz::write(file, &named))?;
    println!(
        "{source}: {}x{} at profile {profile}; tokens {}x{}x{}, descriptors {}x{}x{}; \
         3 encoder passes in {:.2} s (tract-onnx, {})",
        left.width,
        left.height,
        tokens.rows,
        tokens.cols,
        tokens.dim,
        desc_left.rows,
        desc_left.cols,
        desc_left.dim,
        elapsed.as_secs_f64(),
        encoder.path().display()
    );
    println!("wrote {}", out.display());
    Ok(())
}

fn apply_profile(left: &GrayImage, right: &GrayImage, profile: Profile, source: &str) -> Result<(View, View)> {
    if (left.width, left.height) != (right.width, right.height) {
        bail!(
            "{source}: left is {}x{} but right is {}x{}; a rectified pair has views of one size",
            left.width,
            left.height,
            right.width,
            right.height
        );
    }
    let apply = |v: &GrayImage| profile.apply(v).with_context(|| source.to_string());
    Ok((apply(left)?, apply(right)?))
}

fn list_pairs(data: &Path, wanted: Option<Split>) -> Result<()> {
    let pairs = read_index(data)?;
    let mut out = std::io::stdout().lock();
    for pair in pairs.iter().filter(|p| wanted.is_none_or(|s| p.split == s)) {
        let line = writeln!(
            out,
            "{}\t{}\t{}\t{}x{}\t{}",
            pair.pair_id,
            pair.split,
            pair.dataset,
            pair.width,
            pair.height,
            pair.left.display()
        );
        match line {
            // A closed pipe (`bino pairs | head`) just ends the listing.
            Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => return Ok(()),
            other => other?,
        }
    }
    Ok(())
}
