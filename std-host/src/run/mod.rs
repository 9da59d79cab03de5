//! `bino run`: the int8 pipeline on any rectified pair: disparity as a colour picture (with its
//! colour bar), as raw float32 (PFM) and a validity mask, at the size of the images given, with
//! timings and arena use.
//!
//! The disparity is the readout's pixel map exactly as `bino eval` scores it
//! ([`crate::readout::MethodMaps::pixels`]) at the profile's size: refined (`+ref`) by default,
//! by the core's pipeline as it streams (every readout but the host-only ones, the unchecked
//! fusions and the export pathway's fuse-census, which are refined on the whole map; tests pin
//! the two equal), `--refine off` for the bilinear
//! upsampling of the token grid; then resampled to the input's size in its pixels
//! ([`answer::to_input_size`]). Dense unless `--invalid inf`: the pixels whose
//! cell the method's own check rejects, or whose view has no texture, are marked in `valid.png`.

pub mod answer;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use bino_core::pipeline::{Refine as CoreRefine, Report as PipelineReport, Stage};
use bino_core::sgm::Penalties;

use crate::data::profile::load_profiled_pair_sized;
use crate::data::profile::Profile;
use crate::eval::{upsample_mask, DisparityMap};
use crate::int8::pipeline_maps::{readout_options, run_census_stream, run_pipeline_refined, streamed_input};
use crate::int8::Int8Model;
use crate::io::colour::colourise;
use crate::io::colour_bar::with_colour_bar;
use crate::readout::pathway::Pathway;
use crate::readout::{Method, Readout};
pub use answer::InvalidPixels;

/// `bino run --refine`: whether the readout's pixels are refined.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Refine {
    /// The readout's `+ref` variant: the integer pixel refinement (the default).
    On,
    /// The token grid upsampled bilinearly (the output before the refinement existed).
    Off,
}

impl Refine {
    /// The readout `bino run` writes for `--readout readout --refine self`: `readout` refined
    /// when on; an error message when a `+ref` readout is asked for with `--refine off`.
    pub fn apply(self, readout: Readout) -> std::result::Result<Readout, String> {
        match self {
            Refine::On => Ok(readout.refined(true)),
            Refine::Off if readout.refine => Err(format!(
                "--readout {readout} asks for the refinement and --refine off refuses it: use --readout {}",
                readout.refined(false)
            )),
            Refine::Off => Ok(readout),
        }
    }
}

/// What `bino run` runs on and where it writes.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Left view.
    pub left: PathBuf,
    /// Right view.
    pub right: PathBuf,
    /// Resolution profile (`native` needs sides that are multiples of 4).
    pub profile: Profile,
    /// Int8 weight blob.
    pub blob: PathBuf,
    /// Readout (with `+ref`: refined pixels; see [`Refine::apply`]); one of the pathway's.
    pub readout: Readout,
    /// Export (two encoder passes, every readout) or native (one pass on (L, R), the head).
    pub pathway: Pathway,
    /// Disparity candidates of nolink and sgm, in patch columns.
    pub max_cols: usize,
    /// SGM penalties.
    pub penalties: Penalties,
    /// Left-right check tolerance in patch columns.
    pub lr_max_diff: f32,
    /// What `disparity.pfm` holds at invalid pixels.
    pub invalid: InvalidPixels,
    /// Output folder.
    pub out: PathBuf,
}

