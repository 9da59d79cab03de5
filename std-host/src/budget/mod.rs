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

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context, Result};
use serde::{Deserialize, Serialize};
use serde_json::Value;

pub mod cycles;
mod report;
pub use report::{Band, BudgetReport, CoreBudget, CoreCycles, StageBudget, SCHEMA};

/// Bytes in a KiB.
const KIB: f64 = 1024.0;

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

/// Issue 14: the pixel refinement (stage `refine`) costs at most this share of one encoder
/// pass (stage `encode_left`) in executed instructions, on every core.
pub const REFINE_SHARE_OF_ENCODER: f64 = 0.10;

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

/// One stage of a firmware run, as the run's JSON lists it.
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct StageRun {
    /// Stage name (`load`, `rows`, `encode_left`, ...).
    pub name: String,
    /// Executed instructions.
    pub instructions: u64,
    /// Arena bytes in use during the stage.
    pub arena_in_use: u64,
    /// Deepest stack use during the stage, bytes.
    pub stack_peak: u64,
    /// Executed instructions per class ([`cycles::CLASSES`]), when the run counted them (runs
    /// before the cycle model did not).
    #[serde(default)]
    pub classes: Option<BTreeMap<String, u64>>,
    /// The cycle model's adjustments ([`cycles::ADJUSTMENTS`]), with the classes.
    #[serde(default)]
    pub cycle_adjustments: Option<BTreeMap<String, u64>>,
}

impl StageRun {
    /// Modelled cycles of the stage on `core` (the sum over classes and adjustments of count x
    /// cost), when the run counted classes.
    pub fn modelled_cycles(&self, core: &str) -> Option<f64> {
        let counts = self.class_counts()?;
        cycles::modelled_cycles(cycles::cost_table(core), &counts).ok()
    }

    /// The classes and adjustments in one map, when the run counted them.
    pub fn class_counts(&self) -> Option<BTreeMap<String, u64>> {
        let mut all = self.classes.clone()?;
        all.extend(self.cycle_adjustments.clone().unwrap_or_default());
        Some(all)
    }

    /// Checks the class counts: they add up to the instructions, and every name has a cost.
    fn check_classes(&self, core: &str) -> Result<()> {
        let (Some(classes), Some(counts)) = (&self.classes, self.class_counts()) else {
            return Ok(());
        };
        let sum: u64 = classes.values().sum();
        ensure!(
            sum == self.instructions,
            "stage {}: its instruction classes add up to {sum}, its instructions are {}",
            self.name,
            self.instructions
        );
        cycles::modelled_cycles(cycles::cost_table(core), &counts).with_context(|| format!("stage {}", self.name))?;
        Ok(())
    }
}

/// Section sizes of the firmware ELF that the budget needs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Sections {
    /// `.vector_table + .text + .rodata + .gnu.sgstubs`: code and constants in flash.
    pub code: u64,
    /// `.data`: initialised data (its image in flash, the data in RAM).
    pub data: u64,
    /// `.bss`.
    pub bss: u64,
    /// `.uninit`: the arena (and nothing else in this firmware).
    pub uninit: u64,
    /// `.weights`: the blob in the flash-like region.
    pub weights: u64,
}

impl Sections {
    /// From `(name, size)` pairs.
    pub fn from_named(sections: impl IntoIterator<Item = (String, u64)>) -> Self {
        let mut s = Sections::default();
        for (name, size) in sections {
            match name.as_str() {
                ".vector_table" | ".text" | ".rodata" | ".gnu.sgstubs" => s.code += size,
                ".data" => s.data = size,
                ".bss" => s.bss = size,
                ".uninit" => s.uninit = size,
                ".weights" => s.weights = size,
                _ => {}
            }
        }
        s
    }

    /// Flash for code: code, constants and the `.data` image.
    pub fn code_flash(&self) -> u64 {
        self.code + self.data
    }
}

/// Where the section sizes came from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SectionSource {
    /// Read from this ELF now.
    Elf(PathBuf),
    /// Recorded in the run's JSON (the ELF is gone).
    Recorded,
}

/// One core's firmware run (`<core>.json`).
#[derive(Debug, Clone, PartialEq)]
pub struct CoreRun {
    /// `m55` or `m7`.
    pub core: String,
    /// QEMU CPU model.
    pub cpu: String,
    /// QEMU board.
    pub board: String,
    /// Band height and width in pixels.
    pub band: (u64, u64),
    /// Whether every output was bit-identical to the host's.
    pub passed: bool,
    /// QEMU wall time, seconds.
    pub qemu_wall_seconds: f64,
    /// ELF section sizes.
    pub sections: Sections,
    /// Where they came from.
    pub section_source: SectionSource,
    /// Static arena, bytes (the core's `const fn`).
    pub arena_bytes: u64,
    /// Arena high-water reported by the pipeline.
    pub arena_used: u64,
    /// Stack reserved by the linker script, bytes.
    pub stack_bytes: u64,
    /// Of the arena: the pixel refinement's buffers (`pipeline::refine_bytes`), when the run
    /// reported them.
    pub refine_arena: Option<u64>,
    /// Stages in run order.
    pub stages: Vec<StageRun>,
    /// Instructions before the first stage (reset, arena painting).
    pub startup_instructions: u64,
    /// Instructions outside the stages (digests, stack scans, logging).
    pub outside_instructions: u64,
}

