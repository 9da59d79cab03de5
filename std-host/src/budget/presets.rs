//! The board's two presets per frame and core: the fast one (`census+lr+ref`, the encoder-free
//! census readout, `pipeline::run_census`) and the learned one (the native pathway's
//! `fuse-census+lr+ref`), each from the whole frame the firmware measured; each with its frame
//! rate at IPC 1 and under the cycle model, its exact arena (the preset's `const fn`) and its
//! stack peak.
//!
//! A frame of a measured size is counted, not scaled: the 160x120 frame on both cores, and the
//! Alif E7's 320x240 frame (with the options of that width, as the board runs it) where the
//! firmware ran it (the Cortex-M55's, `scripts/firmware.sh --frame320`). Another size is, for
//! the fast preset, its first measured frame's stages scaled by token rows x cells (its work per
//! pixel does not grow with the frame: the search range and the refinement's window are the
//! measured frame's, fixed); for the learned one, its band pair scaled to the frame
//! ([`super::frame`]: the encoder's attention grows with the width); each says so.

use anyhow::Result;
use bino_core::preset::{arena_bytes_for_width, census_arena_bytes_for_width};
use serde::Serialize;

use super::frame::{FrameBudget, FramesReport, Pathway, Scaling};
use super::{clock, Clock, CoreRun, Frame, FrameKind, FrameRun, FAST_PRESET_TARGET};
use crate::io::checkout;

/// One of the board's presets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Preset {
    /// `census+lr+ref`: no encoder, no weights.
    Fast,
    /// `fuse-census+lr+ref` on the native pathway: one encoder pass per band.
    Learned,
}

impl Preset {
    /// `fast` or `learned`.
    pub fn name(self) -> &'static str {
        match self {
            Preset::Fast => "fast",
            Preset::Learned => "learned",
        }
    }

    /// Its readout, as `bino run` names it.
    pub fn readout(self) -> &'static str {
        match self {
            Preset::Fast => "census+lr+ref",
            Preset::Learned => "fuse-census+lr+ref",
        }
    }
}

/// How a preset's frame figures were obtained.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Source {
    /// Counted on a whole frame of this size.
    MeasuredFrame,
    /// The measured frame's stages scaled by token rows x cells.
    ScaledFrame,
    /// The band pair's stages scaled by their work ([`super::frame::RULE`]).
    ScaledBandPair,
}

/// One preset on one frame and core.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PresetFrame {
    // Declared in the JSON's key order (alphabetical; see `report`).
    /// The preset's arena for the frame with the options of its width, exact (its `const fn`),
    /// bytes.
    pub arena_bytes: u64,
    /// Clock of the times, MHz.
    pub clock_mhz: f64,
    /// `m55` or `m7`.
    pub core: String,
    /// The frame.
    pub frame: Frame,
    /// Frames per second at the clock, 1 instruction per cycle.
    pub frames_per_s_ipc1: f64,
    /// Executed instructions per frame.
    pub instructions: u64,
    /// Frames per second under the cycle model (absent without class counts).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub modelled_frames_per_s: Option<f64>,
    /// The preset.
    pub preset: Preset,
    /// Its readout.
    pub readout: &'static str,
    /// Seconds per frame at the clock, 1 instruction per cycle.
    pub seconds_ipc1: f64,
    /// Where the instructions come from.
    pub source: Source,
    /// Deepest stack use of the preset's run on this core, bytes (measured on its run: the
    /// stack does not grow with the frame).
    pub stack_peak_bytes: u64,
    /// Weights the preset needs in flash, bytes: none for the fast one; the blob of the
    /// encoder and the native head ([`learned_weights_bytes`]) for the learned one.
    pub weights_bytes: u64,
}

/// The presets section of the report.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct PresetsReport {
    /// Per frame, core and preset (fast first).
    pub frames: Vec<PresetFrame>,
    /// What the figures are.
    pub note: &'static str,
}

