//! The firmware runs the budget is made of: one `<core>.json` per core (`bino-firmware-run/1`,
//! written by `firmware-sim/qemu-plugin/report.py`), its stages' executed instructions, arena
//! and stack, and the firmware ELF's section sizes (read from the ELF itself when it is still
//! the one measured, else as the run recorded them).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context, Result};
use serde::Deserialize;
use serde_json::Value;

use super::cycles;
use super::elf::elf_sections;

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
    /// The fast preset's whole-frame run (stages `census_*`), when the firmware ran it.
    pub census: Option<FrameRun>,
    /// The learned preset's whole-frame run (stages `frame_*`), when the firmware ran it.
    pub frame: Option<FrameRun>,
    /// The fast preset on the Alif E7's 320x240 frame with the options of that width (stages
    /// `census320_*`), when the firmware ran it (the Cortex-M55's, `scripts/firmware.sh
    /// --frame320`).
    pub census320: Option<FrameRun>,
    /// The learned preset on the E7's frame (stages `frame320_*`), likewise.
    pub frame320: Option<FrameRun>,
}

/// A whole-frame run of a firmware, rows from the camera: the fast preset's (`census` in its
/// JSON: the encoder-free `census+lr+ref`, `pipeline::run_census`) or the learned preset's
/// (`frame`: the native pathway's `fuse-census+lr+ref`, band after band).
#[derive(Debug, Clone, PartialEq, Deserialize)]
pub struct FrameRun {
    /// The frame, pixels.
    pub frame: BandJson,
    /// Its static arena (`preset::census_arena_bytes`, `preset::arena_bytes`), bytes.
    pub arena_bytes: u64,
    /// Arena high-water reported by the pipeline, bytes.
    pub arena_used: u64,
    /// Executed instructions of the frame: its `census_*` or `frame_*` stages.
    pub frame_instructions: u64,
    /// Deepest stack use of its stages, bytes.
    pub stack_peak: u64,
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
    #[serde(default)]
    census: Option<FrameRun>,
    #[serde(default)]
    frame: Option<FrameRun>,
    #[serde(default)]
    census320: Option<FrameRun>,
    #[serde(default)]
    frame320: Option<FrameRun>,
}

/// A band or frame size, pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
pub struct BandJson {
    /// Rows.
    pub height: u64,
    /// Columns.
    pub width: u64,
}

#[derive(Deserialize)]
struct SectionJson {
    size: u64,
}

/// Stages that run once at boot, not per band pair.
const BOOT_STAGES: [&str; 1] = ["load"];

/// Prefix of the native pathway run's stages (`native_encode_pair`, `native_head`, ...); the
/// others (but `load` and the census run's) are the export pathway's.
pub const NATIVE_PREFIX: &str = "native_";

/// Prefix of the fast preset's whole-frame run's stages (`census_rows`, `census_sgm`,
/// `census_refine`).
pub const CENSUS_PREFIX: &str = "census_";

/// Prefix of the learned preset's whole-frame run's stages (`frame_encode_pair`,
/// `frame_head`, ...).
pub const FRAME_PREFIX: &str = "frame_";

/// Prefix of the fast preset's run on the Alif E7's 320x240 frame (`census320_rows`, ...).
pub const CENSUS320_PREFIX: &str = "census320_";

/// Prefix of the learned preset's run on the E7's frame (`frame320_encode_pair`, ...).
pub const FRAME320_PREFIX: &str = "frame320_";

/// Whether stage `name` belongs to a whole-frame run (the fast or the learned preset's, on
/// either frame).
pub fn frame_run_stage(name: &str) -> bool {
    [CENSUS_PREFIX, FRAME_PREFIX, CENSUS320_PREFIX, FRAME320_PREFIX]
        .iter()
        .any(|p| name.starts_with(p))
}

/// Whether stage `name` belongs to a run on the E7's frame, which has an arena of its own
/// outside the static one (`firmware-sim/memory/an547.x`).
pub fn e7_frame_stage(name: &str) -> bool {
    name.starts_with(CENSUS320_PREFIX) || name.starts_with(FRAME320_PREFIX)
}

/// Which preset a whole-frame run is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameKind {
    /// The fast preset (`census+lr+ref`).
    Fast,
    /// The learned preset (the native pathway's `fuse-census+lr+ref`).
    Learned,
}

/// Whether stage `name` is part of the export pathway's band pair.
pub fn export_band_stage(name: &str) -> bool {
    !BOOT_STAGES.contains(&name) && !name.starts_with(NATIVE_PREFIX) && !frame_run_stage(name)
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
            census: run.census,
            frame: run.frame,
            census320: run.census320,
            frame320: run.frame320,
        })
    }

    /// The whole-frame runs of one preset with the prefix of their stages, in run order: the
    /// 160x120 frame's, then the E7 frame's.
    pub fn frame_runs(&self, kind: FrameKind) -> impl Iterator<Item = (&FrameRun, &'static str)> {
        let runs = match kind {
            FrameKind::Fast => [(&self.census, CENSUS_PREFIX), (&self.census320, CENSUS320_PREFIX)],
            FrameKind::Learned => [(&self.frame, FRAME_PREFIX), (&self.frame320, FRAME320_PREFIX)],
        };
        runs.into_iter()
            .filter_map(|(run, prefix)| Some((run.as_ref()?, prefix)))
    }

    /// The stages named `<prefix>*`, in run order.
    pub fn stages_with(&self, prefix: &'static str) -> impl Iterator<Item = &StageRun> {
        self.stages.iter().filter(move |s| s.name.starts_with(prefix))
    }

    /// The census run's stages (`census_*`), in run order.
    pub fn census_stages(&self) -> impl Iterator<Item = &StageRun> {
        self.stages_with(CENSUS_PREFIX)
    }

    /// The learned frame run's stages (`frame_*`), in run order.
    pub fn frame_stages(&self) -> impl Iterator<Item = &StageRun> {
        self.stages_with(FRAME_PREFIX)
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
    /// the head's left-right check included, read from the same pass), `None` for a firmware
    /// that ran only the export pathway.
    pub fn native_band_pair_instructions(&self) -> Option<u64> {
        let native = self.native_stages();
        (!native.is_empty()).then(|| native.iter().map(|s| s.instructions).sum())
    }

    /// The native run's stages (`native_*`), in run order.
    fn native_stages(&self) -> Vec<&StageRun> {
        self.stages
            .iter()
            .filter(|s| s.name.starts_with(NATIVE_PREFIX))
            .collect()
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

    /// Modelled cycles of one band pair on the native pathway (its `native_` stages), with class
    /// counts; `None` without them or without a native run.
    pub fn native_band_pair_modelled_cycles(&self) -> Option<f64> {
        let native = self.native_stages();
        if native.is_empty() {
            return None;
        }
        native.iter().map(|s| s.modelled_cycles(&self.core)).sum()
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

    /// Highest use of the static arena by any stage (the E7 frame's runs have their own).
    pub fn arena_high_water(&self) -> u64 {
        self.stages
            .iter()
            .filter(|s| !e7_frame_stage(&s.name))
            .map(|s| s.arena_in_use)
            .max()
            .unwrap_or(0)
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
