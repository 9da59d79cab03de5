//! `bino sim`: the board, simulated on the host. The camera pair is fed row by row into the
//! band buffer as a sensor delivers it ([`sensor::SensorSource`]), the core pipeline
//! (`bino_core::pipeline`) runs in one arena, and each disparity row is drawn onto an RGB565
//! display framebuffer with `embedded-graphics` as it comes out ([`DisplaySink`]); a status
//! line (host fps, arena use, image size) is drawn last and the display is saved as a PNG.
//!
//! The fps is the host's: the measured wall time of the pipeline run (drawing included) on
//! this machine. It says nothing of a Cortex-M board's speed.
//!
//! Files: `mod.rs` runs the simulation ([`run_sim`]); `display.rs` the RGB565 framebuffer;
//! `sensor.rs` the row-by-row camera; `layout.rs` where the pictures sit ([`Layout`]);
//! `sink.rs` the pipeline sink that draws ([`DisplaySink`]); `tests.rs` the unit tests.

pub mod display;
mod layout;
pub mod sensor;
mod sink;

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Result};
use bino_core::pipeline::{self, Pipeline, Refine, RefineInput, Report};
use bino_core::sgm::Penalties;

use crate::data::profile::{load_profiled_pair, Profile, View};
use crate::data::synthetic::default_scene;
use crate::int8::pipeline_maps::{readout_options, streamed_input};
use crate::int8::{to_u8, Int8Model};
use crate::io::image_io::GrayImage;
use crate::readout::pathway::Pathway;
use crate::readout::{Method, Readout};
use display::{DisplaySize, Framebuffer};
pub use layout::{Layout, Panel};
use sensor::SensorSource;
pub use sink::{DisplaySink, REJECTED};

/// Size of the built-in pair used without `--left/--right` (the `bino demo` scene).
pub const DEFAULT_SCENE: (usize, usize) = (320, 96);

/// What `bino sim` runs on and where it writes.
#[derive(Debug, Clone)]
pub struct SimOptions {
    /// Left and right views; `None`: the built-in scene ([`DEFAULT_SCENE`]).
    pub pair: Option<(PathBuf, PathBuf)>,
    /// Resolution profile of a given pair (the built-in scene runs at its own size).
    pub profile: Profile,
    /// Int8 weight blob.
    pub blob: PathBuf,
    /// Readout drawn (one of the pathway's).
    pub readout: Readout,
    /// Export (two encoder passes, every readout) or native (one pass on (L, R), its head).
    pub pathway: Pathway,
    /// Disparity candidates of nolink and sgm, in patch columns.
    pub max_cols: usize,
    /// SGM penalties.
    pub penalties: Penalties,
    /// Left-right check tolerance in patch columns.
    pub lr_max_diff: f32,
    /// Display size.
    pub display: DisplaySize,
    /// Frames to run (the sensor delivers the pair again for each); fps from their median.
    pub frames: usize,
    /// Output folder; the display goes to `display.png` in it.
    pub out: PathBuf,
}

/// What a simulation measured and wrote.
#[derive(Debug, Clone)]
pub struct SimReport {
    /// Where the pair came from.
    pub source: String,
    /// Size the pipeline ran at.
    pub width: usize,
    /// Height it ran at.
    pub height: usize,
    /// Rows the sensor delivered in the last frame (each row once: equals `height`).
    pub rows_delivered: usize,
    /// Wall time of each frame's pipeline run, drawing included.
    pub frame_times: Vec<Duration>,
    /// Of the last frame: time in each pipeline stage, then `draw` (the sink's drawing).
    pub stage_times: Vec<(&'static str, Duration)>,
    /// The core pipeline's report of the last frame.
    pub pipeline: Report,
    /// Arena bytes allocated: the blob's own size (`Pipeline::arena_bytes`).
    pub arena_bytes: usize,
    /// Rows drawn on the display: token rows, or pixel rows for a `+ref` readout.
    pub rows_drawn: usize,
    /// CRC-32 of the last frame's refined rows (Q8 px, little-endian, top to bottom) for a
    /// `+ref` readout: the digest the firmware logs as its `refined` output.
    pub refined_digest: Option<u32>,
    /// Where things sit on the display.
    pub layout: Layout,
    /// The status lines drawn.
    pub status: Vec<String>,
    /// The display picture written.
    pub png: PathBuf,
}

impl SimReport {
    /// Median frame time.
    pub fn frame_time(&self) -> Duration {
        let mut times = self.frame_times.clone();
        times.sort();
        times.get(times.len() / 2).copied().unwrap_or_default()
    }