// What the budget reads of a `bino-firmware-run/1` file (`firmware-sim/qemu-plugin/report.py`
// writes it); other fields are ignored.
#[derive(Deserialize)]
struct RunJson {
    core: String,
    cpu: String,
    board: String,
    band: BandJson,
    passed: Option<bool>,
    qemu_wall_seconds: Option<f64>,
    elf: Option<PathBuf>,
    elf_sha256: Option<String>,
    elf_sections: BTreeMap<String, SectionJson>,
    arena_bytes: u64,
    arena_used: u64,
    #[serde(default)]
    arena_breakdown: BTreeMap<String, Option<u64>>,
    stack_bytes: u64,
    stages: Vec<StageRun>,
    startup_instructions: u64,
    outside_instructions: u64,
}

#[derive(Deserialize)]
struct BandJson {
    height: u64,
    width: u64,
}

#[derive(Deserialize)]
struct SectionJson {
    size: u64,
}

/// Stages that run once at boot, not per band pair.
const BOOT_STAGES: [&str; 1] = ["load"];

/// Prefix of the native pathway run's stages (`native_encode_pair`, `native_head`, ...); the
/// others (but `load`) are the export pathway's.
pub const NATIVE_PREFIX: &str = "native_";

/// Issue 15: one native band pair (one encoder pass on (L, R) and the native head) costs at
/// most this share of the export pathway's band pair in executed instructions, on every core.
pub const NATIVE_SHARE_OF_EXPORT: f64 = 0.55;

/// Whether stage `name` is part of the export pathway's band pair.
fn export_band_stage(name: &str) -> bool {
    !BOOT_STAGES.contains(&name) && !name.starts_with(NATIVE_PREFIX)
}

impl CoreRun {
    /// Parses a run's JSON; the ELF it names is read when it still exists.
    pub fn parse(text: &str) -> Result<Self> {
        let v: Value = serde_json::from_str(text).context("not JSON")?;
        let schema = v
            .get("schema")
            .and_then(Value::as_str)
            .context("missing string \"schema\"")?;
        ensure!(schema == "bino-firmware-run/1", "unknown schema {schema:?}");
        let run = RunJson::deserialize(&v).context("not a firmware run")?;
        ensure!(!run.stages.is_empty(), "no stages");
        // A stage the firmware never entered (one of the other pathway's) is not reported.
        let mut run = run;
        run.stages
            .retain(|s| s.instructions > 0 || BOOT_STAGES.contains(&s.name.as_str()));
        for stage in &run.stages {
            stage.check_classes(&run.core)?;
        }
        // The ELF the run used, if it is still there and unchanged (a later build overwrites it).
        let same_elf = run.elf.and_then(|path| {
            let bytes = std::fs::read(&path).ok()?;
            (Some(crate::io::files::sha256_hex(&bytes)) == run.elf_sha256).then_some((path, bytes))
        });
        let (sections, section_source) = match same_elf {
            Some((path, bytes)) => {
                let named = elf_sections(&bytes).with_context(|| format!("{}", path.display()))?;
                (Sections::from_named(named), SectionSource::Elf(path))
            }
            None => {
                let recorded = run.elf_sections.into_iter().map(|(name, s)| (name, s.size));
                (Sections::from_named(recorded), SectionSource::Recorded)
            }
        };
        Ok(Self {
            core: run.core,
            cpu: run.cpu,
            board: run.board,
            band: (run.band.height, run.band.width),
            passed: run.passed.unwrap_or(false),
            qemu_wall_seconds: run.qemu_wall_seconds.unwrap_or(f64::NAN),
            sections,
            section_source,
            arena_bytes: run.arena_bytes,
            arena_used: run.arena_used,
            refine_arena: run.arena_breakdown.get("refine").copied().flatten(),
            stack_bytes: run.stack_bytes,
            stages: run.stages,
            startup_instructions: run.startup_instructions,
            outside_instructions: run.outside_instructions,
        })
    }

    /// Executed instructions of one band pair on the export pathway: every stage but blob
    /// loading and the native run's.
    pub fn band_pair_instructions(&self) -> u64 {
        self.stages
            .iter()
            .filter(|s| export_band_stage(&s.name))
            .map(|s| s.instructions)
            .sum()
    }

    /// Executed instructions of one band pair on the native pathway (its `native_` stages,
    /// the head's left-right check included: the mirrored pass and head), `None` for a firmware
    /// that ran only the export pathway.
    pub fn native_band_pair_instructions(&self) -> Option<u64> {
        let native: Vec<&StageRun> = self
            .stages
            .iter()
            .filter(|s| s.name.starts_with(NATIVE_PREFIX))
            .collect();
        (!native.is_empty()).then(|| native.iter().map(|s| s.instructions).sum())
    }

    /// [`CoreRun::native_band_pair_instructions`] without the check: one encoder pass on
    /// (L, R) and the native head (the stages `native_encode_mirror` and `native_head_mirror`
    /// left out; the refinement of the checked grid stays in).
    pub fn native_one_pass_instructions(&self) -> Option<u64> {
        let check = ["native_encode_mirror", "native_head_mirror"];
        let all = self.native_band_pair_instructions()?;
        Some(
            all - check
                .iter()
                .filter_map(|name| self.stage_instructions(name))
                .sum::<u64>(),
        )
    }

