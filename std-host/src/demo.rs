//! `bino demo`: the int8 pipeline end to end on the built-in procedural scene, with no data
//! files: encoder on both views (descriptor pathway), the no-linkage readout and the shared
//! head (also `head+lr` and its pixel refinement `head+lr+ref`, as `bino_host::readout` defines
//! them), and, when the blob carries it, the native pathway (one encoder pass on (L, R), the
//! native head: `native_head`, `native_head+lr`, `native_head+lr+ref`, through the streaming
//! core pipeline), scored against the scene's known disparity, written as pictures and a report.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{ensure, Context, Result};
use bino_core::config::HEAD_MAX_DISP;
use bino_core::model::ids::HeadKind;

use bino_core::pipeline::{self, Options as PipelineOptions, Pathway, Refine, RefineInput};
use bino_core::sgm::Penalties;
use serde::Serialize;

use crate::data::profile::{Profile, View};
use crate::data::synthetic::{default_scene, SyntheticPair};
use crate::eval::{score, upsample_disparity, DisparityMap, GroundTruthMap, Metrics};
use crate::int8::pipeline_maps::{run_census_stream, run_pipeline};
use crate::int8::{guide_map, match_rows, sgm_rows, Int8Model};
use crate::io::colour::{colourise, error_colour};
use crate::io::keyed::Keyed;
use crate::readout::refine::{refine_pixels, GrayViews};
use crate::readout::Readout;

/// The int8 blob shipped with the repository (found from any working directory): the file
/// [`crate::io::checkout::path`] gives for [`crate::io::checkout::BLOB`], as a `&str`.
pub const DEFAULT_BLOB: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../weights/bino_int8.bin");

/// Errors above this many pixels are drawn at full strength in the error maps.
const ERROR_MAP_MAX_PX: f32 = 8.0;
/// Left-right tolerance of head+lr: one patch column, the CLI's `--lr-max-diff` default.
const DEMO_LR_MAX_DIFF_Q8: u16 = 256;

/// What the demo runs on and where it writes.
#[derive(Debug, Clone)]
pub struct DemoOptions {
    /// Int8 weight blob.
    pub blob: PathBuf,
    /// Output folder (created).
    pub out: PathBuf,
    /// Scene width in pixels (multiple of 4, at most the blob's maximum width).
    pub width: usize,
    /// Scene height in pixels (multiple of 4; taller than one band means overlapping bands).
    pub height: usize,
    /// Disparity candidates of the no-linkage readout, in patch columns.
    pub max_cols: usize,
    /// SGM penalties (cost units: 4096 = cosine 1).
    pub penalties: Penalties,
}

/// SGM penalties of every command, in cost units: the core's (`bino_core::sgm::DEFAULT_PENALTIES`,
/// chosen on held-out train pairs, not on the demo's scene nor on the eval split), so the host
/// runs what the firmware runs.
pub const DEFAULT_PENALTIES: Penalties = bino_core::sgm::DEFAULT_PENALTIES;

/// One readout scored against the scene's true disparity.
#[derive(Debug, Clone, PartialEq)]
pub struct ReadoutResult {
    /// `nolink`, `sgm`, `head`, `head+lr`, `head+lr+ref`, or the native pathway's
    /// `native_head`, `native_head+lr`, `native_head+lr+ref`.
    pub name: &'static str,
    /// EVAL.md metrics (pixels at the scene's resolution).
    pub metrics: Metrics,
    /// Per-pixel disparity in pixels.
    pub disparity: DisparityMap,
}

