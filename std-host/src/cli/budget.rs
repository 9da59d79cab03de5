//! `bino budget`: the firmware's memory and compute budget from the firmware runs.

use std::path::PathBuf;

use anyhow::Result;
use bino_host::budget::{run_budget, BudgetOptions};
use bino_host::io::checkout;
use clap::Args;

/// Report the firmware's memory and compute budget against its targets.
///
/// STM32Cube.AI / TFLite Micro style: weights and code flash, arena per stage, stack peak,
/// RAM, executed instructions per stage per core and milliseconds at a stated clock (M55
/// 400 MHz, M7 480 MHz, 1 instruction per cycle assumed), against the targets. Reads the runs
/// of `scripts/firmware.sh` and the firmware ELF.
#[derive(Args)]
pub struct BudgetArgs {
    /// Folder with the firmware runs (m55.json, m7.json); the default is the checkout's.
    #[arg(long, default_value_os_t = checkout::path(checkout::FIRMWARE_RUNS))]
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
}

/// Runs the verb (well under a second: no progress bar).
pub fn run(args: BudgetArgs) -> Result<()> {
    let report = run_budget(&BudgetOptions {
        firmware: args.firmware,
        json: args.json,
        md: args.md,
        png: args.png,
    })?;
    print!("{report}");
    Ok(())
}