    /// Whether every stage has its instruction classes (runs before the cycle model have none).
    pub fn has_class_counts(&self) -> bool {
        self.stages.iter().all(|s| s.classes.is_some())
    }

    /// Modelled cycles of one band pair (every stage but blob loading), with class counts.
    pub fn band_pair_modelled_cycles(&self) -> Option<f64> {
        self.stages
            .iter()
            .filter(|s| export_band_stage(&s.name))
            .map(|s| s.modelled_cycles(&self.core))
            .sum()
    }

    /// Per class and adjustment, the band pair's counts (every stage but blob loading).
    pub fn band_pair_class_counts(&self) -> Option<BTreeMap<String, u64>> {
        let mut total = BTreeMap::new();
        for s in self.stages.iter().filter(|s| export_band_stage(&s.name)) {
            for (name, n) in s.class_counts()? {
                *total.entry(name).or_insert(0) += n;
            }
        }
        Some(total)
    }

    /// Executed instructions of the stage `name`, when the run has it.
    pub fn stage_instructions(&self, name: &str) -> Option<u64> {
        self.stages.iter().find(|s| s.name == name).map(|s| s.instructions)
    }

    /// Deepest stack use of any stage.
    pub fn stack_peak(&self) -> u64 {
        self.stages.iter().map(|s| s.stack_peak).max().unwrap_or(0)
    }

    /// Highest arena use of any stage.
    pub fn arena_high_water(&self) -> u64 {
        self.stages.iter().map(|s| s.arena_in_use).max().unwrap_or(0)
    }

    /// RAM the link reserves: `.data + .bss + .uninit` (the arena) and the stack budget.
    pub fn ram_reserved(&self) -> u64 {
        self.sections.data + self.sections.bss + self.sections.uninit + self.stack_bytes
    }

    /// RAM measured in use: `.data + .bss`, the arena's high-water and the stack's peak.
    pub fn ram_used(&self) -> u64 {
        self.sections.data + self.sections.bss + self.arena_used + self.stack_peak()
    }
}

/// `(name, size)` of every section of a 32-bit little-endian ELF, from its section headers.
pub fn elf_sections(elf: &[u8]) -> Result<Vec<(String, u64)>> {
    ensure!(elf.get(..4) == Some(b"\x7fELF".as_slice()), "not an ELF file");
    ensure!(
        elf.get(4) == Some(&1) && elf.get(5) == Some(&1),
        "not a 32-bit little-endian ELF"
    );
    let u16_at = |at: usize| -> Result<usize> {
        let b = elf.get(at..at + 2).context("truncated ELF")?;
        Ok(u16::from_le_bytes([b[0], b[1]]) as usize)
    };
    let u32_at = |at: usize| -> Result<usize> {
        let b = elf.get(at..at + 4).context("truncated ELF")?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
    };
    let (shoff, shentsize, shnum, shstrndx) = (u32_at(0x20)?, u16_at(0x2E)?, u16_at(0x30)?, u16_at(0x32)?);
    ensure!(shentsize >= 40, "section header entries of {shentsize} bytes");
    let header = |i: usize| shoff + i * shentsize;
    let names_at = u32_at(header(shstrndx) + 16)?;
    let mut out = Vec::with_capacity(shnum);
    for i in 1..shnum {
        let h = header(i);
        let name_at = names_at + u32_at(h)?;
        let name = elf.get(name_at..).context("section name outside the file")?;
        let end = name.iter().position(|&b| b == 0).context("unterminated section name")?;
        out.push((
            String::from_utf8_lossy(&name[..end]).into_owned(),
            u32_at(h + 20)? as u64,
        ));
    }
    Ok(out)
}

/// The runs in a firmware result folder (`m55.json`, `m7.json`; at least one).
pub fn load_runs(dir: &Path) -> Result<Vec<CoreRun>> {
    let mut runs = Vec::new();
    for core in ["m55", "m7"] {
        let path = dir.join(format!("{core}.json"));
        if !path.exists() {
            continue;
        }
        let text = crate::io::files::read_text(&path, "firmware result")?;
        runs.push(CoreRun::parse(&text).with_context(|| format!("{}", path.display()))?);
    }
    if runs.is_empty() {
        bail!(
            "no firmware results (m55.json, m7.json) in {}; run scripts/firmware.sh first",
            dir.display()
        );
    }
    Ok(runs)
}

/// Whether a target is met, with the figure it was judged on.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Verdict {
    // Declared in the JSON's key order (alphabetical; see `report`).
    /// What was measured.
    pub measured: String,
    /// Met or not.
    pub met: bool,
    /// What the target is.
    pub target: String,
}