/// Everything the demo measured.
#[derive(Debug, Clone)]
pub struct DemoReport {
    /// Scene size.
    pub width: usize,
    /// Scene height.
    pub height: usize,
    /// Readouts, no-linkage first, then the head if the blob has one.
    pub readouts: Vec<ReadoutResult>,
    /// Wall time of each step.
    pub timings: Vec<(&'static str, Duration)>,
    /// Arena bytes each streamed readout needs for this scene with its refinement (the sizes
    /// `bino_core::pipeline` checks a run against): the census alone, then each pathway's
    /// learned readout whose head the blob carries.
    pub arenas: Vec<(&'static str, usize)>,
    /// Files written.
    pub files: Vec<PathBuf>,
}

/// Runs the demo; `progress` hears about each step before it starts.
pub fn run_demo(opts: &DemoOptions, mut progress: impl FnMut(&str)) -> Result<DemoReport> {
    ensure!(
        opts.width.is_multiple_of(4) && opts.height.is_multiple_of(4) && opts.width >= 16 && opts.height >= 16,
        "scene size {}x{} must be multiples of 4, at least 16",
        opts.width,
        opts.height
    );
    let mut steps = Steps {
        timings: Vec::new(),
        progress: &mut progress,
    };
    let model = steps.run("loading the int8 blob", || {
        Int8Model::load(&opts.blob).with_context(|| format!("the demo needs the int8 blob {}", opts.blob.display()))
    })?;

    let scene = default_scene(opts.width, opts.height);
    let left = Profile::Native.apply(&scene.left)?;
    let right = Profile::Native.apply(&scene.right)?;
    let (cols, bands_left) = steps.run("encoding the left view (int8)", || {
        model.descriptor_bands(&left).context("left view")
    })?;
    let (_, bands_right) = steps.run("encoding the right view (int8)", || {
        model.descriptor_bands(&right).context("right view")
    })?;
    let (rows, codes_left, codes_right) = (bands_left.rows, bands_left.assemble(), bands_right.assemble());

    let truth = ground_truth(&scene);
    let mut readouts = Vec::new();
    readouts.push(steps.run("no-linkage matching (integer, row by row)", || {
        let tokens = match_rows(&codes_left, &codes_right, rows, cols, opts.max_cols)?;
        scored("nolink", &tokens, &truth)
    })?);
    readouts.push(steps.run("SGM, 4 streaming paths (integer)", || {
        let guide = if opts.penalties.guided() {
            Some(guide_map(&left)?)
        } else {
            None
        };
        let tokens = sgm_rows(
            &codes_left,
            &codes_right,
            rows,
            cols,
            opts.max_cols,
            opts.penalties,
            guide.as_deref(),
        )?;
        scored("sgm", &tokens, &truth)
    })?);
    if model.has_head() {
        let maps = steps.run("shared head (int8, streamed row by row)", || {
            // Each band's head on its own rows, as the core's export pathway runs it.
            model.head_banded(&bands_left, &bands_right, cols, HEAD_MAX_DISP)
        })?;
        let tokens = DisparityMap {
            width: cols,
            height: rows,
            values: maps.disparity.clone(),
        };
        readouts.push(scored("head", &tokens, &truth)?);
        let (filled, kept) = steps.run("head+lr: the head on the mirrored pair, left-right fill", || {
            let kept = model.head_check(&bands_left, &bands_right, &maps, HEAD_MAX_DISP, DEMO_LR_MAX_DIFF_Q8)?;
            Ok((
                crate::readout::fill_rejected(&tokens, &kept, crate::readout::Method::Head.fill()),
                kept,
            ))
        })?;
        readouts.push(scored("head+lr", &filled, &truth)?);
        readouts.push(steps.run(
            "head+lr+ref: integer pixel refinement (census 5x5, 9x9 box, search by width; rejected cells kept)",
            || {
                let views = GrayViews::from_views(&left, &right)?;
                let disparity = refine_pixels(&filled, &views, Some(&kept))?;
                scored_pixels("head+lr+ref", disparity, &truth)
            },
        )?);
    }
    let census = pipeline_options(opts, Pathway::Export, left.width);
    let default = crate::readout::pathway::DEFAULT_READOUT.refined(true);
    let maps = steps.run(
        "census+lr+ref: census SGM of the pixels, its check, refined, no encoder (`bino run`'s default; streamed)",
        || run_census_stream(&left, &right, &census, default),
    )?;
    let refined = maps.refined.context("the census run refined no pixels")?;
    readouts.push(scored_pixels("census+lr+ref", refined, &truth)?);
    if model.has_head() {
        let export = pipeline_options(opts, Pathway::Export, left.width);
        let maps = steps.run(
            "fuse-all+lr+ref: head, census SGM and SGM fused by their checks, refined (the export pathway's; int8 pipeline)",
            || run_pipeline(&model, &left, &right, &export, &mut |_, _| {}),
        )?;
        let fused = crate::readout::pathway::Pathway::Export.default_readout().refined(true);
        readouts.push(scored_pixels("fuse-all+lr+ref", maps.methods.pixels(fused)?, &truth)?);
    }
    if model.has_head_of(HeadKind::Native) {
        let native = pipeline_options(opts, Pathway::Native, left.width);
        let maps = steps.run(
            "native pathway: one encoder pass on (L, R), native head and its check, fused with the census SGM (int8 pipeline)",
            || run_pipeline(&model, &left, &right, &native, &mut |_, _| {}),
        )?;
        for (name, readout) in [
            ("native_head", Readout::HEAD),
            ("native_head+lr", Readout::HEAD_LR),
            ("native_head+lr+ref", Readout::HEAD_LR.refined(true)),
            (
                "native_fuse-census+lr+ref",
                crate::readout::pathway::Pathway::Native.default_readout().refined(true),
            ),
        ] {
            readouts.push(scored_pixels(name, maps.methods.pixels(readout)?, &truth)?);
        }
    }
    let files = steps.run("writing pictures and report", || {
        write_outputs(opts, &scene, &left, &right, &readouts)
    })?;
    let timings = steps.timings;

    Ok(DemoReport {
        width: opts.width,
        height: opts.height,
        readouts,
        timings,
        arenas: arenas(opts, &model),
        files,
    })
}

/// The arena of each streamed readout the demo scores, refinement included.
fn arenas(opts: &DemoOptions, model: &Int8Model) -> Vec<(&'static str, usize)> {
    let (w, h) = (opts.width, opts.height);
    let census = pipeline_options(opts, Pathway::Export, w);
    let refine = Refine::for_width(RefineInput::CensusLr, w);
    let mut out = vec![(
        "census+lr+ref",
        pipeline::census_arena_bytes(h, w, &census, Some(&refine)),
    )];
    for (name, pathway, kind) in [
        ("export fuse-all+lr+ref", Pathway::Export, HeadKind::Export),
        ("native fuse-census+lr+ref", Pathway::Native, HeadKind::Native),
    ] {
        if model.has_head_of(kind) {
            let learned = pipeline_options(opts, pathway, w);
            let refine = Refine::for_width(RefineInput::for_options(&learned), w);
            out.push((name, pipeline::arena_bytes_refined(h, w, &learned, &refine)));
        }
    }
    out
}

/// Runs the demo's steps in order, announcing and timing each.
struct Steps<'a, P: FnMut(&str)> {
    timings: Vec<(&'static str, Duration)>,
    progress: &'a mut P,
}

impl<P: FnMut(&str)> Steps<'_, P> {
    fn run<T>(&mut self, name: &'static str, step: impl FnOnce() -> Result<T>) -> Result<T> {
        (self.progress)(name);
        let started = Instant::now();
        let value = step()?;
        self.timings.push((name, started.elapsed()));
        Ok(value)
    }
}

/// The pipeline's options for `pathway` on views `width` px wide: the head with its check, the
/// demo's candidates, penalties and tolerance.
fn pipeline_options(opts: &DemoOptions, pathway: Pathway, width: usize) -> PipelineOptions {
    PipelineOptions {
        pathway,
        max_cols: opts.max_cols,
        penalties: opts.penalties,
        lr_max_diff_q8: DEMO_LR_MAX_DIFF_Q8,
        head: true,
        head_lr: true,
        head_candidates: crate::readout::head_candidates(width),
    }
}

fn ground_truth(scene: &SyntheticPair) -> GroundTruthMap {
    GroundTruthMap {
        width: scene.left.width,
        height: scene.left.height,
        disparity: scene.disparity.clone(),
        valid: vec![true; scene.disparity.len()],
    }
}

fn scored(name: &'static str, tokens: &DisparityMap, truth: &GroundTruthMap) -> Result<ReadoutResult> {
    scored_pixels(name, upsample_disparity(tokens), truth)
}

fn scored_pixels(name: &'static str, disparity: DisparityMap, truth: &GroundTruthMap) -> Result<ReadoutResult> {
    let metrics = score(&disparity, truth).with_context(|| format!("scoring the {name} readout"))?;
    Ok(ReadoutResult {
        name,
        metrics,
        disparity,
    })
}

fn write_outputs(
    opts: &DemoOptions,
    scene: &SyntheticPair,
    left: &View,
    right: &View,
    readouts: &[ReadoutResult],
) -> Result<Vec<PathBuf>> {
    crate::io::files::create_dir(&opts.out)?;
    let (w, h) = (scene.left.width, scene.left.height);
    let max_disparity = scene.disparity.iter().cloned().fold(1.0f32, f32::max);
    let mut files = Vec::new();
    let mut save = |name: &str, image: image::DynamicImage| -> Result<()> {
        let path = opts.out.join(name);
        crate::io::files::save_png(&image, &path)?;
        files.push(path);
        Ok(())
    };
    save("left.png", gray(left)?)?;
    save("right.png", gray(right)?)?;
    save(
        "disparity_true.png",
        rgb(w, h, colourise(&scene.disparity, max_disparity))?,
    )?;
    for r in readouts {
        save(
            &format!("disparity_{}.png", r.name),
            rgb(w, h, colourise(&r.disparity.values, max_disparity))?,
        )?;
        let errors: Vec<f32> = (r.disparity.values.iter().zip(&scene.disparity))
            .map(|(p, t)| (p - t).abs())
            .collect();
        save(
            &format!("error_{}.png", r.name),
            rgb(w, h, error_colour(&errors, ERROR_MAP_MAX_PX))?,
        )?;
    }
    let report = opts.out.join("report.json");
    crate::io::files::write_bytes(&report, (report_json(opts, readouts) + "\n").as_bytes())?;
    files.push(report);
    Ok(files)
}

fn report_json(opts: &DemoOptions, readouts: &[ReadoutResult]) -> String {
    let json = DemoJson {
        tool: "bino demo",
        blob: opts.blob.display().to_string(),
        width: opts.width,
        height: opts.height,
        scene: "built-in procedural planes: background d=4 px, boxes d=10 and 16 px",
        readouts: Keyed(readouts.iter().map(|r| (r.name.to_string(), r.metrics)).collect()),
    };
    serde_json::to_string_pretty(&json).expect("plain structs serialise")
}

// `report.json`: what ran on what, then each readout's metrics keyed by its name.
#[derive(Serialize)]
struct DemoJson {
    tool: &'static str,
    blob: String,
    width: usize,
    height: usize,
    scene: &'static str,
    #[serde(flatten)]
    readouts: Keyed<Metrics>,
}

fn gray(view: &View) -> Result<image::DynamicImage> {
    let pixels = crate::int8::to_u8(&view.pixels);
    let image = image::GrayImage::from_raw(view.width as u32, view.height as u32, pixels)
        .context("view size does not match its pixels")?;
    Ok(image.into())
}

fn rgb(width: usize, height: usize, pixels: Vec<u8>) -> Result<image::DynamicImage> {
    let image = image::RgbImage::from_raw(width as u32, height as u32, pixels)
        .context("picture size does not match its pixels")?;
    Ok(image.into())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_sizes_and_missing_blobs_are_errors() {
        let opts = DemoOptions {
            blob: PathBuf::from("/nonexistent/blob.bin"),
            out: std::env::temp_dir().join("bino-demo-test"),
            width: 162,
            height: 48,
            max_cols: 10,
            penalties: DEFAULT_PENALTIES,
        };
        let err = run_demo(&opts, |_| {}).unwrap_err().to_string();
        assert!(err.contains("multiples of 4"), "{err}");
        let opts = DemoOptions { width: 160, ..opts };
        let err = format!("{:#}", run_demo(&opts, |_| {}).unwrap_err());
        assert!(err.contains("/nonexistent/blob.bin"), "{err}");
    }

    #[test]
    fn ground_truth_is_the_scene_disparity() {
        let scene = default_scene(64, 48);
        let truth = ground_truth(&scene);
        assert_eq!(truth.disparity, scene.disparity);
        assert_eq!(truth.valid_count(), 64 * 48);
    }
}