/// The section's note.
pub const NOTE: &str = "fast: census+lr+ref (pipeline::run_census, no encoder, no weights), counted on the \
    firmware's whole frames (rows from the camera: 160x120 on every core, the Alif E7's 320x240 with the \
    options of that width, 16 head candidates and a +-4 px refinement, where the core ran it), other sizes its \
    160x120 frame scaled by token rows x cells (keeping that frame's options); learned: the native pathway's \
    fuse-census+lr+ref, counted on the same frames, other sizes its band pair scaled to the frame (frames.rule); \
    arena: the preset's const fn for the frame with the options of its width (preset::census_arena_bytes_for_width, \
    preset::arena_bytes_for_width); stack: the peak of the preset's run; fps at the stated clock, IPC 1, and under \
    the cycle model";

impl PresetsReport {
    /// Both presets on every frame of `frames` (the learned preset's figures are its native
    /// estimates there) for every run.
    pub fn new(runs: &[CoreRun], frames: &FramesReport, sizes: &[Frame]) -> Result<Self> {
        let mut out = Vec::new();
        for &frame in sizes {
            for run in runs {
                let c = Clock {
                    mhz: frames.clock_override_mhz.unwrap_or(clock(&run.core).mhz),
                    ..clock(&run.core)
                };
                if let Some(fast) = fast(run, frame, c)? {
                    out.push(fast);
                }
                if let Some(measured) = measured_learned(run, frame, c) {
                    out.push(measured);
                    continue;
                }
                let learned = frames
                    .estimates
                    .iter()
                    .find(|e| e.core == run.core && e.frame == frame && e.pathway == Pathway::Native);
                if let Some(e) = learned {
                    out.push(learned_frame(run, e));
                }
            }
        }
        Ok(Self {
            frames: out,
            note: NOTE,
        })
    }

    /// The fast preset's frame of `core` measured at `frame`, if the run measured that size.
    pub fn measured_fast(&self, core: &str, frame: Frame) -> Option<&PresetFrame> {
        self.measured(core, frame, Preset::Fast)
    }

    /// `preset`'s frame of `core` measured at `frame`, if the run measured that size.
    pub fn measured(&self, core: &str, frame: Frame, preset: Preset) -> Option<&PresetFrame> {
        self.frames
            .iter()
            .find(|p| p.core == core && p.frame == frame && p.preset == preset && p.source == Source::MeasuredFrame)
    }
}

/// The run's whole frame of `kind` measured at `frame`, with the prefix of its stages.
fn measured_frame(run: &CoreRun, kind: FrameKind, frame: Frame) -> Option<(&FrameRun, &'static str)> {
    run.frame_runs(kind).find(|(f, _)| size(f) == frame)
}

fn size(run: &FrameRun) -> Frame {
    Frame::new(run.frame.height as usize, run.frame.width as usize)
}

/// The fast preset on `frame`: the run's census frame of that size, counted, else its first
/// (160x120) census frame scaled; `None` without one.
fn fast(run: &CoreRun, frame: Frame, c: Clock) -> Result<Option<PresetFrame>> {
    let (census, prefix, ratio, source) = match measured_frame(run, FrameKind::Fast, frame) {
        Some((census, prefix)) => (census, prefix, 1.0, Source::MeasuredFrame),
        None => {
            let Some((census, prefix)) = run.frame_runs(FrameKind::Fast).next() else {
                return Ok(None);
            };
            let ratio = Scaling::Cells.ratio(size(census), frame)?;
            (census, prefix, ratio, Source::ScaledFrame)
        }
    };
    let stages: Vec<_> = run.stages_with(prefix).collect();
    let counted: u64 = stages.iter().map(|s| s.instructions).sum();
    let instructions = (counted as f64 * ratio).round() as u64;
    let modelled: Option<f64> = stages.iter().map(|s| s.modelled_cycles(&run.core)).sum();
    let seconds = round6(c.ms(instructions) / 1e3);
    Ok(Some(PresetFrame {
        arena_bytes: census_arena_bytes_for_width(frame.height, frame.width) as u64,
        clock_mhz: c.mhz,
        core: run.core.clone(),
        frame,
        frames_per_s_ipc1: round6(1.0 / seconds),
        instructions,
        modelled_frames_per_s: modelled.map(|n| round6(1.0 / (c.cycles_ms(n * ratio) / 1e3))),
        preset: Preset::Fast,
        readout: Preset::Fast.readout(),
        seconds_ipc1: seconds,
        source,
        stack_peak_bytes: census.stack_peak,
        weights_bytes: 0,
    }))
}

