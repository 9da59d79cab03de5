//! Whole frames from one measured band pair: what a `W x H` frame costs per core and pathway,
//! each stage measured on the `48 x W0` band pair scaled by its work.
//!
//! The pipeline cuts a frame into overlapping 48-row bands ([`BandPlan`]). With the shipped
//! blob a band encodes only the token rows the band before did not (its token rows do not
//! depend on their place in the band), so every token row is encoded once; a blob without that
//! property encodes every band whole. The other stages see each row of the frame once: the rows
//! stage reads every pixel row once, and a band feeds the readouts only the token rows it keeps.
//! So a stage measured on the band pair scales by its work ([`Scaling`]):
//!
//! - encoder passes (`encode_left`, `encode_right`, `native_encode_pair`): the sum over the
//!   frame's bands of [`encoder_macs`] of the token rows the band encodes (x 2 W / 4 fused
//!   columns) over the measured band's; the attention term grows with the square of the width;
//! - `match`: token rows x the (cell, candidate) pairs a row compares (each cell against the
//!   `min(column + 1, 16)` right cells inside the view) over the band's;
//! - the heads (`head`, `native_head`): per band, the token rows its head reads (those it keeps
//!   and six around them, [`bino_core::band::Band::around_kept`]: each band's head starts
//!   afresh, on either pathway) x cells;
//! - every other stage (`rows`, `sgm`, `left_right`, `refine` and the native twins):
//!   token rows x cells per row (W / 4) over the band's; the heads' candidates (12) are the
//!   preset's, fixed, so their work per cell does not grow with the width;
//! - `load` (the blob's check) runs once per boot: not part of a frame.
//!
//! Modelled cycles scale by the same ratio as the instructions. The firmware's arena for a
//! frame is the band pipeline's for an `H x W` image: the preset's `const fn`
//! ([`export_arena_bytes`], [`arena_bytes`]: the board's, native), exact. [`check`] holds the rule against a second
//! measured band width.

use std::fmt;
use std::str::FromStr;

use anyhow::{anyhow, bail, Result};
use bino_core::band::BandPlan;
use bino_core::config::{check_view_size, PATCH_H};
use bino_core::model::head::ROW_REACH;
use bino_core::preset::{arena_bytes, export_arena_bytes, OPTIONS};
use serde::Serialize;

use super::{clock, frame_run_stage, Clock, CoreRun, NATIVE_PREFIX};
use crate::bench::encoder_macs;
use crate::io::checkout;
use bino_core::blob::Blob;
use bino_core::model::encoder::Encoder;
use bino_core::model::weights::AttentionSpan;

/// A frame (or band) size in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Frame {
    /// Rows.
    pub height: usize,
    /// Columns.
    pub width: usize,
}

/// The frames reported unless asked for others: QQVGA and QVGA.
pub const DEFAULT_FRAMES: [Frame; 2] = [
    Frame {
        width: 160,
        height: 120,
    },
    Frame {
        width: 320,
        height: 240,
    },
];

impl fmt::Display for Frame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}x{}", self.width, self.height)
    }
}

impl FromStr for Frame {
    type Err = anyhow::Error;

    /// `WxH` (width first, as cameras are named), checked against the pipeline's grid.
    fn from_str(s: &str) -> Result<Self> {
        let parsed = s
            .split_once(['x', 'X'])
            .and_then(|(w, h)| Some((w.trim().parse::<usize>().ok()?, h.trim().parse::<usize>().ok()?)));
        let Some((width, height)) = parsed else {
            bail!("expected WxH (width x height in pixels, e.g. 320x240)");
        };
        let frame = Frame { width, height };
        frame.plan()?;
        Ok(frame)
    }
}

impl Frame {
    /// A `height x width` frame.
    pub const fn new(height: usize, width: usize) -> Self {
        Self { height, width }
    }

    /// The bands the pipeline runs on this frame; an error for a size it does not take (the
    /// core's own checks: multiples of the token grid, at most its height).
    pub fn plan(&self) -> Result<BandPlan> {
        let (token_rows, _) = check_view_size(self.height, self.width).map_err(|e| anyhow!("{e}"))?;
        BandPlan::new(token_rows).map_err(|e| anyhow!("{e}"))
    }

    /// Token rows and cells per row.
    fn grid(&self) -> (usize, usize) {
        (self.height / PATCH_H, self.width / bino_core::config::CELL_W)
    }
}