    /// Frames per second on this host, from the median frame time.
    pub fn host_fps(&self) -> f64 {
        1.0 / self.frame_time().as_secs_f64().max(1e-9)
    }
}

/// Runs the simulation; `progress` hears about each step before it starts.
pub fn run_sim(opts: &SimOptions, mut progress: impl FnMut(&str)) -> Result<SimReport> {
    ensure!(opts.frames >= 1, "--frames must be at least 1");
    opts.pathway.check(opts.readout)?;
    // The pipeline must have the readout before any work starts.
    let input = refine_input(opts.readout, opts.pathway)?;
    crate::io::files::check_output_dir(&opts.out, "--out")?;
    progress("loading the pair and the blob");
    let (source, left, right) = load_pair(opts)?;
    let (width, height) = (left.width, left.height);
    // The census readouts read pixels only: no blob, no encoder.
    let model = match input.census_only() {
        true => None,
        false => Some(Int8Model::load(&opts.blob)?),
    };
    let pipeline = match model.as_ref() {
        Some(model) => Some(Pipeline::new(model.blob()?).map_err(anyhow::Error::msg)?),
        None => None,
    };
    if let (true, Some(model)) = (opts.readout.uses_head(), model.as_ref()) {
        model.require_head(opts.pathway.core())?;
    }
    // The options `bino run` and `bino eval` run the readout with.
    let pipeline_opts = readout_options(
        opts.readout,
        opts.pathway,
        opts.max_cols,
        opts.penalties,
        opts.lr_max_diff,
        width,
    );
    // A +ref readout: the pipeline's refinement stage streams pixel rows, drawn as they come.
    // The census SGM streams beside a refinement of its fusion only, so an unrefined census
    // fusion runs that refinement too and draws the fused token rows instead.
    let census = matches!(input, RefineInput::FusedCensusLr | RefineInput::FusedAllLr);
    let refine = match opts.readout.refine || census {
        true => Some(Refine::for_width(input, width)),
        false => None,
    };
    let layout = Layout::new(opts.display, width, height)?;
    let arena_bytes = match (&pipeline, &refine) {
        (_, _) if input.census_only() => pipeline::census_arena_bytes(height, width, &pipeline_opts, refine.as_ref()),
        // The blob's own size: what a board running this blob sizes its arena by.
        (Some(p), _) => p.arena_bytes(height, width, &pipeline_opts, refine.as_ref()),
        (None, Some(r)) => pipeline::arena_bytes_refined(height, width, &pipeline_opts, r),
        (None, None) => pipeline::arena_bytes_for(height, width, &pipeline_opts),
    };
    let mut arena = vec![0u8; arena_bytes];

    let mut frame_times = Vec::with_capacity(opts.frames);
    let mut last = None;
    for frame in 0..opts.frames {
        let encoder = match (input.census_only(), opts.pathway) {
            (true, _) => "census SGM (no encoder)",
            (false, crate::readout::pathway::Pathway::Export) => "encoder (L,L), (R,R)",
            (false, crate::readout::pathway::Pathway::Native) => "encoder (L,R)",
        };
        progress(&format!(
            "frame {}/{}: sensor rows -> band buffer -> {encoder} -> {} -> display",
            frame + 1,
            opts.frames,
            opts.readout.name()
        ));
        let mut fb = Framebuffer::new(opts.display);
        layout.draw_camera(&mut fb, &left);
        let mut sensor = SensorSource::new(&left.pixels, &right.pixels, width, height).map_err(anyhow::Error::msg)?;
        let mut sink = DisplaySink::new(&mut fb, layout.disparity, opts.readout, opts.max_cols);
        let started = Instant::now();
        let report = match (&pipeline, &refine) {
            (None, _) => pipeline::run_census(&mut sensor, &pipeline_opts, refine.as_ref(), &mut arena, &mut sink),
            (Some(p), Some(r)) => p.run_refined(&mut sensor, &pipeline_opts, r, &mut arena, &mut sink),
            (Some(p), None) => p.run(&mut sensor, &pipeline_opts, &mut arena, &mut sink),
        }
        .map_err(anyhow::Error::msg)?;
        sink.finish();
        frame_times.push(started.elapsed());
        let (stage_times, rows_drawn, digest) = (sink.stage_times(), sink.rows_drawn, sink.refined_digest());
        ensure!(
            sensor.frame_done(),
            "the pipeline read {} of the sensor's {height} rows",
            sensor.rows_delivered()
        );
        last = Some((fb, report, stage_times, rows_drawn, digest, sensor.rows_delivered()));
    }
    let Some((mut fb, report, stage_times, rows_drawn, refined_digest, rows_delivered)) = last else {
        unreachable!("at least one frame ran");
    };
    let mut sim = SimReport {
        source,
        width,
        height,
        rows_delivered,
        frame_times,
        stage_times,
        pipeline: report,
        arena_bytes,
        rows_drawn,
        refined_digest,
        layout,
        status: Vec::new(),
        png: opts.out.join("display.png"),
    };
    sim.status = status_lines(&sim, opts.readout);
    layout.draw_status(&mut fb, &sim.status);
    progress("writing the display");
    fb.save_png(&sim.png)?;
    Ok(sim)
}

/// Why `bino sim` has no unchecked fused readout: the board's pipeline fuses the checked rows.
const UNCHECKED_FUSE_NOT_STREAMED: &str = "the board's streaming pipeline (bino_core::pipeline), which bino sim \
     runs, fuses the head and SGM by their checks (fuse+lr, fuse+lr+ref); the unchecked fuse is computed by \
     bino run and bino eval only";

/// The core pipeline's refinement input for a readout: the same token grid `bino run` and
/// `bino eval` refine (a readout the pipeline does not stream is an error).
fn refine_input(readout: Readout, pathway: Pathway) -> Result<RefineInput> {
    match (streamed_input(readout, pathway), readout.method) {
        (Some(input), _) => Ok(input),
        (None, Method::Fused) => bail!("--readout {readout}: {UNCHECKED_FUSE_NOT_STREAMED}"),
        (None, _) => bail!(
            "--readout {readout}: the board's streaming pipeline (bino_core::pipeline), which bino sim runs, \
             streams the census SGM fused by the checks (fuse-census+lr with --pathway native, fuse-all+lr \
             with --pathway export, each optionally +ref); the unchecked fusions are computed by bino run and \
             bino eval only"
        ),
    }
}

/// The pair as the sensor delivers it: gray bytes at the profile's size.
fn load_pair(opts: &SimOptions) -> Result<(String, GrayImage, GrayImage)> {
    let Some((left_path, right_path)) = &opts.pair else {
        let (w, h) = DEFAULT_SCENE;
        let scene = default_scene(w, h);
        return Ok(("built-in scene".to_string(), scene.left, scene.right));
    };
    let (left, right) = load_profiled_pair(left_path, right_path, opts.profile)?;
    let gray = |view: &View| GrayImage::new(view.width, view.height, to_u8(&view.pixels));
    let source = format!("{} + {} ({})", left_path.display(), right_path.display(), opts.profile);
    Ok((source, gray(&left)?, gray(&right)?))
}

fn status_lines(sim: &SimReport, readout: Readout) -> Vec<String> {
    let kept = match readout.method {
        Method::Nolink => sim.pipeline.wta_kept,
        Method::Sgm => sim.pipeline.sgm_kept,
        Method::Head => sim.pipeline.head_kept,
        Method::Fused | Method::CensusFused | Method::FusedAll => sim.pipeline.fused_kept,
        Method::Census => sim.pipeline.census_kept,
    };
    let kept = 100.0 * kept as f64 / (sim.pipeline.rows * sim.pipeline.cols).max(1) as f64;
    vec![
        format!(
            "host {:.2} fps ({:.0} ms)  {}x{} {}",
            sim.host_fps(),
            sim.frame_time().as_secs_f64() * 1e3,
            sim.width,
            sim.height,
            readout.name()
        ),
        format!(
            "arena {}/{} B  LR {:.0}%",
            sim.pipeline.arena_used, sim.arena_bytes, kept
        ),
    ]
}

#[cfg(test)]
mod tests;
