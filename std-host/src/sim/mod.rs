//! `bino sim`: the board, simulated on the host. The camera pair is fed row by row into the
//! band buffer as a sensor delivers it ([`sensor::SensorSource`]), the core pipeline
//! (`bino_core::pipeline`) runs in one arena, and each disparity row is drawn onto an RGB565
//! display framebuffer with `embedded-graphics` as it comes out ([`DisplaySink`]); a status
//! line (host fps, arena use, image size) is drawn last and the display is saved as a PNG.
//!
//! The fps is the host's: the measured wall time of the pipeline run (drawing included) on
//! this machine. It says nothing of a Cortex-M board's speed.

pub mod display;
pub mod sensor;

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Result};
use bino_core::config::HEAD_MAX_DISP;
use bino_core::matching::DISPARITY_FRAC_BITS;
use bino_core::model::head::HeadRow;
use bino_core::pipeline::{
    self, CensusRow, FusedRow, HeadChecked, MatchedRow, Options as PipelineOptions, Pipeline, Refine, RefineInput,
    Report, Sink, Stage,
};
use bino_core::sgm::Penalties;
use embedded_graphics::mono_font::ascii::FONT_6X10;
use embedded_graphics::mono_font::MonoTextStyle;
use embedded_graphics::pixelcolor::{Rgb565, Rgb888, RgbColor};
use embedded_graphics::prelude::*;
use embedded_graphics::primitives::Rectangle;
use embedded_graphics::text::{Baseline, Text};

use crate::data::profile::{load_profiled_pair, Profile, View};
use crate::data::synthetic::default_scene;
use crate::int8::{to_u8, Int8Model};
use crate::io::colour::colourise;
use crate::io::image_io::GrayImage;
use crate::readout::pathway::Pathway;
use crate::readout::{Method, Readout};
use display::{DisplaySize, Framebuffer};
use sensor::SensorSource;

/// Size of the built-in pair used without `--left/--right` (the `bino demo` scene).
pub const DEFAULT_SCENE: (usize, usize) = (320, 96);