/// The targets judged on the runs.
pub fn verdicts(runs: &[CoreRun]) -> Vec<Verdict> {
    let mut out = Vec::new();
    if let Some(r) = runs.first() {
        out.push(Verdict {
            target: format!("weights <= {:.1} MiB", TARGETS.weights_bytes as f64 / KIB / KIB),
            measured: kib(r.sections.weights),
            met: r.sections.weights <= TARGETS.weights_bytes,
        });
        out.push(Verdict {
            target: format!("arena <= {}", kib(TARGETS.arena_bytes)),
            measured: format!("{} (static {})", kib(r.arena_used), kib(r.arena_bytes)),
            met: r.arena_bytes <= TARGETS.arena_bytes,
        });
    }
    for r in runs {
        let n = r.band_pair_instructions();
        let c = clock(&r.core);
        match r.core.as_str() {
            "m55" => out.push(Verdict {
                target: format!(
                    "Cortex-M55 <= {}M instructions per band pair ({:.1} s at {} MHz, IPC {})",
                    TARGETS.m55_instructions / 1_000_000,
                    Clock::ms(&c, TARGETS.m55_instructions) / 1e3,
                    c.mhz,
                    c.ipc
                ),
                measured: format!(
                    "{:.0}M ({:.1}x the target; {:.2} s)",
                    n as f64 / 1e6,
                    n as f64 / TARGETS.m55_instructions as f64,
                    c.ms(n) / 1e3
                ),
                met: n <= TARGETS.m55_instructions,
            }),
            "m7" => out.push(Verdict {
                target: format!(
                    "Cortex-M7 <= {} s per band pair at {} MHz, IPC {}",
                    TARGETS.m7_seconds, c.mhz, c.ipc
                ),
                measured: format!(
                    "{:.2} s ({:.0}M instructions; {:.1}x the target)",
                    c.ms(n) / 1e3,
                    n as f64 / 1e6,
                    c.ms(n) / 1e3 / TARGETS.m7_seconds
                ),
                met: c.ms(n) / 1e3 <= TARGETS.m7_seconds,
            }),
            _ => {}
        }
        if let (Some(one_pass), Some(checked)) = (r.native_one_pass_instructions(), r.native_band_pair_instructions()) {
            let share = one_pass as f64 / n.max(1) as f64;
            out.push(Verdict {
                target: format!(
                    "{} native band pair (one encoder pass on (L, R) + native head) <= {:.0} % of the export pathway's",
                    core_name(&r.core),
                    100.0 * NATIVE_SHARE_OF_EXPORT
                ),
                measured: format!(
                    "{:.0}M ({:.1} % of {:.0}M; with the head's check, a second pass: {:.0}M, {:.1} %)",
                    one_pass as f64 / 1e6,
                    100.0 * share,
                    n as f64 / 1e6,
                    checked as f64 / 1e6,
                    100.0 * checked as f64 / n.max(1) as f64
                ),
                met: share <= NATIVE_SHARE_OF_EXPORT,
            });
        }
        if let (Some(refine), Some(encoder)) = (r.stage_instructions("refine"), r.stage_instructions("encode_left")) {
            let share = refine as f64 / encoder.max(1) as f64;
            out.push(Verdict {
                target: format!(
                    "{} refinement <= {:.0} % of one encoder pass in instructions",
                    core_name(&r.core),
                    100.0 * REFINE_SHARE_OF_ENCODER
                ),
                measured: format!(
                    "{:.1}M ({:.2} % of encode_left's {:.0}M)",
                    refine as f64 / 1e6,
                    100.0 * share,
                    encoder as f64 / 1e6
                ),
                met: share <= REFINE_SHARE_OF_ENCODER,
            });
        }
    }
    out
}

fn core_name(core: &str) -> &str {
    match core {
        "m55" => "Cortex-M55",
        "m7" => "Cortex-M7",
        other => other,
    }
}

fn kib(bytes: u64) -> String {
    format!("{:.1} KiB", bytes as f64 / KIB)
}

