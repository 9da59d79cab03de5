//! `bino demo`: the int8 pipeline on the built-in scene, scored against its known disparity.

use std::path::PathBuf;

use anyhow::Result;
use bino_host::demo::DemoOptions;
use bino_host::io::checkout;
use clap::Args;

use super::args::{Candidates, SgmPenalties, NOLINK_CANDIDATES_HELP};
use super::progress::Progress;

/// Score the int8 pipeline on the built-in scene against its known disparity.
///
/// No data needed: the encoder on both views, no-linkage matching, SGM and the shared head
/// (also head+lr and head+lr+ref, its pixel refinement), then the native pathway, each scored
/// against the scene's known disparity; writes the pair, the disparity maps, the error maps and
/// report.json to --out.
#[derive(Args)]
#[command(mut_arg("max_cols", |a| a.help(NOLINK_CANDIDATES_HELP)))]
pub struct DemoArgs {
    /// Int8 weight blob; the default is the checkout's shipped one.
    #[arg(long, default_value_os_t = checkout::path(checkout::BLOB))]
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
    #[command(flatten)]
    candidates: Candidates,
    #[command(flatten)]
    sgm: SgmPenalties,
}

/// Runs the verb.
pub fn run(args: DemoArgs) -> Result<()> {
    let opts = DemoOptions {
        blob: args.blob,
        out: args.out,
        width: args.width,
        height: args.height,
        max_cols: args.candidates.max_cols,
        penalties: args.sgm.penalties(),
    };
    let progress = Progress::new(false);
    let report = bino_host::demo::run_demo(&opts, |step| progress.step(step))?;
    progress.finish();
    println!(
        "BINO int8 demo: built-in scene {}x{}, blob {}",
        report.width,
        report.height,
        opts.blob.display()
    );
    println!("{:<20} {:>9} {:>9} {:>9}", "readout", "epe px", "bad1tok %", "bad2 %");
    for r in &report.readouts {
        println!(
            "{:<20} {:>9.3} {:>9.2} {:>9.2}",
            r.name, r.metrics.epe, r.metrics.bad1tok, r.metrics.bad2
        );
    }
    for (step, took) in &report.timings {
        println!("  {step}: {:.1} ms", took.as_secs_f64() * 1e3);
    }
    // The arenas the core checks each run against (the firmware's figures at 48x160).
    let arenas: Vec<String> = report
        .arenas
        .iter()
        .map(|(name, bytes)| format!("{name} {bytes} B"))
        .collect();
    println!(
        "arena for the {}x{} scene, refinement included: {}",
        report.width,
        report.height,
        arenas.join(", ")
    );
    for file in &report.files {
        println!("wrote {}", file.display());
    }
    Ok(())
}