/// Status lines at the bottom of the display.
const STATUS_LINES: usize = 2;
/// Pixel rows per status line (FONT_6X10 is 10 rows high, plus one of spacing).
const LINE_PITCH: usize = 11;
/// Pixels between the camera view and the disparity panel.
const GAP: usize = 2;
/// Colour of cells the left-right check rejected.
pub const REJECTED: Rgb565 = Rgb565::new(3, 6, 3);
/// Background of the status bar.
const STATUS_BACKGROUND: Rgb565 = Rgb565::new(0, 0, 6);

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
    /// Arena bytes allocated (`bino_core::pipeline::arena_bytes`).
    pub arena_bytes: usize,
    /// Rows drawn on the display: token rows, or pixel rows for a `+ref` readout.
    pub rows_drawn: usize,
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
    let input = refine_input(opts.readout)?;
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
    let pipeline_opts = PipelineOptions {
        pathway: opts.pathway.core(),
        max_cols: opts.max_cols,
        penalties: opts.penalties,
        // The census check's tolerance is one column on every command (as `bino run`'s).
        lr_max_diff_q8: match input.census_only() {
            true => crate::readout::census::CENSUS_LR_MAX_DIFF_Q8,
            false => crate::readout::lr_tolerance_q8(opts.lr_max_diff),
        },
        head: opts.readout.uses_head(),
        // The head's own left-right check: the display darkens (or, for head+lr, fills) the
        // cells it rejects, as for the other methods.
        head_lr: opts.readout.uses_head(),
        head_candidates: crate::readout::head_candidates(width),
    };
    // A +ref readout: the pipeline's refinement stage streams pixel rows, drawn as they come.
    // The census SGM streams beside a refinement of its fusion only, so an unrefined census
    // fusion runs that refinement too and draws the fused token rows instead.
    let census = matches!(input, RefineInput::FusedCensusLr | RefineInput::FusedAllLr);
    let refine = match opts.readout.refine || census {
        true => Some(Refine::for_width(input, width)),
        false => None,
    };
    let layout = Layout::new(opts.display, width, height)?;
    let arena_bytes = match &refine {
        _ if input.census_only() => pipeline::census_arena_bytes(height, width, &pipeline_opts, refine.as_ref()),
        Some(r) => pipeline::arena_bytes_refined(height, width, &pipeline_opts, r),
        None => pipeline::arena_bytes_for(height, width, &pipeline_opts),
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
        let (stage_times, rows_drawn) = (sink.stage_times(), sink.rows_drawn);
        ensure!(
            sensor.frame_done(),
            "the pipeline read {} of the sensor's {height} rows",
            sensor.rows_delivered()
        );
        last = Some((fb, report, stage_times, rows_drawn, sensor.rows_delivered()));
    }
    let Some((mut fb, report, stage_times, rows_drawn, rows_delivered)) = last else {
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
fn refine_input(readout: Readout) -> Result<RefineInput> {
    Ok(match (readout.method, readout.lr) {
        (Method::Nolink, false) => RefineInput::Nolink,
        (Method::Nolink, true) => RefineInput::NolinkLr,
        (Method::Sgm, false) => RefineInput::Sgm,
        (Method::Sgm, true) => RefineInput::SgmLr,
        (Method::Head, false) => RefineInput::Head,
        (Method::Head, true) => RefineInput::HeadLr,
        (Method::Fused, true) => RefineInput::FusedLr,
        (Method::Fused, false) => bail!("--readout {readout}: {UNCHECKED_FUSE_NOT_STREAMED}"),
        (Method::CensusFused, true) => RefineInput::FusedCensusLr,
        (Method::FusedAll, true) => RefineInput::FusedAllLr,
        (Method::Census, false) => RefineInput::Census,
        (Method::Census, true) => RefineInput::CensusLr,
        (Method::CensusFused | Method::FusedAll, false) => bail!(
            "--readout {readout}: the board's streaming pipeline (bino_core::pipeline), which bino sim runs, \
             streams the census SGM fused by the checks (fuse-census+lr with --pathway native, fuse-all+lr \
             with --pathway export, each optionally +ref); the unchecked fusions are computed by bino run and \
             bino eval only"
        ),
    })
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

/// A rectangle of the display showing an image-sized picture scaled by `num / den`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Panel {
    /// Left column on the display.
    pub x: usize,
    /// Top row on the display.
    pub y: usize,
    /// Columns used.
    pub width: usize,
    /// Rows used.
    pub height: usize,
    num: usize,
    den: usize,
}

impl Panel {
    /// The largest scaling of an `image_w x image_h` picture into the `room_w x room_h`
    /// rectangle at `(x, y)`, centred in it.
    fn fit(x: usize, y: usize, room_w: usize, room_h: usize, image_w: usize, image_h: usize) -> Self {
        // Scale = min(room_w / image_w, room_h / image_h), kept as a fraction.
        let (num, den) = if room_w * image_h <= room_h * image_w {
            (room_w, image_w)
        } else {
            (room_h, image_h)
        };
        let (width, height) = (image_w * num / den.max(1), image_h * num / den.max(1));
        Self {
            x: x + (room_w - width.min(room_w)) / 2,
            y: y + (room_h - height.min(room_h)) / 2,
            width,
            height,
            num,
            den: den.max(1),
        }
    }

    /// Display pixels `[start, end)` covered by image pixels `[from, to)` along one axis.
    fn span(&self, from: usize, to: usize) -> (usize, usize) {
        (from * self.num / self.den, to * self.num / self.den)
    }

    /// The image pixel shown at display offset `d` along one axis (nearest below).
    fn source(&self, d: usize) -> usize {
        d * self.den / self.num.max(1)
    }

    /// Fills the display rectangle covering image pixels `[x0, x1) x [y0, y1)`.
    fn fill(&self, fb: &mut Framebuffer, (x0, x1): (usize, usize), (y0, y1): (usize, usize), colour: Rgb565) {
        let (dx0, dx1) = self.span(x0, x1);
        let (dy0, dy1) = self.span(y0, y1);
        let area = Rectangle::new(
            Point::new((self.x + dx0) as i32, (self.y + dy0) as i32),
            Size::new((dx1 - dx0) as u32, (dy1 - dy0) as u32),
        );
        let Ok(()) = fb.fill_solid(&area, colour);
    }

    /// The panel's rectangle on the display.
    pub fn rectangle(&self) -> Rectangle {
        Rectangle::new(
            Point::new(self.x as i32, self.y as i32),
            Size::new(self.width as u32, self.height as u32),
        )
    }
}

/// Where the camera view, the disparity map and the status bar sit on the display: the two
/// pictures one above the other or side by side, whichever shows them larger.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layout {
    /// The left camera view.
    pub camera: Panel,
    /// The disparity map (same scale as the camera view: cell (r, c) covers its 4x4 pixels).
    pub disparity: Panel,
    /// Top row of the status bar.
    pub status_y: usize,
}