/// The shipped encoder (`weights/bino_int8.bin`, the blob the firmware runs): which keys its
/// queries read, for [`encoder_macs`], and whether a frame's bands share their common token
/// rows (`Encoder::rows_independent`); band attention, nothing shared, where the blob cannot be
/// read.
fn shipped() -> (AttentionSpan, bool) {
    static SHIPPED: std::sync::OnceLock<(AttentionSpan, bool)> = std::sync::OnceLock::new();
    *SHIPPED.get_or_init(|| {
        let bytes = std::fs::read(checkout::path(checkout::BLOB)).unwrap_or_default();
        Blob::parse(&bytes)
            .ok()
            .and_then(|blob| Encoder::new(blob).ok())
            .map_or((AttentionSpan::Band, false), |encoder| {
                (encoder.weights().span(), encoder.rows_independent())
            })
    })
}

/// Which keys the shipped encoder's queries read ([`shipped`]).
pub(crate) fn shipped_span() -> AttentionSpan {
    shipped().0
}

/// The token rows each band of `plan` encodes: the whole band, or with the shipped blob's
/// shared rows only those the band before did not ([`BandPlan::encoded`]).
pub(crate) fn encoded_rows(plan: &BandPlan) -> impl Iterator<Item = usize> + '_ {
    let shared = shipped().1;
    (0..plan.len()).map(move |i| plan.encoded(i, shared).map_or(0, |rows| rows.len()))
}

/// How a stage's work grows with the frame (see the module's doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Scaling {
    /// Once per boot (`load`): no share in a frame.
    Boot,
    /// Per band, [`encoder_macs`] of its tokens.
    Encoder,
    /// Per token row, the (cell, candidate) pairs the row matcher compares.
    Pairs,
    /// Per token row, its cells.
    Cells,
    /// Per band, the token rows its head reads, their cells.
    HeadRows,
}

impl Scaling {
    /// The rule of stage `name` (either pathway's).
    pub fn of(name: &str) -> Self {
        match name.strip_prefix(NATIVE_PREFIX).unwrap_or(name) {
            "load" => Scaling::Boot,
            "encode_left" | "encode_right" | "encode_pair" => Scaling::Encoder,
            "match" => Scaling::Pairs,
            "head" => Scaling::HeadRows,
            _ => Scaling::Cells,
        }
    }

    /// The stage's work on `frame` in the rule's unit (MACs, pairs or cells; 0 for boot) and
    /// how many times the stage runs on it (bands for the encoder, token rows for the others).
    pub fn work(self, frame: Frame) -> Result<(f64, f64)> {
        let plan = frame.plan()?;
        let (token_rows, cols) = frame.grid();
        Ok(match self {
            Scaling::Boot => (0.0, 0.0),
            Scaling::Encoder => (
                encoded_rows(&plan)
                    .map(|rows| encoder_macs(rows, 2 * cols, shipped_span()) as f64)
                    .sum(),
                plan.len() as f64,
            ),
            Scaling::Pairs => ((token_rows * pairs(cols, OPTIONS.max_cols)) as f64, token_rows as f64),
            Scaling::Cells => ((token_rows * cols) as f64, token_rows as f64),
            Scaling::HeadRows => {
                let rows: usize = plan.iter().map(|band| band.around_kept(ROW_REACH).len()).sum();
                ((rows * cols) as f64, rows as f64)
            }
        })
    }

    /// Work on `to` over work on `from`: the factor a stage measured on `from` is scaled by.
    pub fn ratio(self, from: Frame, to: Frame) -> Result<f64> {
        Ok(match self {
            Scaling::Boot => 0.0,
            _ => self.work(to)?.0 / self.work(from)?.0,
        })
    }

    /// A stage's instructions on `to` from two measurements `(band, instructions)` at
    /// different widths, fitted as a constant per run of the stage (per band for the encoder,
    /// per token row for the others) plus a slope in work: exact at both measurements. `None`
    /// when the two have the same work per run (nothing to fit).
    pub fn fitted(self, (a, at_a): (Frame, u64), (b, at_b): (Frame, u64), to: Frame) -> Result<Option<f64>> {
        if self == Scaling::Boot {
            return Ok(Some(0.0));
        }
        let ((wa, na), (wb, nb), (wt, nt)) = (self.work(a)?, self.work(b)?, self.work(to)?);
        let (xa, xb) = (wa / na, wb / nb);
        if (xa - xb).abs() <= 1e-9 * xa.abs().max(xb.abs()) {
            return Ok(None);
        }
        let (ya, yb) = (at_a as f64 / na, at_b as f64 / nb);
        let slope = (ya - yb) / (xa - xb);
        let constant = ya - slope * xa;
        Ok(Some(nt * constant + slope * wt))
    }
}