/// `1234567` as `1,234,567`.
pub fn grouped(n: u64) -> String {
    let digits = n.to_string();
    let mut out = String::new();
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// The report as Markdown tables.
pub fn markdown(runs: &[CoreRun]) -> String {
    let mut md = String::new();
    let cores: Vec<String> = runs
        .iter()
        .map(|r| format!("{} ({}, {})", r.core.to_uppercase(), r.cpu, r.board))
        .collect();
    let first = &runs[0];
    let _ = writeln!(
        md,
        "Band pair {}x{} (height x width); numbers from the firmware runs under QEMU and the firmware ELF.\n",
        first.band.0, first.band.1
    );
    let _ = writeln!(md, "| memory | {} |", cores.join(" | "));
    let _ = writeln!(md, "|---|{}", "---:|".repeat(runs.len()));
    let row = |md: &mut String, label: &str, f: &dyn Fn(&CoreRun) -> String| {
        let cells: Vec<String> = runs.iter().map(f).collect();
        let _ = writeln!(md, "| {label} | {} |", cells.join(" | "));
    };
    let b = |n: u64| format!("{} B", grouped(n));
    row(&mut md, "weights flash (`.weights`)", &|r| b(r.sections.weights));
    row(&mut md, "code flash (`.text .rodata .vector_table .data`)", &|r| {
        b(r.sections.code_flash())
    });
    row(
        &mut md,
        "arena, static (`pipeline::arena_bytes`)",
        &|r| b(r.arena_bytes),
    );
    row(&mut md, "arena high-water (measured)", &|r| b(r.arena_used));
    if runs.iter().any(|r| r.refine_arena.is_some()) {
        row(&mut md, "of which the refinement (`pipeline::refine_bytes`)", &|r| {
            r.refine_arena.map_or("-".to_string(), b)
        });
    }
    row(&mut md, "stack peak / reserved", &|r| {
        format!("{} / {}", b(r.stack_peak()), b(r.stack_bytes))
    });
    row(&mut md, "RAM reserved (`.data .bss .uninit` + stack)", &|r| {
        b(r.ram_reserved())
    });
    row(&mut md, "RAM used (`.data .bss` + arena + stack peak)", &|r| {
        b(r.ram_used())
    });
    row(&mut md, "QEMU wall time", &|r| format!("{:.0} s", r.qemu_wall_seconds));
    row(&mut md, "outputs bit-identical to the host", &|r| {
        if r.passed { "yes" } else { "**no**" }.to_string()
    });

    let _ = writeln!(md);
    let mut header = String::from("| stage | arena in use |");
    let mut rule = String::from("|---|---:|");
    for r in runs {
        let c = clock(&r.core);
        let _ = write!(
            header,
            " {0} stack | {0} instructions | {0} ms at {1} MHz |",
            r.core.to_uppercase(),
            c.mhz
        );
        rule.push_str("---:|---:|---:|");
    }
    let _ = writeln!(md, "{header}\n{rule}");
    for (i, s) in first.stages.iter().enumerate() {
        let _ = write!(md, "| {} | {} |", s.name, b(s.arena_in_use));
        for r in runs {
            let c = clock(&r.core);
            match r.stages.get(i).filter(|t| t.name == s.name) {
                Some(t) => {
                    let _ = write!(
                        md,
                        " {} | {} | {:.1} |",
                        b(t.stack_peak),
                        grouped(t.instructions),
                        c.ms(t.instructions)
                    );
                }
                None => md.push_str(" - | - | - |"),
            }
        }
        md.push('\n');
    }
    let _ = write!(
        md,
        "| **band pair, export pathway** (all but load and native_*) | {} |",
        b(first.arena_high_water())
    );
    for r in runs {
        let n = r.band_pair_instructions();
        let _ = write!(
            md,
            " {} | **{}** | **{:.0}** |",
            b(r.stack_peak()),
            grouped(n),
            clock(&r.core).ms(n)
        );
    }
    md.push('\n');
    if runs.iter().any(|r| r.native_band_pair_instructions().is_some()) {
        let _ = write!(md, "| **band pair, native pathway** (native_*) | |");
        for r in runs {
            let n = r.native_band_pair_instructions().unwrap_or(0);
            let _ = write!(md, " | **{}** | **{:.0}** |", grouped(n), clock(&r.core).ms(n));
        }
        md.push('\n');
    }
    let _ = write!(md, "| outside the stages (digests, logging) | |");
    for r in runs {
        let _ = write!(
            md,
            " | {} | |",
            grouped(r.outside_instructions + r.startup_instructions)
        );
    }
    md.push('\n');
    let _ = writeln!(
        md,
        "\nInstructions are executed instructions counted by a QEMU TCG plugin, not cycles. The \
         milliseconds assume {}; real parts differ (memory wait states, the M7's dual issue, \
         the M55's MVE beats). `load` (blob CRC and parsing) runs once at boot.\n",
        runs.iter()
            .map(|r| {
                let c = clock(&r.core);
                format!(
                    "{} at {} MHz and {} instruction per cycle",
                    r.core.to_uppercase(),
                    c.mhz,
                    c.ipc
                )
            })
            .collect::<Vec<_>>()
            .join(", ")
    );
    let _ = writeln!(md, "| target | measured | state |\n|---|---|---|");
    for v in verdicts(runs) {
        let _ = writeln!(
            md,
            "| {} | {} | {} |",
            v.target,
            v.measured,
            if v.met { "met" } else { "**missed**" }
        );
    }
    md.push_str(&cycles::markdown(runs));
    md
}

/// The report as JSON.
pub fn to_json(runs: &[CoreRun]) -> BudgetReport {
    BudgetReport::new(runs)
}

/// Options of `bino budget`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BudgetOptions {
    /// Folder with the runs' `<core>.json`.
    pub firmware: PathBuf,
    /// Write the JSON report here.
    pub json: Option<PathBuf>,
    /// Write the Markdown report here.
    pub md: Option<PathBuf>,
    /// Write the bar chart here.
    pub png: Option<PathBuf>,
}