impl Layout {
    /// The layout of a `width x height` pair on `display`.
    pub fn new(display: DisplaySize, width: usize, height: usize) -> Result<Self> {
        let (w, h) = (display.width, display.height);
        let status_y = h.saturating_sub(STATUS_LINES * LINE_PITCH + 1);
        let room = status_y.saturating_sub(GAP);
        let stacked = (
            Panel::fit(0, 0, w, room / 2, width, height),
            Panel::fit(0, room / 2 + GAP, w, room / 2, width, height),
        );
        let half = w.saturating_sub(GAP) / 2;
        let side = (
            Panel::fit(0, 0, half, room, width, height),
            Panel::fit(half + GAP, 0, half, room, width, height),
        );
        let (camera, disparity) = if side.0.width * side.0.height > stacked.0.width * stacked.0.height {
            side
        } else {
            stacked
        };
        ensure!(
            disparity.width >= 1 && disparity.height >= 1 && status_y > 0,
            "display {display} is too small for a {width}x{height} image and {STATUS_LINES} status lines"
        );
        Ok(Self {
            camera,
            disparity,
            status_y,
        })
    }

    /// Draws the left camera view (gray) into its panel.
    pub fn draw_camera(&self, fb: &mut Framebuffer, left: &GrayImage) {
        let p = &self.camera;
        let pixels = (0..p.height).flat_map(|dy| {
            let row = p.source(dy).min(left.height - 1) * left.width;
            (0..p.width).map(move |dx| {
                let g = left.pixels[row + p.source(dx).min(left.width - 1)];
                Rgb565::new(g >> 3, g >> 2, g >> 3)
            })
        });
        let Ok(()) = fb.fill_contiguous(&p.rectangle(), pixels);
    }

    /// Draws the status bar: one line of text per entry (FONT_6X10, white).
    pub fn draw_status(&self, fb: &mut Framebuffer, lines: &[String]) {
        let size = fb.display_size();
        let bar = Rectangle::new(
            Point::new(0, self.status_y as i32),
            Size::new(size.width as u32, (size.height - self.status_y) as u32),
        );
        let Ok(()) = fb.fill_solid(&bar, STATUS_BACKGROUND);
        let style = MonoTextStyle::new(&FONT_6X10, Rgb565::WHITE);
        for (i, line) in lines.iter().enumerate() {
            let at = Point::new(2, (self.status_y + 1 + i * LINE_PITCH) as i32);
            let Ok(_) = Text::with_baseline(line, at, style, Baseline::Top).draw(fb);
        }
    }
}

/// Draws each token row of the chosen readout onto the display as the pipeline emits it,
/// and times the pipeline's stages and its own drawing.
pub struct DisplaySink<'f> {
    fb: &'f mut Framebuffer,
    panel: Panel,
    readout: Readout,
    /// Colour scale: this many patch columns is the far end of the map.
    max_disparity: f32,
    /// Head rows waiting for their left-right check (it comes a row of the mirrored head later).
    pending_heads: Vec<(usize, Vec<u16>)>,
    /// Rows drawn: token rows, or pixel rows for a `+ref` readout.
    pub rows_drawn: usize,
    times: [Duration; Stage::ALL.len() + 1],
    current: Option<(usize, Instant)>,
}

impl<'f> DisplaySink<'f> {
    /// A sink drawing `readout` into `panel` of `fb`; `max_cols` candidates of nolink and sgm
    /// (the head's and the census's colour scale is the head's trained range).
    pub fn new(fb: &'f mut Framebuffer, panel: Panel, readout: Readout, max_cols: usize) -> Self {
        // The census searches as far as the head (4 px a head candidate).
        let head_range = readout.uses_head() || readout.method == Method::Census;
        let candidates = if head_range { HEAD_MAX_DISP } else { max_cols };
        Self {
            fb,
            panel,
            readout,
            max_disparity: candidates.saturating_sub(1).max(1) as f32,
            pending_heads: Vec::new(),
            rows_drawn: 0,
            times: [Duration::ZERO; Stage::ALL.len() + 1],
            current: None,
        }
    }