/// The learned preset's weights in flash: the checkout's native-only blob
/// (`weights/bino_int8_native.bin`, `bino quantize --only native`), else the run's whole blob.
pub fn learned_weights_bytes(run: &CoreRun) -> u64 {
    std::fs::metadata(checkout::path(checkout::NATIVE_BLOB)).map_or(run.sections.weights, |m| m.len())
}

/// The learned preset counted on the run's learned frame of size `frame`, when it measured one.
fn measured_learned(run: &CoreRun, frame: Frame, c: Clock) -> Option<PresetFrame> {
    let (learned, prefix) = measured_frame(run, FrameKind::Learned, frame)?;
    let stages: Vec<_> = run.stages_with(prefix).collect();
    let instructions: u64 = stages.iter().map(|s| s.instructions).sum();
    let modelled: Option<f64> = stages.iter().map(|s| s.modelled_cycles(&run.core)).sum();
    let seconds = round6(c.ms(instructions) / 1e3);
    Some(PresetFrame {
        arena_bytes: arena_bytes_for_width(frame.height, frame.width) as u64,
        clock_mhz: c.mhz,
        core: run.core.clone(),
        frame,
        frames_per_s_ipc1: round6(1.0 / seconds),
        instructions,
        modelled_frames_per_s: modelled.map(|n| round6(1.0 / (c.cycles_ms(n) / 1e3))),
        preset: Preset::Learned,
        readout: Preset::Learned.readout(),
        seconds_ipc1: seconds,
        source: Source::MeasuredFrame,
        stack_peak_bytes: learned.stack_peak,
        weights_bytes: learned_weights_bytes(run),
    })
}

/// The learned preset from its native frame estimate.
fn learned_frame(run: &CoreRun, e: &FrameBudget) -> PresetFrame {
    let stack = run
        .stages
        .iter()
        .filter(|s| Pathway::Native.has(&s.name))
        .map(|s| s.stack_peak)
        .max()
        .unwrap_or(0);
    PresetFrame {
        arena_bytes: arena_bytes_for_width(e.frame.height, e.frame.width) as u64,
        clock_mhz: e.clock_mhz,
        core: e.core.clone(),
        frame: e.frame,
        frames_per_s_ipc1: e.frames_per_s_ipc1,
        instructions: e.instructions,
        modelled_frames_per_s: e.modelled_frames_per_s,
        preset: Preset::Learned,
        readout: Preset::Learned.readout(),
        seconds_ipc1: e.seconds_ipc1,
        source: Source::ScaledBandPair,
        stack_peak_bytes: stack,
        weights_bytes: learned_weights_bytes(run),
    }
}

/// The fast preset's target ([`FAST_PRESET_TARGET`]) judged on the M55 run's measured frame at
/// the core's own clock: `(met, measured)`; `None` when no M55 run measured that frame.
pub fn fast_target(runs: &[CoreRun]) -> Option<(bool, String)> {
    let (frame, fps) = FAST_PRESET_TARGET;
    let run = runs.iter().find(|r| r.core == "m55")?;
    let census = run.census.as_ref()?;
    let measured = Frame::new(census.frame.height as usize, census.frame.width as usize);
    if measured != frame {
        return None;
    }
    let instructions: u64 = run.census_stages().map(|s| s.instructions).sum();
    let c = clock(&run.core);
    let ceiling = c.mhz * 1e6 * c.ipc / fps;
    let got = 1e3 / c.ms(instructions);
    Some((
        instructions as f64 <= ceiling,
        format!(
            "{:.1}M instructions per frame, measured ({got:.2} fps; {:.0} % of the {:.0}M the target allows)",
            instructions as f64 / 1e6,
            100.0 * instructions as f64 / ceiling,
            ceiling / 1e6
        ),
    ))
}

fn round6(x: f64) -> f64 {
    (x * 1e6).round() / 1e6
}
