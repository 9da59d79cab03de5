//! The budget as JSON (`bino budget --json`, schema `bino-budget/1`): typed, serialised with
//! serde. Fields are declared in alphabetical order, the order the file has always had its
//! keys in, so reports of different runs diff line by line.

use serde::Serialize;

use super::{clock, verdicts, CoreRun, SectionSource, Verdict};

/// Schema name and version of the file.
pub const SCHEMA: &str = "bino-budget/1";

/// The whole report.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BudgetReport {
    /// One entry per firmware run, in the order the runs were read (M55, M7).
    pub cores: Vec<CoreBudget>,
    /// What the instruction counts and times are (and are not).
    pub note: &'static str,
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
    /// Executed instructions of one band pair (every stage but `load`).
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
    /// Executed instructions.
    pub instructions: u64,
    /// Stage name.
    pub name: String,
    /// Deepest stack use during the stage, bytes.
    pub stack_peak_bytes: u64,
}

impl BudgetReport {
    /// The report of `runs`.
    pub fn new(runs: &[CoreRun]) -> Self {
        Self {
            cores: runs.iter().map(CoreBudget::new).collect(),
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
            board: r.board.clone(),
            clock_mhz: c.mhz,
            code_flash_bytes: r.sections.code_flash(),
            core: r.core.clone(),
            cpu: r.cpu.clone(),
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
                    instructions: s.instructions,
                    name: s.name.clone(),
                    stack_peak_bytes: s.stack_peak,
                })
                .collect(),
            weights_flash_bytes: r.sections.weights,
        }
    }
}