/// Runs `bino budget`: returns the Markdown report after writing the files asked for.
pub fn run_budget(opts: &BudgetOptions) -> Result<String> {
    let runs = load_runs(&opts.firmware)?;
    let md = markdown(&runs);
    if let Some(path) = &opts.json {
        let text = serde_json::to_string_pretty(&to_json(&runs))? + "\n";
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

/// The bar chart: memory per stage (arena in use, stack peak) and instructions per stage per
/// core (log scale: the encoder passes are 10^4 times the smallest stages).
mod chart;

#[cfg(test)]
mod tests {
    use serde_json::json;

    use super::*;

    /// A minimal 32-bit little-endian ELF with the given sections (names and sizes only).
    fn tiny_elf(sections: &[(&str, u32)]) -> Vec<u8> {
        let mut names = vec![0u8];
        let mut name_at = Vec::new();
        for (n, _) in sections.iter().chain([(".shstrtab", 0)].iter()) {
            name_at.push(names.len() as u32);
            names.extend_from_slice(n.as_bytes());
            names.push(0);
        }
        let shoff = 52 + names.len();
        let shnum = sections.len() + 2;
        let mut elf = vec![0u8; 52];
        elf[..6].copy_from_slice(b"\x7fELF\x01\x01");
        elf[0x20..0x24].copy_from_slice(&(shoff as u32).to_le_bytes());
        elf[0x2E..0x30].copy_from_slice(&40u16.to_le_bytes());
        elf[0x30..0x32].copy_from_slice(&(shnum as u16).to_le_bytes());
        elf[0x32..0x34].copy_from_slice(&((shnum - 1) as u16).to_le_bytes());
        elf.extend_from_slice(&names);
        elf.extend_from_slice(&[0u8; 40]); // the null section
        for (i, (_, size)) in sections
            .iter()
            .chain([(".shstrtab", names.len() as u32)].iter())
            .enumerate()
        {
            let mut h = [0u8; 40];
            h[..4].copy_from_slice(&name_at[i].to_le_bytes());
            h[16..20].copy_from_slice(&(if i == sections.len() { 52u32 } else { 0 }).to_le_bytes());
            h[20..24].copy_from_slice(&size.to_le_bytes());
            elf.extend_from_slice(&h);
        }
        elf
    }

    #[test]
    fn elf_section_headers_are_read() {
        let elf = tiny_elf(&[(".text", 43756), (".weights", 1537200), (".uninit", 486928)]);
        let got = elf_sections(&elf).unwrap();
        assert_eq!(
            got,
            vec![
                (".text".to_string(), 43756),
                (".weights".to_string(), 1537200),
                (".uninit".to_string(), 486928),
                (".shstrtab".to_string(), 34),
            ]
        );
        assert!(elf_sections(b"not an elf").is_err());
        assert!(
            elf_sections(&elf[..60]).is_err(),
            "truncated headers are an error, not a panic"
        );
    }

    #[test]
    fn sections_are_grouped_into_flash_and_ram() {
        let s = Sections::from_named(
            [
                (".vector_table", 100),
                (".text", 1000),
                (".rodata", 50),
                (".data", 4),
                (".bss", 16),
            ]
            .map(|(n, v)| (n.to_string(), v)),
        );
        assert_eq!((s.code, s.code_flash(), s.bss, s.weights), (1150, 1154, 16, 0));
    }

    fn run_json(core: &str, encode: u64) -> String {
        json!({
            "schema": "bino-firmware-run/1", "core": core, "cpu": "cpu", "board": "board",
            "band": {"height": 48, "width": 160}, "passed": true, "qemu_wall_seconds": 10.0,
            "elf": "/nonexistent/bino-firmware",
            "elf_sections": {".text": {"size": 40000, "addr": 0}, ".rodata": {"size": 2000, "addr": 0},
                             ".data": {"size": 4, "addr": 0}, ".bss": {"size": 16, "addr": 0},
                             ".uninit": {"size": 486928, "addr": 0}, ".weights": {"size": 1537200, "addr": 0}},
            "arena_bytes": 486918, "arena_used": 486912, "stack_bytes": 32768,
            "arena_breakdown": {"pixels": 15360, "refine": 6881},
            "stages": [
                {"name": "load", "instructions": 8_000_000u64, "arena_in_use": 0, "stack_peak": 1784},
                {"name": "encode_left", "instructions": encode, "arena_in_use": 486912, "stack_peak": 7360},
                {"name": "head", "instructions": 100u64, "arena_in_use": 369256, "stack_peak": 6852},
                {"name": "refine", "instructions": 60_000_000u64, "arena_in_use": 300000, "stack_peak": 2000},
            ],
            "startup_instructions": 5, "outside_instructions": 7,
        })
        .to_string()
    }

    #[test]
    fn runs_parse_and_add_up() {
        let r = CoreRun::parse(&run_json("m55", 700_000_000)).unwrap();
        assert_eq!(r.section_source, SectionSource::Recorded);
        assert_eq!(
            r.band_pair_instructions(),
            760_000_100,
            "load is a boot cost, not per band pair"
        );
        assert_eq!(r.refine_arena, Some(6881));
        assert_eq!(r.stage_instructions("refine"), Some(60_000_000));
        assert_eq!((r.stack_peak(), r.arena_high_water()), (7360, 486912));
        assert_eq!(r.ram_reserved(), 4 + 16 + 486928 + 32768);
        assert_eq!(r.ram_used(), 4 + 16 + 486912 + 7360);
        assert!(CoreRun::parse("{}").is_err());
        assert!(CoreRun::parse(&run_json("m55", 1).replace("bino-firmware-run/1", "other")).is_err());
    }

    /// `run_json` with class counts on every stage: all its instructions `other`, plus the
    /// given adjustments.
    fn run_json_with_classes(core: &str, encode: u64, adjustments: Value) -> String {
        let mut v: Value = serde_json::from_str(&run_json(core, encode)).unwrap();
        for stage in v["stages"].as_array_mut().unwrap() {
            let n = stage["instructions"].as_u64().unwrap();
            stage["classes"] = json!({"mve": 0, "fp": 0, "mul": 0, "div": 0, "load_store": 0,
                                      "branch": 0, "loop": 0, "other": n});
            stage["cycle_adjustments"] = adjustments.clone();
        }
        v.to_string()
    }

    #[test]
    fn class_counts_are_optional_checked_and_priced() {
        let old = CoreRun::parse(&run_json("m7", 1000)).unwrap();
        assert!(!old.has_class_counts());
        assert_eq!(old.band_pair_modelled_cycles(), None);
        assert!(markdown(&[old]).contains("M7: no class counts in this run"));

        let adj = json!({"mve_overlap": 0, "dual_issue_pair": 100, "extra_words": 10});
        let r = CoreRun::parse(&run_json_with_classes("m7", 1000, adj.clone())).unwrap();
        assert!(r.has_class_counts());
        // encode_left: 1000 `other` at 1, 100 pairs at -0.5, 10 extra words at 0.5.
        assert_eq!(r.stages[1].modelled_cycles("m7"), Some(1000.0 - 50.0 + 5.0));
        // Band pair: encode_left, head (100), refine (60M), each with the same adjustments.
        assert_eq!(
            r.band_pair_modelled_cycles(),
            Some((1000 + 100 + 60_000_000) as f64 + 3.0 * (-50.0 + 5.0))
        );
        let md = markdown(std::slice::from_ref(&r));
        assert!(md.contains("a model, not a measurement"), "{md}");
        assert!(md.contains("| encode_left | 0.0 | 955 | 0.0 | 0.95 |"), "{md}");
        assert!(md.contains("| dual_issue_pair | 300 | -0.5 |"), "{md}");
        let j = to_json(std::slice::from_ref(&r));
        let cm = j.cores[0].cycle_model.as_ref().unwrap();
        assert_eq!(cm.class_counts["other"], 1000 + 100 + 60_000_000);
        assert_eq!(j.cores[0].stages[1].modelled_cycles, Some(955.0));

        let mut bad: Value = serde_json::from_str(&run_json_with_classes("m55", 1000, adj)).unwrap();
        bad["stages"][1]["classes"]["other"] = json!(999);
        let err = format!("{:#}", CoreRun::parse(&bad.to_string()).unwrap_err());
        assert!(err.contains("encode_left") && err.contains("add up to 999"), "{err}");
        bad["stages"][1]["classes"]["other"] = json!(1000);
        bad["stages"][1]["cycle_adjustments"]["warp"] = json!(1);
        let err = format!("{:#}", CoreRun::parse(&bad.to_string()).unwrap_err());
        assert!(err.contains("\"warp\" has no cost"), "{err}");
    }

    #[test]
    fn the_elf_is_read_only_when_it_is_the_one_measured() {
        let dir = std::env::temp_dir().join(format!("bino-budget-elf-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("bino-firmware");
        let elf = tiny_elf(&[(".text", 1000), (".weights", 77), (".uninit", 5)]);
        std::fs::write(&path, &elf).unwrap();
        let with = |sha: &str| {
            let mut v: Value = serde_json::from_str(&run_json("m55", 1)).unwrap();
            v["elf"] = json!(path.to_str().unwrap());
            v["elf_sha256"] = json!(sha);
            CoreRun::parse(&v.to_string()).unwrap()
        };
        let same = with(&crate::io::files::sha256_hex(&elf));
        assert_eq!(same.section_source, SectionSource::Elf(path.clone()));
        assert_eq!(
            (same.sections.code, same.sections.weights, same.sections.uninit),
            (1000, 77, 5)
        );
        let rebuilt = with("0000");
        assert_eq!(rebuilt.section_source, SectionSource::Recorded);
        assert_eq!(rebuilt.sections.weights, 1537200, "the sizes recorded at the run");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn verdicts_judge_the_targets() {
        let m55 = CoreRun::parse(&run_json("m55", 680_000_000)).unwrap();
        let m7 = CoreRun::parse(&run_json("m7", 4_740_000_000)).unwrap();
        let v = verdicts(&[m55.clone(), m7]);
        let met: Vec<bool> = v.iter().map(|v| v.met).collect();
        // weights 1,537,200 B <= 1.5 MiB; arena 486,918 <= 512 KiB; M55 740M <= 800M and its
        // refinement 60M of a 680M pass (8.8 %); M7 10 s > 8 s and 60M of 4740M.
        assert_eq!(met, [true, true, true, true, false, true], "{v:#?}");
        assert!(v[3].measured.starts_with("60.0M (8.82 %"), "{}", v[3].measured);
        assert!(v[4].measured.starts_with("10.00 s"), "{}", v[4].measured);
        let slow = CoreRun::parse(&run_json("m55", 500_000_000)).unwrap();
        let v = verdicts(&[slow]);
        assert!(v[2].met && !v[3].met, "{v:#?}: 60M is 12 % of a 500M pass");
        assert!((clock("m55").ms(400_000_000) - 1000.0).abs() < 1e-9);
        assert!((clock("m7").ms(480_000_000) - 1000.0).abs() < 1e-9);
    }

    /// A firmware that runs both pathways: the native stages (`native_*`) stay out of the export
    /// band pair, stages never entered are dropped, and the native band pair without its
    /// check's second pass is judged against the export one.
    #[test]
    fn the_native_pathway_is_judged_beside_the_export_one() {
        let mut v: Value = serde_json::from_str(&run_json("m55", 700_000_000)).unwrap();
        let stages = v["stages"].as_array_mut().unwrap();
        for (name, n) in [
            ("encode_pair", 0u64),
            ("native_encode_pair", 300_000_000),
            ("native_head", 50),
            ("native_refine", 60_000_000),
            ("native_encode_mirror", 300_000_000),
            ("native_head_mirror", 50),
        ] {
            stages.push(json!({"name": name, "instructions": n, "arena_in_use": 1, "stack_peak": 1}));
        }
        let r = CoreRun::parse(&v.to_string()).unwrap();
        assert!(r.stage_instructions("encode_pair").is_none(), "never entered: dropped");
        assert_eq!(r.band_pair_instructions(), 760_000_100, "the export pathway alone");
        assert_eq!(r.native_band_pair_instructions(), Some(660_000_100));
        assert_eq!(r.native_one_pass_instructions(), Some(360_000_050));
        let verdict = verdicts(std::slice::from_ref(&r))
            .into_iter()
            .find(|v| v.target.contains("native band pair"))
            .unwrap();
        // 360M of 760M: 47.4 % <= 55 %.
        assert!(verdict.met, "{verdict:?}");
        assert!(
            verdict.measured.starts_with("360M (47.4 % of 760M"),
            "{}",
            verdict.measured
        );
        let md = markdown(std::slice::from_ref(&r));
        assert!(
            md.contains("| **band pair, native pathway** (native_*) | | | **660,000,100** |"),
            "{md}"
        );
        assert!(CoreRun::parse(&run_json("m55", 1))
            .unwrap()
            .native_band_pair_instructions()
            .is_none());
    }

    #[test]
    fn markdown_and_json_carry_the_numbers() {
        let runs = [CoreRun::parse(&run_json("m55", 700_000_000)).unwrap()];
        let md = markdown(&runs);
        assert!(md.contains("| weights flash (`.weights`) | 1,537,200 B |"), "{md}");
        assert!(
            md.contains("| of which the refinement (`pipeline::refine_bytes`) | 6,881 B |"),
            "{md}"
        );
        assert!(
            md.contains("| refine | 300,000 B | 2,000 B | 60,000,000 | 150.0 |"),
            "{md}"
        );
        assert!(
            md.contains("| encode_left | 486,912 B | 7,360 B | 700,000,000 | 1750.0 |"),
            "{md}"
        );
        assert!(md.contains("not cycles"), "{md}");
        let j = to_json(&runs);
        assert_eq!(j.cores[0].band_pair_instructions, 760_000_100);
        assert_eq!(j.cores[0].refine_arena_bytes, Some(6881));
        assert_eq!(j.cores[0].assumed_instructions_per_cycle, 1.0);
        let text = serde_json::to_string_pretty(&j).unwrap();
        let v: Value = serde_json::from_str(&text).unwrap();
        assert_eq!(v["cores"][0]["band_pair_instructions"], 760_000_100u64);
        assert_eq!(v["cores"][0]["stages"][3]["name"], "refine");
        assert_eq!(v["targets"][0]["met"], true);
        assert_eq!(v["schema"], "bino-budget/1");
        // Keys sorted at every level, as the file always had them (`Value` maps are sorted).
        assert_eq!(text, serde_json::to_string_pretty(&v).unwrap());
        assert_eq!(grouped(1234567), "1,234,567");
        assert_eq!(grouped(12), "12");
    }

    #[test]
    fn the_chart_draws_bars_and_text() {
        let runs = [
            CoreRun::parse(&run_json("m55", 700_000_000)).unwrap(),
            CoreRun::parse(&run_json("m7", 4_740_000_000)).unwrap(),
        ];
        let chart = chart::draw(&runs).unwrap();
        assert_eq!(chart.dimensions(), chart::SIZE);
        let count = |f: &dyn Fn(&image::Rgb<u8>) -> bool| chart.pixels().filter(|p| f(p)).count();
        // The two series' colours: blue bars (arena, M55) and orange ones (stack, M7).
        let blue = count(&|p| p.0 == [33, 150, 228]);
        let orange = count(&|p| p.0 == [245, 124, 32]);
        assert!(
            blue > 5_000 && orange > 5_000,
            "{blue} blue, {orange} orange bar pixels"
        );
        // Text (titles, stage names, value labels) is dark and anti-aliased: many grey levels.
        let dark = count(&|p| p.0.iter().all(|&c| c < 100));
        let greys: std::collections::BTreeSet<u8> = chart
            .pixels()
            .filter(|p| p.0[0] == p.0[1] && p.0[1] == p.0[2])
            .map(|p| p.0[0])
            .collect();
        assert!(
            dark > 5_000,
            "{dark} dark pixels: no text drawn? (the axes alone are about 2,300)"
        );
        assert!(greys.len() > 50, "{} grey levels: text not anti-aliased", greys.len());
        // The caption strip above the first panel holds its title.
        let title = (0..25).flat_map(|y| (0..chart::SIZE.0).map(move |x| (x, y)));
        let title_ink = title.filter(|&(x, y)| chart.get_pixel(x, y).0[0] < 128).count();
        assert!(title_ink > 600, "{title_ink} title pixels");
    }
}