/// What a run measured and wrote.
#[derive(Debug, Clone)]
pub struct RunReport {
    /// Size the pipeline ran at (the profile's).
    pub width: usize,
    /// Height it ran at.
    pub height: usize,
    /// Size of the answer written: the input's (width, height).
    pub output: (usize, usize),
    /// % of pixels valid: their cell passes the readout's own check and holds texture.
    pub density: f64,
    /// What the user should know before trusting the answer ([`answer::warnings`]).
    pub warnings: Vec<String>,
    /// Wall time of each step.
    pub timings: Vec<(&'static str, Duration)>,
    /// Wall time inside the core pipeline, per stage.
    pub stage_times: Vec<(Stage, Duration)>,
    /// The core pipeline's report (arena use by part, bands, left-right counts).
    pub pipeline: PipelineReport,
    /// Arena bytes allocated: the blob's own size (`Pipeline::arena_bytes`).
    pub arena_bytes: usize,
    /// Files written.
    pub files: Vec<PathBuf>,
}

/// Runs the pipeline; `progress` hears about each step before it starts.
pub fn run_pair(opts: &RunOptions, mut progress: impl FnMut(&str)) -> Result<RunReport> {
    let mut timings = Vec::new();
    let step = |name: &'static str, timings: &mut Vec<(&'static str, Duration)>, progress: &mut dyn FnMut(&str)| {
        progress(name);
        timings.push((name, Duration::ZERO));
        Instant::now()
    };
    opts.pathway.check(opts.readout)?;
    crate::io::files::check_output_dir(&opts.out, "--out")?;
    let started = step("loading the pair and the blob", &mut timings, &mut progress);
    let (left, right, input) = load_profiled_pair_sized(&opts.left, &opts.right, opts.profile)?;
    // The census readouts read pixels only: no blob, no encoder.
    let census_only = opts.readout.method == Method::Census;
    let model = match census_only {
        true => None,
        false => Some(Int8Model::load(&opts.blob)?),
    };
    if let (true, Some(model)) = (opts.readout.uses_head(), model.as_ref()) {
        model.require_head(opts.pathway.core())?;
    }
    finish(&mut timings, started);

    let pipeline_step = match (census_only, opts.pathway) {
        (true, _) => "integer pipeline: rows -> census SGM -> left-right check -> pixels, band by band (no encoder)",
        (false, Pathway::Export) => "int8 pipeline: rows -> encoder (L,L), (R,R) -> readouts, band by band",
        (false, Pathway::Native) => "int8 pipeline: rows -> encoder (L,R) -> native head, band by band",
    };
    let started = step(pipeline_step, &mut timings, &mut progress);
    let pipeline_opts = readout_options(
        opts.readout,
        opts.pathway,
        opts.max_cols,
        opts.penalties,
        opts.lr_max_diff,
        left.width,
    );
    let mut on_band = |i: usize, n: usize| {
        if n > 1 {
            progress(&format!("  band {i} of {n}"));
        }
    };
    // A `+ref` readout the core streams is refined in the pipeline, as the board refines it;
    // the host-only ones (the unchecked fusions, the export pathway's fuse-census), on the
    // whole map.
    let refine = match (opts.readout.refine, streamed_input(opts.readout, opts.pathway)) {
        (true, Some(input)) => Some(CoreRefine::for_width(input, left.width)),
        _ => None,
    };
    let maps = match model.as_ref() {
        Some(model) => run_pipeline_refined(model, &left, &right, &pipeline_opts, refine.as_ref(), &mut on_band)?,
        None => run_census_stream(&left, &right, &pipeline_opts, opts.readout)?,
    };
    finish(&mut timings, started);

    let pixels = match (opts.readout.refine, maps.refined.is_some()) {
        (true, true) => "left-right mask (pixels refined in the pipeline)",
        (true, false) => "pixels (integer refinement), left-right mask",
        (false, _) => "pixels (bilinear), left-right mask",
    };
    let started = step(pixels, &mut timings, &mut progress);
    // The readout exactly as `bino eval` scores it (the core's refined rows equal it, pinned by
    // tests); the mask is its method's own check.
    let disparity = match maps.refined {
        Some(refined) => refined,
        None => maps.methods.pixels(opts.readout)?,
    };
    let (tokens, consistent) = maps.methods.method(opts.readout.method)?;
    let consistent = consistent.context("the method's left-right check did not run")?;
    // Valid: the method's own check keeps the cell and the view has texture there.
    let views = &maps.methods.views;
    let textured = answer::textured_cells(&views.left, views.width, views.height)?;
    let cells: Vec<bool> = consistent.iter().zip(&textured).map(|(&c, &t)| c && t).collect();
    let valid = upsample_mask(&cells, tokens.width, disparity.width, disparity.height);
    let (disparity, valid) = answer::to_input_size(&disparity, &valid, opts.profile, input)?;
    let disparity = match opts.invalid {
        InvalidPixels::Keep => disparity,
        InvalidPixels::Inf => answer::mark_invalid(&disparity, &valid),
    };
    finish(&mut timings, started);

