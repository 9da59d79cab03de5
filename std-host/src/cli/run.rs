//! `bino run`: the int8 pipeline on a rectified pair of any size.

use std::path::PathBuf;

use anyhow::Result;
use bino_host::io::checkout;
use bino_host::readout::Method;
use bino_host::run::RunOptions;
use clap::Args;

use super::args::{LeftRightCheck, PairCandidates, PairProfile, ReadoutPathway, SgmPenalties};
use super::progress::Progress;

/// Compute the disparity of a rectified pair of any size with the int8 pipeline.
///
/// Writes disparity.png (colour, with its colour bar), disparity.pfm (float32 disparities in
/// the input's pixels, the readout as `bino eval` scores it: refined, the readout's +ref, unless
/// --refine off; dense unless --invalid inf) and valid.png (pixels whose cell the readout's own
/// check keeps and whose view has texture) to --out, all at the input's size; --profile chooses
/// the size it is computed at.
#[derive(Args)]
pub struct RunArgs {
    /// Left view (PNG, PPM/PGM or JPEG; colour becomes gray).
    #[arg(long)]
    left: PathBuf,
    /// Right view, same size.
    #[arg(long)]
    right: PathBuf,
    #[command(flatten)]
    profile: PairProfile,
    /// Int8 weight blob; the default is the checkout's shipped one.
    #[arg(long, default_value_os_t = checkout::path(checkout::BLOB))]
    blob: PathBuf,
    /// Readout: a method (see below), optionally +lr, then optionally +ref.
    ///
    /// Methods: nolink, sgm, head, fuse, census, fuse-census, fuse-all.
    ///
    /// +lr: cells the method's own left-right check rejects filled by the lower of their nearest
    /// kept neighbours left and right; +ref: the same as --refine on. fuse+lr: the head and SGM,
    /// their weighted mean where both pass their checks, the one that passes elsewhere. census: census matching of
    /// the pixels with SGM (no encoder); fuse-census: the head fused with it as fuse+lr fuses
    /// the head and SGM (on either pathway); fuse-all: the head fused with the census, then with
    /// the SGM (export pathway). Default: census+lr, no encoder (the most accurate on the real
    /// labeled validation pairs); with --pathway, that pathway's learned readout: fuse-all+lr on
    /// export, fuse-census+lr on native (the board's learned preset).
    #[arg(long)]
    readout: Option<bino_host::readout::Readout>,
    #[command(flatten)]
    pathway: ReadoutPathway,
    /// Pixel refinement of the readout: on (its +ref) or off (the token grid upsampled).
    ///
    /// on: the views' sharpness equalised where one is defocused, then a census 5x5 search
    /// around the upsampled token disparity, +-2 px below 200 px of width and +-4 at 320
    /// (round(width / 80)); off: the token grid upsampled bilinearly.
    #[arg(long, value_enum, default_value = "on")]
    refine: bino_host::run::Refine,
    #[command(flatten)]
    candidates: PairCandidates,
    #[command(flatten)]
    sgm: SgmPenalties,
    #[command(flatten)]
    lr: LeftRightCheck,
    /// What disparity.pfm holds at invalid pixels: keep (the readout's value) or inf.
    ///
    /// Invalid: the readout's own check rejects the pixel's cell, or the view has no texture
    /// there (valid.png). inf is Middlebury's convention for unknown disparity.
    #[arg(long, value_enum, default_value = "keep")]
    invalid: bino_host::run::InvalidPixels,
    /// Threads for the encoder's passes (default: every core); the output is the same.
    ///
    /// Each thread encodes a band ahead of the streaming pipeline, which then replays the
    /// passes: the output is bit for bit that of one thread.
    #[arg(long)]
    threads: Option<usize>,
    /// Output folder.
    #[arg(long, default_value = "out/run")]
    out: PathBuf,
}

/// Runs the verb.
pub fn run(args: RunArgs) -> Result<()> {
    let (chosen, pathway) = bino_host::readout::pathway::resolve(args.readout, args.pathway.pathway);
    let readout = args
        .refine
        .apply(chosen)
        .unwrap_or_else(|msg| super::usage_error("run", msg));
    match args.threads {
        Some(0) => super::usage_error("run", "--threads must be at least 1".to_string()),
        Some(n) => bino_host::int8::pass_cache::set_threads(n),
        None => {}
    }
    let opts = RunOptions {
        left: args.left,
        right: args.right,
        profile: args.profile.profile,
        blob: args.blob,
        readout,
        pathway,
        max_cols: args.candidates.max_cols,
        penalties: args.sgm.penalties(),
        lr_max_diff: args.lr.lr_max_diff,
        invalid: args.invalid,
        out: args.out,
    };
    let progress = Progress::new(false);
    let report = bino_host::run::run_pair(&opts, |step| progress.step(step))?;
    progress.finish();
    // One figure: the valid pixels (valid.png: the readout's own check keeps them, texture).
    let pathway = match opts.readout.method {
        Method::Census => "no encoder".to_string(),
        _ => format!("{} pathway", opts.pathway),
    };
    for warning in &report.warnings {
        eprintln!("warning: {warning}");
    }
    println!(
        "bino run: {} readout, {pathway}, computed at {}x{} ({}), written at {}x{}: {:.1} % of pixels valid",
        opts.readout.name(),
        report.width,
        report.height,
        opts.profile,
        report.output.0,
        report.output.1,
        report.density
    );
    for (step, took) in &report.timings {
        println!("  {step}: {:.1} ms", took.as_secs_f64() * 1e3);
    }
    let p = &report.pipeline;
    println!("  {} band(s)", p.bands);
    println!("  time inside the pipeline by stage:");
    for (stage, took) in &report.stage_times {
        if !took.is_zero() {
            println!("    {:<12} {:8.1} ms", stage.name(), took.as_secs_f64() * 1e3);
        }
    }
    println!(
        "arena: {} bytes used of {} (pixel band {}, descriptors {}, encoder {}, readout streams {}, refinement {})",
        p.arena_used, report.arena_bytes, p.pixels, p.descriptors, p.encoder, p.streams, p.refine
    );
    for file in &report.files {
        println!("wrote {}", file.display());
    }
    Ok(())
}
