//! `bino budget`: the firmware's memory and compute budget from the firmware runs.

use std::path::PathBuf;

use anyhow::Result;
use bino_host::budget::frame::{Frame, DEFAULT_FRAMES};
use bino_host::budget::{run_budget, BudgetOptions, FrameOptions};
use bino_host::io::checkout;
use clap::Args;

/// Report the firmware's memory and compute budget against its targets.
///
/// STM32Cube.AI / TFLite Micro style: weights and code flash, arena per stage, stack peak,
/// RAM, executed instructions per stage per core and milliseconds at a stated clock (M55
/// 400 MHz, M7 480 MHz, 1 instruction per cycle assumed), against the targets. Reads the runs
/// of `scripts/firmware.sh` and the firmware ELF.
///
/// Frames: per core and pathway, whole frames (160x120 and 320x240, and any `--frame`) from
/// the band pair's stages scaled by their work, with the exact arena; the rule is checked
/// against the 48x32 run in `<firmware>/small` when it is there.
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
    /// Also report a frame of this size, `WxH` pixels (repeatable).
    ///
    /// Width and height multiples of 4; 160x120 and 320x240 are always reported.
    #[arg(long = "frame", value_name = "WxH", value_parser = parse_frame)]
    frames: Vec<Frame>,
    /// Clock of every core for the frame figures, MHz (default: M55 400, M7 480).
    #[arg(long, value_name = "F", value_parser = parse_clock, allow_negative_numbers = true)]
    clock_mhz: Option<f64>,
}

fn parse_frame(s: &str) -> Result<Frame, String> {
    s.parse::<Frame>().map_err(|e| format!("{e:#}"))
}

fn parse_clock(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(mhz) if mhz.is_finite() && mhz > 0.0 => Ok(mhz),
        Ok(_) => Err(format!("{s}: expected a clock above 0 MHz")),
        Err(_) => Err(format!("{s}: expected a number of MHz")),
    }
}

/// Runs the verb (well under a second: no progress bar).
pub fn run(args: BudgetArgs) -> Result<()> {
    let report = run_budget(&BudgetOptions {
        firmware: args.firmware,
        json: args.json,
        md: args.md,
        png: args.png,
        frames: FrameOptions {
            frames: frames_to_report(args.frames),
            clock_mhz: args.clock_mhz,
        },
    })?;
    print!("{report}");
    Ok(())
}

/// The default frames, then the asked-for ones not among them.
fn frames_to_report(asked: Vec<Frame>) -> Vec<Frame> {
    let mut frames = DEFAULT_FRAMES.to_vec();
    for f in asked {
        if !frames.contains(&f) {
            frames.push(f);
        }
    }
    frames
}