    let started = step("writing outputs", &mut timings, &mut progress);
    let files = write_outputs(&opts.out, &disparity, &valid)?;
    finish(&mut timings, started);
    let density = 100.0 * valid.iter().filter(|&&v| v).count() as f64 / valid.len().max(1) as f64;
    Ok(RunReport {
        width: left.width,
        height: left.height,
        output: input,
        warnings: answer::warnings(input, (left.width, left.height)),
        density,
        timings,
        stage_times: maps.stage_times,
        pipeline: maps.report,
        arena_bytes: maps.arena_bytes,
        files,
    })
}

fn finish(timings: &mut [(&'static str, Duration)], started: Instant) {
    if let Some(last) = timings.last_mut() {
        last.1 = started.elapsed();
    }
}

fn write_outputs(out: &Path, disparity: &DisparityMap, valid: &[bool]) -> Result<Vec<PathBuf>> {
    crate::io::files::create_dir(out)?;
    let (w, h) = (disparity.width, disparity.height);
    let max = disparity
        .values
        .iter()
        .cloned()
        .filter(|v| v.is_finite())
        .fold(1.0f32, f32::max);
    let colour = image::RgbImage::from_raw(w as u32, h as u32, colourise(&disparity.values, max))
        .context("disparity picture size")?;
    let png = out.join("disparity.png");
    crate::io::files::save_png(&with_colour_bar(colour, max).into(), &png)?;
    let mask = image::GrayImage::from_raw(
        w as u32,
        h as u32,
        valid.iter().map(|&v| if v { 255 } else { 0 }).collect(),
    )
    .context("mask size")?;
    let mask_path = out.join("valid.png");
    crate::io::files::save_png(&mask.into(), &mask_path)?;
    let pfm = out.join("disparity.pfm");
    crate::io::files::write_bytes(&pfm, &pfm_bytes(disparity))?;
    Ok(vec![png, pfm, mask_path])
}

/// Grayscale PFM: header, then float32 little-endian rows from the bottom up.
pub fn pfm_bytes(map: &DisparityMap) -> Vec<u8> {
    let mut bytes = Vec::with_capacity(32 + map.values.len() * 4);
    let _ = write!(bytes, "Pf\n{} {}\n-1.0\n", map.width, map.height);
    for row in map.values.chunks_exact(map.width.max(1)).rev() {
        for v in row {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    bytes
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(width: usize, values: Vec<f32>) -> DisparityMap {
        DisparityMap {
            width,
            height: values.len() / width,
            values,
        }
    }

    #[test]
    fn pfm_has_the_header_and_bottom_up_rows() {
        let bytes = pfm_bytes(&map(2, vec![1.0, 2.0, 3.0, 4.0]));
        let header = b"Pf\n2 2\n-1.0\n";
        assert_eq!(&bytes[..header.len()], header);
        let first = f32::from_le_bytes(bytes[header.len()..header.len() + 4].try_into().unwrap());
        assert_eq!(first, 3.0, "the bottom row comes first");
        assert_eq!(bytes.len(), header.len() + 16);
    }

    #[test]
    fn refine_picks_the_readout() {
        let sgm_lr = "sgm+lr".parse::<Readout>().unwrap();
        assert_eq!(Refine::On.apply(sgm_lr).unwrap().name(), "sgm+lr+ref");
        assert_eq!(Refine::On.apply(sgm_lr.refined(true)).unwrap().name(), "sgm+lr+ref");
        assert_eq!(Refine::Off.apply(sgm_lr).unwrap(), sgm_lr);
        let err = Refine::Off.apply(sgm_lr.refined(true)).unwrap_err();
        assert!(err.contains("--readout sgm+lr"), "{err}");
    }
}