    /// Charges the time since the last switch to the current bucket and starts `bucket`.
    fn switch(&mut self, bucket: Option<usize>) -> Option<usize> {
        let now = Instant::now();
        let previous = self.current.take().map(|(b, since)| {
            self.times[b] += now - since;
            b
        });
        self.current = bucket.map(|b| (b, now));
        previous
    }

    /// Stops the clock (after the run).
    pub fn finish(&mut self) {
        self.switch(None);
    }

    /// Time in each pipeline stage, then in drawing.
    pub fn stage_times(&self) -> Vec<(&'static str, Duration)> {
        let names = Stage::ALL.iter().map(|s| s.name()).chain(["draw"]);
        names.zip(self.times).collect()
    }

    /// Draws one token row of the readout: a `+lr` readout's rejected cells filled
    /// (`bino_core::lr::fill_rejected`), the others' shown dark.
    fn show_row(&mut self, row: usize, disparity_q8: &[u16], consistent: &[u8]) {
        if self.readout.lr {
            let mut filled = disparity_q8.to_vec();
            if bino_core::lr::fill_rejected(&mut filled, consistent).is_ok() {
                self.draw_row(row, &filled, &vec![1; filled.len()]);
            }
        } else {
            self.draw_row(row, disparity_q8, consistent);
        }
    }

    /// Draws one token row (disparity in Q8 patch columns, 1 = passed the left-right check).
    fn draw_row(&mut self, row: usize, disparity_q8: &[u16], consistent: &[u8]) {
        let previous = self.switch(Some(Stage::ALL.len()));
        let unit = (1u32 << DISPARITY_FRAC_BITS) as f32;
        let values: Vec<f32> = disparity_q8.iter().map(|&d| d as f32 / unit).collect();
        let colours = colourise(&values, self.max_disparity);
        let cell = crate::eval::PIXELS_PER_PATCH_COLUMN;
        for (c, rgb) in colours.chunks_exact(3).enumerate() {
            let colour = if consistent.get(c) == Some(&1) {
                Rgb565::from(Rgb888::new(rgb[0], rgb[1], rgb[2]))
            } else {
                REJECTED
            };
            self.panel.fill(
                self.fb,
                (c * cell, (c + 1) * cell),
                (row * cell, (row + 1) * cell),
                colour,
            );
        }
        self.rows_drawn += 1;
        self.switch(previous);
    }

    /// Draws one refined pixel row (Q8 px) on the token rows' colour scale.
    fn draw_pixel_row(&mut self, row: usize, disparity_q8: &[u16]) {
        let previous = self.switch(Some(Stage::ALL.len()));
        let unit = (1u32 << DISPARITY_FRAC_BITS) as f32;
        let values: Vec<f32> = disparity_q8.iter().map(|&d| d as f32 / unit).collect();
        let max_px = self.max_disparity * crate::eval::PIXELS_PER_PATCH_COLUMN as f32;
        for (x, rgb) in colourise(&values, max_px).chunks_exact(3).enumerate() {
            let colour = Rgb565::from(Rgb888::new(rgb[0], rgb[1], rgb[2]));
            self.panel.fill(self.fb, (x, x + 1), (row, row + 1), colour);
        }
        self.rows_drawn += 1;
        self.switch(previous);
    }
}

