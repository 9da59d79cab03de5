//! `bino budget`: the firmware's memory and compute budget, in the manner of STM32Cube.AI's and
//! TFLite Micro's reports — flash for weights and code, RAM (arena per stage, stack), executed
//! instructions per stage per core and the time they would take at a stated clock.
//!
//! Every number comes from the firmware runs (`scripts/firmware.sh` writes `<core>.json` per
//! core: the QEMU plugin's instruction counts, the firmware's own arena and stack measurements)
//! and from the firmware ELF's section headers (read here when the ELF the run used is still
//! there, same SHA-256, else the sizes the run recorded from it with `llvm-size`). Nothing is estimated except the time,
//! which assumes a stated number of instructions per cycle: instructions are not cycles. Beside
//! it, the cycle model ([`cycles`]) prices each stage's instructions per class in cycles per core:
//! a documented model, reported as such.

use std::path::{Path, PathBuf};

use anyhow::Result;

/// The bar chart: memory per stage (arena in use, stack peak) and instructions per stage per
/// core (log scale: the encoder passes are 10^4 times the smallest stages).
mod chart;
pub mod cycles;
mod elf;
pub mod frame;
mod markdown;
pub mod presets;
mod report;
mod runs;
mod verdict;

pub use elf::elf_sections;
pub use frame::{Frame, FrameOptions, FramesReport};
pub use markdown::{frames_markdown, grouped, markdown, presets_markdown};
pub use presets::{PresetFrame, PresetsReport};
pub use report::{Band, BudgetReport, CoreBudget, CoreCycles, StageBudget, SCHEMA};
pub use runs::{
    e7_frame_stage, frame_run_stage, load_runs, BandJson, CoreRun, FrameKind, FrameRun, SectionSource, Sections,
    StageRun, CENSUS320_PREFIX, CENSUS_PREFIX, FRAME320_PREFIX, FRAME_PREFIX, NATIVE_PREFIX,
};
pub use verdict::{verdicts, Verdict};

/// The targets.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Targets {
    /// Arena, bytes (the AN547's 512 KiB DTCM).
    pub arena_bytes: u64,
    /// Weight blob, bytes.
    pub weights_bytes: u64,
    /// Cortex-M55: executed instructions per band pair.
    pub m55_instructions: u64,
    /// Cortex-M7: seconds per band pair at its clock.
    pub m7_seconds: f64,
}

/// 512 KiB arena, 1.5 MiB weights, 800M M55 instructions, 8 s on the M7.
pub const TARGETS: Targets = Targets {
    arena_bytes: 512 * 1024,
    weights_bytes: 3 * 512 * 1024,
    m55_instructions: 800_000_000,
    m7_seconds: 8.0,
};

/// The fast preset's target: at least this many frames per second of this frame on the M55 at
/// its clock, IPC 1 (4 fps of 160x120: at most 100M instructions per frame at 400 MHz).
pub const FAST_PRESET_TARGET: (Frame, f64) = (Frame::new(120, 160), 4.0);

/// Executed instructions per export band pair each core's kernels were tuned against.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ExportCeilings {
    /// Cortex-M55.
    pub m55: u64,
    /// Cortex-M7.
    pub m7: u64,
}

/// 1.3G instructions on the M55, 8G on the M7.
pub const EXPORT_CEILINGS: ExportCeilings = ExportCeilings {
    m55: 1_300_000_000,
    m7: 8_000_000_000,
};

/// Issue 14: the pixel refinement (stage `refine`) costs at most this share of one encoder
/// pass (stage `encode_left`) in executed instructions, on every core.
pub const REFINE_SHARE_OF_ENCODER: f64 = 0.10;

/// One native band pair with the head's left-right check (one encoder pass on (L, R), the
/// native head, the right view read from its logits) costs at most this share of the export
/// pathway's band pair in executed instructions, on every core.
pub const NATIVE_SHARE_OF_EXPORT: f64 = 0.55;

/// A core's clock and the instructions-per-cycle assumption that turns counts into time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Clock {
    /// Clock in MHz.
    pub mhz: f64,
    /// Instructions retired per cycle, assumed.
    pub ipc: f64,
}

impl Clock {
    /// Milliseconds `instructions` take at this clock.
    pub fn ms(&self, instructions: u64) -> f64 {
        instructions as f64 / (self.mhz * 1e3 * self.ipc)
    }

    /// Milliseconds `cycles` take at this clock (no IPC: they are cycles already).
    pub fn cycles_ms(&self, cycles: f64) -> f64 {
        cycles / (self.mhz * 1e3)
    }
}

/// The clock a core is reported at: M55 400 MHz, M7 480 MHz, both at 1 instruction per cycle.
pub fn clock(core: &str) -> Clock {
    match core {
        "m7" => Clock { mhz: 480.0, ipc: 1.0 },
        _ => Clock { mhz: 400.0, ipc: 1.0 },
    }
}

/// The report as JSON, with the default frames and no second band width.
pub fn to_json(runs: &[CoreRun]) -> Result<BudgetReport> {
    let opts = FrameOptions::default();
    let frames = FramesReport::new(runs, &[], &opts)?;
    let presets = PresetsReport::new(runs, &frames, &opts.frames)?;
    Ok(BudgetReport::new(runs, frames, presets))
}

/// Options of `bino budget`.
#[derive(Debug, Clone, PartialEq)]
pub struct BudgetOptions {
    /// Folder with the runs' `<core>.json`.
    pub firmware: PathBuf,
    /// Write the JSON report here.
    pub json: Option<PathBuf>,
    /// Write the Markdown report here.
    pub md: Option<PathBuf>,
    /// Write the bar chart here.
    pub png: Option<PathBuf>,
    /// The frames section's frames and clock.
    pub frames: FrameOptions,
}

/// Where the second measured band width lives, inside the firmware folder.
pub const SECOND_WIDTH_DIR: &str = "small";

/// Runs `bino budget`: returns the Markdown report after writing the files asked for.
pub fn run_budget(opts: &BudgetOptions) -> Result<String> {
    let runs = load_runs(&opts.firmware)?;
    // The same firmware at a second band width (`scripts/firmware.sh --band small`), when there.
    let second_dir = opts.firmware.join(SECOND_WIDTH_DIR);
    let second = if second_dir.is_dir() {
        load_runs(&second_dir)?
    } else {
        Vec::new()
    };
    let frames = FramesReport::new(&runs, &second, &opts.frames)?;
    let presets = PresetsReport::new(&runs, &frames, &opts.frames.frames)?;
    let md = markdown(&runs) + &presets_markdown(&presets) + &frames_markdown(&runs, &frames);
    if let Some(path) = &opts.json {
        let report = BudgetReport::new(&runs, frames, presets);
        let text = serde_json::to_string_pretty(&report)? + "\n";
        write_file(path, text.as_bytes())?;
    }
    if let Some(path) = &opts.md {
        write_file(path, md.as_bytes())?;
    }
    if let Some(path) = &opts.png {
        crate::io::files::save_png(&chart::draw(&runs)?.into(), path)?;
    }
    Ok(md)
}

fn write_file(path: &Path, bytes: &[u8]) -> Result<()> {
    crate::io::files::write_bytes(path, bytes)
}

#[cfg(test)]
mod tests;