/// (Cell, candidate) pairs of a row of `cols` cells with `candidates` candidates: cell `c` has
/// `min(c + 1, candidates)` right cells inside the view.
pub fn pairs(cols: usize, candidates: usize) -> usize {
    (0..cols).map(|c| (c + 1).min(candidates)).sum()
}

/// The two pathways of a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Pathway {
    /// Two encoder passes, every readout: the stages without the `native_` prefix.
    Export,
    /// One pass on (L, R), the native head: the `native_*` stages.
    Native,
}

impl Pathway {
    /// Both, export first.
    pub const ALL: [Pathway; 2] = [Pathway::Export, Pathway::Native];

    /// Whether stage `name` belongs to this pathway's band pair (`load` and the whole-frame
    /// runs' to neither).
    pub fn has(self, name: &str) -> bool {
        name != "load" && !frame_run_stage(name) && name.starts_with(NATIVE_PREFIX) == (self == Pathway::Native)
    }

    /// `export` or `native`.
    pub fn name(self) -> &'static str {
        match self {
            Pathway::Export => "export",
            Pathway::Native => "native",
        }
    }

    /// The exact arena of a `frame` on this pathway (the preset's `const fn`), bytes.
    pub fn arena_bytes(self, frame: Frame) -> usize {
        match self {
            Pathway::Export => export_arena_bytes(frame.height, frame.width),
            Pathway::Native => arena_bytes(frame.height, frame.width),
        }
    }
}

/// One stage scaled from the measured band to a frame.
#[derive(Debug, Clone, PartialEq)]
pub struct ScaledStage {
    /// Stage name.
    pub name: String,
    /// Its rule.
    pub scaling: Scaling,
    /// The factor: work on the frame over work on the measured band.
    pub ratio: f64,
    /// Instructions on the frame.
    pub instructions: f64,
    /// Modelled cycles on the frame (with class counts).
    pub modelled_cycles: Option<f64>,
}

/// The stages of `run`'s `pathway` scaled to `frame`; empty when the run lacks the pathway.
pub fn scale(run: &CoreRun, pathway: Pathway, frame: Frame) -> Result<Vec<ScaledStage>> {
    let band = band_of(run);
    run.stages
        .iter()
        .filter(|s| pathway.has(&s.name))
        .map(|s| {
            let scaling = Scaling::of(&s.name);
            let ratio = scaling.ratio(band, frame)?;
            Ok(ScaledStage {
                name: s.name.clone(),
                scaling,
                ratio,
                instructions: s.instructions as f64 * ratio,
                modelled_cycles: s.modelled_cycles(&run.core).map(|c| c * ratio),
            })
        })
        .collect()
}

/// One frame on one core and pathway.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FrameBudget {
    /// The exact arena (the preset's `const fn` for the frame's size), bytes.
    pub arena_bytes: u64,
    /// The frame's instructions over the measured band pair's on this pathway.
    pub band_pairs: f64,
    /// Bands the pipeline runs.
    pub bands: usize,
    /// Clock of the times, MHz.
    pub clock_mhz: f64,
    /// `m55` or `m7`.
    pub core: String,
    /// Frame size.
    pub frame: Frame,
    /// Frames per second at the clock, 1 instruction per cycle.
    pub frames_per_s_ipc1: f64,
    /// Instructions of the frame with each stage fitted through both measured band widths
    /// ([`Scaling::fitted`]; absent without the second run).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fitted_instructions: Option<u64>,
    /// Executed instructions of the frame (scaled by work; rounded).
    pub instructions: u64,
    /// Modelled cycles of the frame (absent without class counts).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub modelled_cycles: Option<f64>,
    /// Frames per second under the cycle model.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub modelled_frames_per_s: Option<f64>,
    /// Seconds per frame under the cycle model.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub modelled_seconds: Option<f64>,
    /// `export` or `native`.
    pub pathway: Pathway,
    /// Seconds per frame at the clock, 1 instruction per cycle.
    pub seconds_ipc1: f64,
}