impl Sink for DisplaySink<'_> {
    fn stage(&mut self, stage: Stage) {
        let bucket = Stage::ALL.iter().position(|&s| s == stage);
        self.switch(bucket);
    }

    fn matched(&mut self, row: &MatchedRow<'_>) {
        if self.readout.refine {
            return;
        }
        match self.readout.method {
            Method::Nolink => self.show_row(row.row, row.wta_q8, row.wta_consistent),
            Method::Sgm => self.show_row(row.row, row.sgm_q8, row.sgm_consistent),
            Method::Head | Method::Fused | Method::Census | Method::CensusFused | Method::FusedAll => {}
        }
    }

    fn head(&mut self, row: HeadRow<'_>) {
        if self.readout.method == Method::Head && !self.readout.refine {
            self.pending_heads.push((row.row, row.disparity_q8.to_vec()));
        }
    }

    fn head_checked(&mut self, row: &HeadChecked<'_>) {
        let Some(at) = self.pending_heads.iter().position(|(r, _)| *r == row.row) else {
            return;
        };
        let (_, disparity) = self.pending_heads.remove(at);
        self.show_row(row.row, &disparity, row.consistent);
    }

    fn fused(&mut self, row: &FusedRow<'_>) {
        if self.readout.fuses() && !self.readout.refine {
            self.show_row(row.row, row.disparity_q8, row.consistent);
        }
    }

    fn census(&mut self, row: &CensusRow<'_>) {
        if self.readout.method == Method::Census && !self.readout.refine {
            self.show_row(row.row, row.disparity_q8, row.consistent);
        }
    }

    fn refined(&mut self, row: usize, disparity_q8: &[u16]) {
        if self.readout.refine {
            self.draw_pixel_row(row, disparity_q8);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_pair_fills_the_width_of_a_qvga_display_twice_stacked() {
        let layout = Layout::new(DisplaySize::QVGA, 320, 96).unwrap();
        // 240 - 23 status rows = 217; two 96-row pictures at scale 1 fit above each other,
        // each centred in its 107-row half.
        assert_eq!(layout.status_y, 217);
        assert_eq!(
            (
                layout.camera.x,
                layout.camera.y,
                layout.camera.width,
                layout.camera.height
            ),
            (0, 5, 320, 96)
        );
        assert_eq!(layout.disparity.width, 320);
        assert_eq!(layout.disparity.height, 96);
        assert_eq!(layout.disparity.y, 107 + 2 + 5);
        assert!(layout.disparity.y + 96 <= layout.status_y);
    }

    #[test]
    fn tall_images_go_side_by_side_and_tiny_displays_are_refused() {
        let layout = Layout::new(DisplaySize::QVGA, 320, 320).unwrap();
        assert_eq!(layout.camera.y, layout.disparity.y, "{layout:?}");
        assert!(layout.disparity.x >= layout.camera.x + layout.camera.width);
        assert!(layout.disparity.x + layout.disparity.width <= 320);
        let tiny = DisplaySize { width: 32, height: 24 };
        assert!(Layout::new(tiny, 320, 96).is_err());
    }

    #[test]
    fn a_row_is_drawn_into_its_cells_and_rejected_cells_are_dark() {
        let size = DisplaySize { width: 64, height: 48 };
        let mut fb = Framebuffer::new(size);
        // A 16x8 image (4 patch columns, 2 token rows) at scale 2 from (10, 4).
        let panel = Panel::fit(10, 4, 32, 16, 16, 8);
        assert_eq!((panel.x, panel.y, panel.width, panel.height), (10, 4, 32, 16));
        let mut sink = DisplaySink::new(&mut fb, panel, Readout::SGM, 4);
        sink.draw_row(1, &[0, 256, 512, 768], &[1, 1, 0, 1]);
        assert_eq!(sink.rows_drawn, 1);
        // Token row 1 is image rows 4..8, display rows 4 + 8..4 + 16; each cell 8 px wide.
        for (c, expected_dark) in [false, false, true, false].into_iter().enumerate() {
            let x = 10 + 8 * c;
            let colour = fb.pixel(x + 3, 12 + 5).unwrap();
            assert_eq!(colour == REJECTED, expected_dark, "cell {c}: {colour:?}");
            assert_eq!(fb.pixel(x, 12), fb.pixel(x + 7, 19), "cell {c} is one colour");
        }
        assert_ne!(fb.pixel(10, 12), fb.pixel(18, 12), "disparity 0 and 1 differ in colour");
        // Nothing outside the row's cells.
        let lit = fb.raw().iter().filter(|&&w| w != 0).count();
        assert_eq!(lit, 4 * 8 * 8);
        assert_eq!(fb.pixel(10, 11), Some(Rgb565::BLACK));
        assert_eq!(fb.pixel(42, 12), Some(Rgb565::BLACK));
    }
}
