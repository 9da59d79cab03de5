//! The budget as JSON (`bino budget --json`, schema `bino-budget/1`): typed, serialised with
//! serde. Fields are declared in alphabetical order, the order the file has always had its
//! keys in, so reports of different runs diff line by line.

use std::collections::BTreeMap;

use serde::Serialize;

use super::frame::FramesReport;
use super::presets::PresetsReport;
use super::{clock, cycles, verdicts, CoreRun, SectionSource, Verdict};

/// Schema name and version of the file. Fields are only ever added (`presets` is the latest), so
/// readers of version 1 read every report.
pub const SCHEMA: &str = "bino-budget/1";

/// The whole report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BudgetReport {
    /// One entry per firmware run, in the order the runs were read (M55, M7).
    pub cores: Vec<CoreBudget>,
    /// Whole frames scaled from the band pair, per core and pathway, and the scaling rule's
    /// check against a second measured band width.
    pub frames: FramesReport,
    /// What the instruction counts and times are (and are not).
    pub note: &'static str,
    /// The board's presets per frame and core: each counted on the firmware's whole frame of
    /// that size where the core ran one, else scaled (each says which).
    pub presets: PresetsReport,
    /// [`SCHEMA`].
    pub schema: &'static str,
    /// The targets judged on the runs.
    pub targets: Vec<Verdict>,
}

/// One core's budget.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CoreBudget {
    /// Arena high-water reported by the pipeline, bytes.
    pub arena_high_water_bytes: u64,
    /// Static arena (the core's `const fn`), bytes.
    pub arena_static_bytes: u64,
    /// Instructions per cycle assumed for the times.
    pub assumed_instructions_per_cycle: f64,
    /// Band size in pixels.
    pub band: Band,
    /// Milliseconds of one band pair at the stated clock and IPC.
    pub band_pair_estimated_ms: f64,
    /// Executed instructions of one band pair on the export pathway (every stage but `load`
    /// and the native run's `native_*`).
    pub band_pair_instructions: u64,
    /// QEMU board.
    pub board: String,
    /// Clock the times assume, MHz.
    pub clock_mhz: f64,
    /// Code, constants and the `.data` image in flash, bytes.
    pub code_flash_bytes: u64,
    /// `m55` or `m7`.
    pub core: String,
    /// QEMU CPU model.
    pub cpu: String,
    /// The cycle model's band pair; `null` when the run has no class counts (runs measured
    /// before the plugin classified instructions).
    pub cycle_model: Option<CoreCycles>,
    /// Executed instructions of one native band pair, its head's check included (the
    /// `native_*` stages; absent for a firmware that ran only the export pathway).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub native_band_pair_instructions: Option<u64>,
    /// Whether every output was bit-identical to the host's.
    pub outputs_bit_identical: bool,
    /// QEMU wall time, seconds (`null` when the run did not record it).
    pub qemu_wall_seconds: f64,
    /// RAM the link reserves, bytes.
    pub ram_reserved_bytes: u64,
    /// RAM measured in use, bytes.
    pub ram_used_bytes: u64,
    /// The refinement's share of the arena, bytes (`null` when the run did not report it).
    pub refine_arena_bytes: Option<u64>,
    /// Where the section sizes came from: the ELF's path, or the run's record.
    pub sections_from: String,
    /// Deepest stack use of any stage, bytes.
    pub stack_peak_bytes: u64,
    /// Stack reserved by the linker script, bytes.
    pub stack_reserved_bytes: u64,
    /// The stages in run order.
    pub stages: Vec<StageBudget>,
    /// The blob in flash, bytes.
    pub weights_flash_bytes: u64,
}

/// One core's band pair under the cycle model (`firmware-sim/qemu-plugin/CYCLES.md`).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CoreCycles {
    /// Modelled cycles of one band pair: the sum over its stages of count x cost per class.
    pub band_pair_modelled_cycles: f64,
    /// Those cycles in milliseconds at the core's clock.
    pub band_pair_modelled_ms: f64,
    /// Modelled cycles of one band pair on the native pathway (the board's learned preset), when the
    /// firmware ran it.
    pub native_band_pair_modelled_cycles: Option<f64>,
    /// Those cycles in milliseconds at the core's clock.
    pub native_band_pair_modelled_ms: Option<f64>,
    /// The band pair's instructions per class and the adjustments' counts.
    pub class_counts: BTreeMap<String, u64>,
    /// Cycles per instruction of each class, or per adjustment event, on this core.
    pub costs: BTreeMap<String, f64>,
    /// What the figures are.
    pub note: &'static str,
}