/// The frame of `run` on `pathway` at `clock_mhz` (the core's own clock when `None`), with the
/// fit through `second` (the same core at another band width) when given; `None` when the run
/// lacks the pathway.
pub fn frame_budget(
    run: &CoreRun,
    second: Option<&CoreRun>,
    pathway: Pathway,
    frame: Frame,
    clock_mhz: Option<f64>,
) -> Result<Option<FrameBudget>> {
    let stages = scale(run, pathway, frame)?;
    if stages.is_empty() {
        return Ok(None);
    }
    let c = Clock {
        mhz: clock_mhz.unwrap_or(clock(&run.core).mhz),
        ..clock(&run.core)
    };
    let instructions: f64 = stages.iter().map(|s| s.instructions).sum();
    let modelled: Option<f64> = stages.iter().map(|s| s.modelled_cycles).sum();
    let band_pair: u64 = run
        .stages
        .iter()
        .filter(|s| pathway.has(&s.name))
        .map(|s| s.instructions)
        .sum();
    let fitted = match second {
        Some(other) => fitted(run, other, pathway, frame)?,
        None => None,
    };
    // Rounded to a millionth: figures that print short and read back the same.
    let seconds = round6(c.ms(instructions.round() as u64) / 1e3);
    let modelled = modelled.map(f64::round);
    let modelled_seconds = modelled.map(|n| round6(c.cycles_ms(n) / 1e3));
    Ok(Some(FrameBudget {
        arena_bytes: pathway.arena_bytes(frame) as u64,
        bands: frame.plan()?.len(),
        band_pairs: round6(instructions / band_pair.max(1) as f64),
        clock_mhz: c.mhz,
        core: run.core.clone(),
        frame,
        fitted_instructions: fitted.map(|n| n.round() as u64),
        frames_per_s_ipc1: round6(1.0 / seconds),
        instructions: instructions.round() as u64,
        modelled_cycles: modelled,
        modelled_frames_per_s: modelled_seconds.map(|s| round6(1.0 / s)),
        modelled_seconds,
        pathway,
        seconds_ipc1: seconds,
    }))
}

/// The pathway's instructions on `frame`, each stage fitted through `run` and `other` (one
/// core at two band widths); a stage `other` lacks, or one whose work per run is the same at
/// both, is scaled by its work. `None` when the two runs have the same band.
fn fitted(run: &CoreRun, other: &CoreRun, pathway: Pathway, frame: Frame) -> Result<Option<f64>> {
    let (a, b) = (band_of(run), band_of(other));
    if a == b {
        return Ok(None);
    }
    let mut total = 0.0;
    for s in run.stages.iter().filter(|s| pathway.has(&s.name)) {
        let scaling = Scaling::of(&s.name);
        let at_b = other.stage_instructions(&s.name);
        let fit = match at_b {
            Some(n) => scaling.fitted((a, s.instructions), (b, n), frame)?,
            None => None,
        };
        total += match fit {
            Some(n) => n,
            None => s.instructions as f64 * scaling.ratio(a, frame)?,
        };
    }
    Ok(Some(total))
}

fn band_of(run: &CoreRun) -> Frame {
    Frame::new(run.band.0 as usize, run.band.1 as usize)
}

/// Every frame on every run and pathway, frames outermost; `second`: runs of the same cores at
/// another band width, for the fitted figures.
pub fn frame_budgets(
    runs: &[CoreRun],
    second: &[CoreRun],
    frames: &[Frame],
    clock_mhz: Option<f64>,
) -> Result<Vec<FrameBudget>> {
    let mut out = Vec::new();
    for &frame in frames {
        for run in runs {
            let other = second.iter().find(|o| o.core == run.core);
            for pathway in Pathway::ALL {
                out.extend(frame_budget(run, other, pathway, frame, clock_mhz)?);
            }
        }
    }
    Ok(out)
}

/// One stage of the check: a run at one band width scaled to another measured one.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct StageCheck {
    /// Percent: (predicted - measured) / measured.
    pub error_percent: f64,
    /// Measured at the second width.
    pub measured: u64,
    /// Stage name, or `band pair, export` / `band pair, native` for a pathway's sum.
    pub name: String,
    /// Predicted from the first width.
    pub predicted: u64,
    /// The stage's rule (absent for the sums).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub scaling: Option<Scaling>,
}

