//! `bino sim`: the board simulated on the host, the display saved as a PNG.

use std::path::PathBuf;

use anyhow::Result;
use bino_host::io::checkout;
use bino_host::sim::SimOptions;
use clap::Args;

use super::args::{LeftRightCheck, PairCandidates, PairProfile, ReadoutPathway, SgmPenalties};
use super::progress::Progress;

/// Simulate the board on the host: camera rows in, display out.
///
/// The pair is fed row by row into the band buffer as a camera delivers it, the int8 pipeline
/// runs in one arena, and each disparity row is drawn (embedded-graphics) on an RGB565 display
/// with a status line (host fps, arena use, image size); the display is saved as display.png in
/// --out. Without --left/--right the built-in 320x96 scene is used.
#[derive(Args)]
pub struct SimArgs {
    /// Left view (PNG, PPM/PGM or JPEG; colour becomes gray).
    #[arg(long, requires = "right")]
    left: Option<PathBuf>,
    /// Right view, same size.
    #[arg(long, requires = "left")]
    right: Option<PathBuf>,
    #[command(flatten)]
    profile: PairProfile,
    /// Int8 weight blob; the default is the checkout's shipped one.
    #[arg(long, default_value_os_t = checkout::path(checkout::BLOB))]
    blob: PathBuf,
    /// Readout drawn (a method, optionally +lr, then optionally +ref); default `bino run`'s.
    ///
    /// Methods: nolink, sgm, head, census, each optionally +lr, and the checked fusions fuse+lr
    /// and fuse-all+lr (native pathway: fuse-census+lr).
    ///
    /// nolink, sgm, head, census: cells their left-right check rejects are dark; +lr: those
    /// cells filled from their lower kept neighbour, as `bino eval` scores; each token row as the pipeline streams
    /// it. A +ref readout draws its refined pixel rows as the pipeline's refinement stage
    /// streams them. The default is `bino run`'s, refined: census+lr+ref (no encoder); with
    /// --pathway, that pathway's (export: fuse-all+lr+ref; native, the board's learned preset:
    /// fuse-census+lr+ref).
    #[arg(long)]
    readout: Option<bino_host::readout::Readout>,
    #[command(flatten)]
    pathway: ReadoutPathway,
    #[command(flatten)]
    candidates: PairCandidates,
    #[command(flatten)]
    sgm: SgmPenalties,
    #[command(flatten)]
    lr: LeftRightCheck,
    /// Display size, WIDTHxHEIGHT.
    #[arg(long, default_value = "320x240")]
    display: bino_host::sim::display::DisplaySize,
    /// Frames to run (the camera delivers the pair again each time); fps from the median.
    #[arg(long, default_value_t = 1)]
    frames: usize,
    /// Output folder.
    #[arg(long, default_value = "out/sim")]
    out: PathBuf,
}

/// Runs the verb.
pub fn run(args: SimArgs) -> Result<()> {
    let (readout, pathway) = match bino_host::readout::pathway::resolve(args.readout, args.pathway.pathway) {
        // The default readouts are refined, as `bino run`'s.
        (readout, pathway) if args.readout.is_none() => (readout.refined(true), pathway),
        chosen => chosen,
    };
    let opts = SimOptions {
        pair: args.left.zip(args.right),
        profile: args.profile.profile,
        blob: args.blob,
        readout,
        pathway,
        max_cols: args.candidates.max_cols,
        penalties: args.sgm.penalties(),
        lr_max_diff: args.lr.lr_max_diff,
        display: args.display,
        frames: args.frames,
        out: args.out,
    };
    let progress = Progress::new(false);
    let report = bino_host::sim::run_sim(&opts, |step| progress.step(step))?;
    progress.finish();
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
    if let Some(digest) = report.refined_digest {
        // The firmware logs the same CRC as `output=refined digest=...` for its readout.
        println!("refined rows digest {digest:08x} (CRC-32 of the Q8 rows, as the firmware's refined output)");
    }
    Ok(())
}