/// Band height and width, pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Band {
    /// Rows.
    pub height: u64,
    /// Columns.
    pub width: u64,
}

/// One stage of a core's run.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StageBudget {
    /// Arena in use during the stage, bytes.
    pub arena_in_use_bytes: u64,
    /// Milliseconds at the stated clock and IPC.
    pub estimated_ms: f64,
    /// Executed instructions per class and the cycle model's adjustments (absent when the run
    /// has no class counts).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub instruction_classes: Option<BTreeMap<String, u64>>,
    /// Executed instructions.
    pub instructions: u64,
    /// The cycle model's cycles for the stage (absent without class counts).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub modelled_cycles: Option<f64>,
    /// Those cycles in milliseconds at the core's clock (absent without class counts).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub modelled_ms: Option<f64>,
    /// Stage name.
    pub name: String,
    /// Deepest stack use during the stage, bytes.
    pub stack_peak_bytes: u64,
}

impl BudgetReport {
    /// The report of `runs` with its frames section.
    pub fn new(runs: &[CoreRun], frames: FramesReport, presets: PresetsReport) -> Self {
        Self {
            cores: runs.iter().map(CoreBudget::new).collect(),
            frames,
            presets,
            note: "instructions are executed instructions counted under QEMU, not cycles; estimated_ms assumes \
                   the stated clock and instructions per cycle",
            schema: SCHEMA,
            targets: verdicts(runs),
        }
    }
}

impl CoreBudget {
    fn new(r: &CoreRun) -> Self {
        let c = clock(&r.core);
        Self {
            arena_high_water_bytes: r.arena_used,
            arena_static_bytes: r.arena_bytes,
            assumed_instructions_per_cycle: c.ipc,
            band: Band {
                height: r.band.0,
                width: r.band.1,
            },
            band_pair_estimated_ms: c.ms(r.band_pair_instructions()),
            band_pair_instructions: r.band_pair_instructions(),
            native_band_pair_instructions: r.native_band_pair_instructions(),
            board: r.board.clone(),
            clock_mhz: c.mhz,
            code_flash_bytes: r.sections.code_flash(),
            core: r.core.clone(),
            cpu: r.cpu.clone(),
            cycle_model: r.band_pair_modelled_cycles().map(|n| CoreCycles {
                band_pair_modelled_cycles: n,
                band_pair_modelled_ms: c.cycles_ms(n),
                native_band_pair_modelled_cycles: r.native_band_pair_modelled_cycles(),
                native_band_pair_modelled_ms: r.native_band_pair_modelled_cycles().map(|n| c.cycles_ms(n)),
                class_counts: r.band_pair_class_counts().unwrap_or_default(),
                costs: cycles::cost_table(&r.core)
                    .iter()
                    .map(|k| (k.name.to_string(), k.cycles))
                    .collect(),
                note: "a model, not a measurement: cycles = sum over classes of count x cost; costs and \
                       assumptions in firmware-sim/qemu-plugin/CYCLES.md",
            }),
            outputs_bit_identical: r.passed,
            qemu_wall_seconds: r.qemu_wall_seconds,
            ram_reserved_bytes: r.ram_reserved(),
            ram_used_bytes: r.ram_used(),
            refine_arena_bytes: r.refine_arena,
            sections_from: match &r.section_source {
                SectionSource::Elf(p) => p.display().to_string(),
                SectionSource::Recorded => "recorded in the run's JSON".to_string(),
            },
            stack_peak_bytes: r.stack_peak(),
            stack_reserved_bytes: r.stack_bytes,
            stages: r
                .stages
                .iter()
                .map(|s| StageBudget {
                    arena_in_use_bytes: s.arena_in_use,
                    estimated_ms: c.ms(s.instructions),
                    instruction_classes: s.class_counts(),
                    instructions: s.instructions,
                    modelled_cycles: s.modelled_cycles(&r.core),
                    modelled_ms: s.modelled_cycles(&r.core).map(|n| c.cycles_ms(n)),
                    name: s.name.clone(),
                    stack_peak_bytes: s.stack_peak,
                })
                .collect(),
            weights_flash_bytes: r.sections.weights,
        }
    }
}