/// The scaling rule checked on one core: the run at the budget's band scaled to the second
/// run's band, stage by stage, against what the second run measured.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ScalingCheck {
    /// `m55` or `m7`.
    pub core: String,
    /// The band the prediction starts from.
    pub from: Frame,
    /// Per stage, then per pathway.
    pub stages: Vec<StageCheck>,
    /// The second measured band.
    pub to: Frame,
}

/// Scales `run` to `other`'s band and compares stage by stage (both runs of one core).
pub fn check(run: &CoreRun, other: &CoreRun) -> Result<ScalingCheck> {
    let to = band_of(other);
    let mut stages = Vec::new();
    for pathway in Pathway::ALL {
        let scaled = scale(run, pathway, to)?;
        let (mut predicted, mut measured) = (0.0, 0u64);
        for s in &scaled {
            let Some(m) = other.stage_instructions(&s.name) else {
                continue;
            };
            predicted += s.instructions;
            measured += m;
            stages.push(StageCheck {
                error_percent: percent(s.instructions, m),
                measured: m,
                name: s.name.clone(),
                predicted: s.instructions.round() as u64,
                scaling: Some(s.scaling),
            });
        }
        if measured > 0 {
            stages.push(StageCheck {
                error_percent: percent(predicted, measured),
                measured,
                name: format!("band pair, {}", pathway.name()),
                predicted: predicted.round() as u64,
                scaling: None,
            });
        }
    }
    Ok(ScalingCheck {
        core: run.core.clone(),
        from: band_of(run),
        stages,
        to,
    })
}

fn percent(predicted: f64, measured: u64) -> f64 {
    round6(100.0 * (predicted - measured as f64) / measured.max(1) as f64)
}

fn round6(x: f64) -> f64 {
    (x * 1e6).round() / 1e6
}

/// The scaling rule in one sentence, for the reports.
pub const RULE: &str = "each stage of the band pair scaled by its work: encoder passes by the sum over \
    the frame's bands of encoder MACs (embedding, per-token linear layers, attention 2 x DIM per query and key it reads, per block: the keys of its token row with the shipped encoder) of \
    the token rows each band encodes (with the shipped blob's shared rows, only those the band before did not: \
    every token row once); match by token rows x (cell, candidate) pairs inside the view; the heads (head, native_head) \
    by the token rows each band's head reads (those it keeps and 6 around them) x cells; every other stage (rows, \
    sgm, left_right, refine and the native twins) by token rows x cells per row (the heads' 12 candidates are \
    fixed); load is once per boot and left out; modelled cycles scale as the instructions";

/// What the frames section reports: which frames and at what clock.
#[derive(Debug, Clone, PartialEq)]
pub struct FrameOptions {
    /// Frames, in order.
    pub frames: Vec<Frame>,
    /// Clock of every core for the frame figures, MHz (`None`: each core's own).
    pub clock_mhz: Option<f64>,
}

impl Default for FrameOptions {
    fn default() -> Self {
        Self {
            frames: DEFAULT_FRAMES.to_vec(),
            clock_mhz: None,
        }
    }
}

/// The report's frames section.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct FramesReport {
    /// The clock every core's frame figures assume, MHz, when one was asked for (`--clock-mhz`);
    /// absent: each core's own.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub clock_override_mhz: Option<f64>,
    /// Per frame, core and pathway.
    pub estimates: Vec<FrameBudget>,
    /// How the stages are scaled ([`RULE`]).
    pub rule: &'static str,
    /// The rule on the budget's band pair scaled to the second measured width, per core; empty
    /// without the second run.
    pub scaling_check: Vec<ScalingCheck>,
}

impl FramesReport {
    /// The frames of `opts` on `runs`; `second`: the same cores at another band width.
    pub fn new(runs: &[CoreRun], second: &[CoreRun], opts: &FrameOptions) -> Result<Self> {
        let mut scaling_check = Vec::new();
        for run in runs {
            if let Some(other) = second.iter().find(|o| o.core == run.core && o.band != run.band) {
                scaling_check.push(check(run, other)?);
            }
        }
        Ok(Self {
            clock_override_mhz: opts.clock_mhz,
            estimates: frame_budgets(runs, second, &opts.frames, opts.clock_mhz)?,
            rule: RULE,
            scaling_check,
        })
    }
}
