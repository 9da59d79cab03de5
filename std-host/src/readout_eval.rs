//! `bino eval`: BINO's readouts on every pair of a split that has ground truth, in int8 (the
//! core pipeline) and in float (tract descriptors through the float twins of the same
//! readouts), next to OpenCV StereoSGBM on the same profile images, scored with EVAL.md's
//! metrics per pair and on average.
//!
//! Readouts: `nolink` (cosine WTA + parabola), `sgm` (4 streaming paths + parabola) and `head`
//! (the shared head), each also `+lr` and each of those also `+ref` (the integer pixel
//! refinement, the same for both precisions: [`crate::refine`]). Each method's left-right check
//! also gives `LRkeep` (% of ground-truth pixels whose cell passes it) and the error on those
//! pixels only (`GT+LR`). Every score also exists on the large-disparity subset (`large`: the
//! top quartile of each pair's ground-truth disparities, the paper's stress test), and
//! `--occlude` adds the paper's one-view occlusion benchmark ([`crate::occlusion`]).

use std::path::PathBuf;
use std::str::FromStr;
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context, Result};
use bino_core::config::{CELL_W, HEAD_CANDIDATES_LIMIT, HEAD_MAX_DISP};
use bino_core::pipeline::Options as PipelineOptions;
use bino_core::sgm::Penalties;
use serde::Serialize;

use crate::eval::float_twins::{consistent, right_view, sgm};
use crate::eval::{
    density, load_eval_item, mean_metrics, score, score_sparse, similarity_volume, upsample_mask, wta_subtoken,
    DisparityMap, EvalItem, GroundTruthMap, Metrics,
};
use crate::float_head::FloatHead;
use crate::int8::{guide_map, to_u8, Int8Model};
use crate::keyed::Keyed;
use crate::nuisance::{degrade_item, Nuisance};
use crate::occlusion::{check_severities, occlude_item};
use crate::pairs::{read_index, Split};
use crate::pathway::Pathway;
use crate::pipeline_maps::run_pipeline;
use crate::profile::{Profile, View};
use crate::readout::MethodMaps;
pub use crate::readout::Readout;
use crate::reference::ReferenceEncoder;
use crate::refine::GrayViews;
use crate::sgbm::{GrayPair, SgbmRunner};

/// The arithmetic a readout runs in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Precision {
    /// The int8 engine and the core's integer readouts.
    Int8,
    /// tract on the float ONNX models and the float twins of the readouts.
    F32,
}

impl Precision {
    /// Its name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Precision::Int8 => "int8",
            Precision::F32 => "f32",
        }
    }
}

impl FromStr for Precision {
    type Err = anyhow::Error;

    fn from_str(s: &str) -> Result<Self> {
        match s {
            "int8" => Ok(Precision::Int8),
            "f32" => Ok(Precision::F32),
            other => bail!("unknown precision {other:?} (expected int8 or f32)"),
        }
    }
}

/// What `bino eval` runs.
#[derive(Debug, Clone)]
pub struct EvalOptions {
    /// Folder with PAIRS.tsv.
    pub data: PathBuf,
    /// Split name (pairs need ground truth).
    pub split: String,
    /// EVAL.md resolution profile.
    pub profile: Profile,
    /// Int8 weight blob.
    pub blob: PathBuf,
    /// Float encoder (ONNX), for `f32`.
    pub onnx: PathBuf,
    /// Float head (ONNX), for `f32` with the `head` readout.
    pub head_onnx: PathBuf,
    /// Precisions to run, in order.
    pub precisions: Vec<Precision>,
    /// Readouts to score, in order (each one of the pathway's).
    pub readouts: Vec<Readout>,
    /// Export (two encoder passes, every readout) or native (one pass on (L, R), its head).
    pub pathway: Pathway,
    /// Float native-pathway head (ONNX), for `f32` on the native pathway.
    pub native_head_onnx: PathBuf,
    /// Disparity candidates of `nolink` and `sgm`, in patch columns.
    pub max_cols: usize,
    /// SGM penalties.
    pub penalties: Penalties,
    /// Left-right check tolerance, patch columns.
    pub lr_max_diff: f32,
    /// Run StereoSGBM (Python, OpenCV) on the same pairs.
    pub sgbm: bool,
    /// Only the first this many pairs.
    pub limit: Option<usize>,
    /// Nuisances of the right view, each scored over the whole set after the clean run.
    pub nuisances: Vec<Nuisance>,
    /// Seed of the nuisances and occlusions (with each pair's id).
    pub seed: u64,
    /// One-view occlusion severities, % of the right view's area, rising; each scored over the
    /// whole set after the clean run ([`crate::occlusion`]).
    pub occlusions: Vec<u32>,
}

impl EvalOptions {
    /// The table's rows: every precision with every readout.
    pub fn rows(&self) -> Vec<(Precision, Readout)> {
        self.precisions
            .iter()
            .flat_map(|&p| self.readouts.iter().map(move |&r| (p, r)))
            .collect()
    }
}

/// One readout's scores on one pair (or their mean).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ReadoutScore {
    /// EVAL.md metrics over every ground-truth pixel (the readout is dense).
    pub metrics: Metrics,
    /// % of ground-truth pixels whose cell passes the left-right check (`nolink`, `sgm`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lr_keep: Option<f64>,
    /// epe over the ground-truth pixels that pass the left-right check.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gt_lr_epe: Option<f64>,
    /// The same metrics on the large-disparity subset
    /// ([`GroundTruthMap::large_disparity_subset`]).
    pub large: Metrics,
}

/// How the right view was degraded for a run over the set.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Degradation {
    /// One of `--nuisance`.
    Nuisance(Nuisance),
    /// One-view occlusion of this % of the area (`--occlude`).
    Occlusion(u32),
}

impl Degradation {
    /// Its name in reports: the nuisance's, or `occlusion N%`.
    pub fn name(self) -> String {
        match self {
            Degradation::Nuisance(n) => n.name().to_string(),
            Degradation::Occlusion(p) => format!("occlusion {p}%"),
        }
    }
}

/// One pair's scores, a row each (in [`EvalOptions::rows`] order), and SGBM's.
#[derive(Debug, Clone)]
pub struct PairEval {
    /// The pair's id.
    pub pair_id: String,
    /// Scores per row.
    pub scores: Vec<ReadoutScore>,
    /// StereoSGBM on the same images (its invalid pixels filled as EVAL.md says).
    pub sgbm: Option<Metrics>,
    /// StereoSGBM on the large-disparity subset.
    pub sgbm_large: Option<Metrics>,
    /// Wall time for the pair (every precision and readout).
    pub elapsed: Duration,
    /// How the right view was degraded (None: clean).
    pub nuisance: Option<Degradation>,
}

/// The whole set's scores under one condition of the right view.
#[derive(Debug, Clone)]
pub struct SetEval {
    /// Per pair.
    pub pairs: Vec<PairEval>,
    /// Mean per row.
    pub mean: Vec<ReadoutScore>,
    /// SGBM's mean.
    pub sgbm_mean: Option<Metrics>,
    /// SGBM's mean on the large-disparity subsets.
    pub sgbm_large_mean: Option<Metrics>,
}

/// The whole set under one nuisance.
#[derive(Debug, Clone)]
pub struct NuisanceEval {
    /// The nuisance.
    pub nuisance: Nuisance,
    /// Its scores.
    pub set: SetEval,
}

/// The whole set with the right view occluded at one severity.
#[derive(Debug, Clone)]
pub struct OcclusionEval {
    /// % of the right view's area covered.
    pub percent: u32,
    /// Its scores.
    pub set: SetEval,
}

/// Every pair and the unweighted mean.
#[derive(Debug, Clone)]
pub struct EvalReport {
    /// The options it ran with.
    pub options: EvalOptions,
    /// Per pair.
    pub pairs: Vec<PairEval>,
    /// Mean per row.
    pub mean: Vec<ReadoutScore>,
    /// SGBM's mean.
    pub sgbm_mean: Option<Metrics>,
    /// SGBM's mean on the large-disparity subsets.
    pub sgbm_large_mean: Option<Metrics>,
    /// The same under each nuisance, in [`EvalOptions::nuisances`] order.
    pub nuisances: Vec<NuisanceEval>,
    /// The same under each occlusion severity, in [`EvalOptions::occlusions`] order.
    pub occlusions: Vec<OcclusionEval>,
}

/// Runs the readouts over the split; `progress(done, total, pair)` after each pair.
pub fn evaluate(opts: &EvalOptions, mut progress: impl FnMut(usize, usize, &PairEval)) -> Result<EvalReport> {
    ensure!(!opts.readouts.is_empty(), "no readout to evaluate");
    ensure!(!opts.precisions.is_empty(), "no precision to evaluate");
    ensure!(opts.limit != Some(0), "--limit must be at least 1");
    for (i, n) in opts.nuisances.iter().enumerate() {
        ensure!(
            !opts.nuisances[..i].contains(n),
            "--nuisance {} is given twice",
            n.name()
        );
    }
    check_severities(&opts.occlusions)?;
    let split = match opts.split.as_str() {
        "eval" => Split::Eval,
        "val" => Split::Val,
        other => bail!("split {other:?}: only eval and val pairs carry ground truth (use --split eval)"),
    };
    for &readout in &opts.readouts {
        opts.pathway.check(readout)?;
    }
    let wants = |p: Precision| opts.precisions.contains(&p);
    let head = opts.readouts.iter().any(|r| r.uses_head());
    let model = if wants(Precision::Int8) {
        let model = Int8Model::load(&opts.blob)?;
        if head {
            model.require_head(opts.pathway.core())?;
        }
        Some(model)
    } else {
        None
    };
    let mut float = if wants(Precision::F32) {
        let encoder = ReferenceEncoder::load(&opts.onnx)?;
        let head_onnx = match opts.pathway {
            Pathway::Export => &opts.head_onnx,
            Pathway::Native => &opts.native_head_onnx,
        };
        let head = if head {
            Some(FloatHead::from_onnx(head_onnx)?)
        } else {
            None
        };
        Some((encoder, head))
    } else {
        None
    };
    let sgbm = if opts.sgbm { Some(SgbmRunner::locate()?) } else { None };
    let records: Vec<_> = read_index(&opts.data)?
        .into_iter()
        .filter(|r| r.split == split)
        .take(opts.limit.unwrap_or(usize::MAX))
        .collect();
    ensure!(!records.is_empty(), "no {split} pairs in {}", opts.data.display());
    let items = records
        .iter()
        .map(|r| load_eval_item(r, opts.profile))
        .collect::<Result<Vec<_>>>()?;
    let mut run = |items: &[EvalItem], condition| {
        evaluate_set(
            opts,
            model.as_ref(),
            &mut float,
            sgbm.as_ref(),
            items,
            condition,
            &mut progress,
        )
    };
    let clean = run(&items, None)?;
    let mut nuisances = Vec::with_capacity(opts.nuisances.len());
    for &nuisance in &opts.nuisances {
        let degraded: Vec<EvalItem> = items.iter().map(|i| degrade_item(i, nuisance, opts.seed)).collect();
        let set = run(&degraded, Some(Degradation::Nuisance(nuisance)))?;
        nuisances.push(NuisanceEval { nuisance, set });
    }
    let mut occlusions = Vec::with_capacity(opts.occlusions.len());
    for &percent in &opts.occlusions {
        let occluded = (items.iter())
            .map(|i| occlude_item(i, percent, opts.seed))
            .collect::<Result<Vec<_>>>()?;
        let set = run(&occluded, Some(Degradation::Occlusion(percent)))?;
        occlusions.push(OcclusionEval { percent, set });
    }
    Ok(EvalReport {
        options: opts.clone(),
        pairs: clean.pairs,
        mean: clean.mean,
        sgbm_mean: clean.sgbm_mean,
        sgbm_large_mean: clean.sgbm_large_mean,
        nuisances,
        occlusions,
    })
}

type FloatModels = Option<(ReferenceEncoder, Option<FloatHead>)>;

/// Every row and SGBM over `items` (right views under `nuisance`, already applied).
fn evaluate_set(
    opts: &EvalOptions,
    model: Option<&Int8Model>,
    float: &mut FloatModels,
    sgbm: Option<&SgbmRunner>,
    items: &[EvalItem],
    nuisance: Option<Degradation>,
    progress: &mut impl FnMut(usize, usize, &PairEval),
) -> Result<SetEval> {
    let sgbm_scores = match sgbm {
        Some(runner) => Some(sgbm_metrics(runner, items)?),
        None => None,
    };
    let mut pairs = Vec::with_capacity(items.len());
    for (i, item) in items.iter().enumerate() {
        let started = Instant::now();
        let mut scores = Vec::new();
        for &precision in &opts.precisions {
            let maps = match precision {
                Precision::Int8 => int8_maps(opts, model.context("int8 model")?, item)?,
                Precision::F32 => {
                    let (encoder, head) = float.as_mut().context("float model")?;
                    float_maps(opts, encoder, head.as_mut(), item)?
                }
            };
            for &readout in &opts.readouts {
                scores.push(
                    score_readout(&maps, readout, &item.gt)
                        .with_context(|| format!("pair {}: {} {}", item.pair_id, precision.name(), readout.name()))?,
                );
            }
        }
        let pair = PairEval {
            pair_id: item.pair_id.clone(),
            scores,
            sgbm: sgbm_scores.as_ref().map(|s| s[i].0),
            sgbm_large: sgbm_scores.as_ref().map(|s| s[i].1),
            elapsed: started.elapsed(),
            nuisance,
        };
        progress(i + 1, items.len(), &pair);
        pairs.push(pair);
    }
    let mean = (0..opts.rows().len())
        .map(|r| mean_score(&pairs.iter().map(|p| p.scores[r]).collect::<Vec<_>>()))
        .collect::<Result<Vec<_>>>()?;
    let sgbm_mean_of = |which: fn(&(Metrics, Metrics)) -> Metrics| match &sgbm_scores {
        Some(s) => mean_metrics(&s.iter().map(which).collect::<Vec<_>>()).map(Some),
        None => Ok(None),
    };
    Ok(SetEval {
        sgbm_mean: sgbm_mean_of(|s| s.0)?,
        sgbm_large_mean: sgbm_mean_of(|s| s.1)?,
        pairs,
        mean,
    })
}

/// Scores `readout` of `maps` against `gt`: the metrics of its pixel disparity, and the
/// method's left-right keep rate and the error on the pixels it keeps.
fn score_readout(maps: &MethodMaps, readout: Readout, gt: &GroundTruthMap) -> Result<ReadoutScore> {
    let (tokens, mask) = maps.method(readout.method)?;
    let pixels = maps.pixels(readout)?;
    let metrics = score(&pixels, gt)?;
    let large = score(&pixels, &gt.large_disparity_subset())?;
    let (lr_keep, gt_lr_epe) = match mask {
        Some(mask) => {
            let keep = upsample_mask(mask, tokens.width, pixels.width, pixels.height);
            let restricted = GroundTruthMap {
                valid: gt.valid.iter().zip(&keep).map(|(&g, &k)| g && k).collect(),
                ..gt.clone()
            };
            let gt_lr = score(&pixels, &restricted).map(|m| m.epe).unwrap_or(f64::NAN);
            (Some(density(&keep, gt)?), Some(gt_lr))
        }
        None => (None, None),
    };
    Ok(ReadoutScore {
        metrics,
        lr_keep,
        gt_lr_epe,
        large,
    })
}

fn int8_maps(opts: &EvalOptions, model: &Int8Model, item: &EvalItem) -> Result<MethodMaps> {
    let head = opts.readouts.iter().any(|r| r.uses_head());
    let pipeline = PipelineOptions {
        pathway: opts.pathway.core(),
        max_cols: opts.max_cols,
        penalties: opts.penalties,
        lr_max_diff_q8: lr_tolerance_q8(opts.lr_max_diff),
        head,
        // The head's own check: for head+lr, and for head's LRkeep column.
        head_lr: head,
        head_candidates: head_candidates(item.left.width),
    };
    Ok(run_pipeline(model, &item.left, &item.right, &pipeline, &mut |_, _| {})?.methods)
}

/// A left-right tolerance in patch columns as the core's Q8.
pub fn lr_tolerance_q8(columns: f32) -> u16 {
    (columns.max(0.0) * 256.0).round().min(u16::MAX as f32) as u16
}

/// Disparity candidates of the heads for views `width` px wide, in patch columns: the
/// StereoSGBM reference's search range at that width (EVAL.md: `numDisparities` 32 px per
/// 160 px of width, 64 px = 16 columns at w320), never fewer than the
/// [`HEAD_MAX_DISP`] = 12 they were trained with (44 px: a w160 view's disparities stay below
/// 28 px on the eval split, while 8 % of the w320 ground truth lies above 40 px). Every command
/// and precision uses it, so a readout has one definition per width.
pub fn head_candidates(width: usize) -> usize {
    let sgbm_px = 16 * (2 * width).div_ceil(160);
    (sgbm_px / CELL_W).clamp(HEAD_MAX_DISP, HEAD_CANDIDATES_LIMIT)
}

fn float_maps(
    opts: &EvalOptions,
    encoder: &mut ReferenceEncoder,
    head: Option<&mut FloatHead>,
    item: &EvalItem,
) -> Result<MethodMaps> {
    if opts.pathway == Pathway::Native {
        return float_native_maps(opts, encoder, head.context("the native pathway needs its head")?, item);
    }
    let left = encoder.descriptors(&item.left).context("left view")?;
    let right = encoder.descriptors(&item.right).context("right view")?;
    let volume = similarity_volume(&left, &right, opts.max_cols)?;
    let volume_right = right_view(&volume);
    let wta = wta_subtoken(&volume);
    // The guides only where the SGM uses them ([`Penalties::edge`]).
    let guides = if opts.penalties.guided() {
        Some((guide_map(&item.left)?, guide_map(&item.right)?))
    } else {
        None
    };
    let guide_left = guides.as_ref().map(|(l, _)| l.as_slice());
    let guide_right = guides.as_ref().map(|(_, r)| r.as_slice());
    let sgm_left = sgm(&volume, opts.penalties, guide_left);
    let wta_consistent = consistent(&wta, &wta_subtoken(&volume_right), opts.lr_max_diff);
    let sgm_consistent = consistent(
        &sgm_left,
        &sgm(&volume_right, opts.penalties, guide_right),
        opts.lr_max_diff,
    );
    let (head, head_consistent) = match head {
        Some(h) => {
            let map = |values: Vec<f32>| DisparityMap {
                width: left.cols,
                height: left.rows,
                values,
            };
            let nd = head_candidates(item.left.width);
            let head_left = map(h.forward(&left, &right, nd)?.disparity);
            // The right view: the head on the mirrored pair, mirrored back.
            let head_right = mirror(&map(h.forward(&right.mirrored(), &left.mirrored(), nd)?.disparity));
            let mask = consistent(&head_left, &head_right, opts.lr_max_diff);
            (Some(head_left), Some(mask))
        }
        None => (None, None),
    };
    Ok(MethodMaps {
        nolink: Some(wta),
        sgm: Some(sgm_left),
        head,
        nolink_consistent: wta_consistent,
        sgm_consistent,
        head_consistent,
        // The refinement reads the pipeline's 8-bit views in both precisions.
        views: GrayViews::from_views(&item.left, &item.right)?,
    })
}

/// The native pathway in float: the native head on the phase maps of one pass on (L, R); for
/// its check, on those of the pass on the mirrored pair, mirrored back.
fn float_native_maps(
    opts: &EvalOptions,
    encoder: &mut ReferenceEncoder,
    head: &mut FloatHead,
    item: &EvalItem,
) -> Result<MethodMaps> {
    let mut run = |left: &View, right: &View| -> Result<DisparityMap> {
        let (even, odd) = encoder.tokens(left, right)?.phase_maps();
        Ok(DisparityMap {
            width: even.cols,
            height: even.rows,
            values: head.forward(&even, &odd, head_candidates(left.width))?.disparity,
        })
    };
    let head_left = run(&item.left, &item.right).context("native pass on (L, R)")?;
    let head_right = mirror(&run(&item.right.mirrored(), &item.left.mirrored()).context("mirrored pass")?);
    let mask = consistent(&head_left, &head_right, opts.lr_max_diff);
    Ok(MethodMaps {
        nolink: None,
        sgm: None,
        head: Some(head_left),
        nolink_consistent: Vec::new(),
        sgm_consistent: Vec::new(),
        head_consistent: Some(mask),
        views: GrayViews::from_views(&item.left, &item.right)?,
    })
}

/// A token map with each row's columns reversed.
fn mirror(map: &DisparityMap) -> DisparityMap {
    let mut values = map.values.clone();
    for row in values.chunks_exact_mut(map.width.max(1)) {
        row.reverse();
    }
    DisparityMap { values, ..*map }
}

/// SGBM's metrics per pair: on all ground-truth pixels, and on the large-disparity subset.
fn sgbm_metrics(runner: &SgbmRunner, items: &[EvalItem]) -> Result<Vec<(Metrics, Metrics)>> {
    let views: Vec<(Vec<u8>, Vec<u8>)> = items
        .iter()
        .map(|i| (to_u8(&i.left.pixels), to_u8(&i.right.pixels)))
        .collect();
    let pairs: Vec<GrayPair<'_>> = items
        .iter()
        .zip(&views)
        .map(|(item, (l, r))| GrayPair {
            left: l,
            right: r,
            width: item.left.width,
            height: item.left.height,
        })
        .collect();
    runner
        .run(&pairs)?
        .iter()
        .zip(items)
        .map(|((disparity, valid), item)| {
            let all = score_sparse(disparity, valid, &item.gt);
            all.and_then(|all| Ok((all, score_sparse(disparity, valid, &item.gt.large_disparity_subset())?)))
                .with_context(|| format!("pair {}: SGBM", item.pair_id))
        })
        .collect()
}

fn mean_score(scores: &[ReadoutScore]) -> Result<ReadoutScore> {
    let metrics = mean_metrics(&scores.iter().map(|s| s.metrics).collect::<Vec<_>>())?;
    let large = mean_metrics(&scores.iter().map(|s| s.large).collect::<Vec<_>>())?;
    let mean_of = |f: fn(&ReadoutScore) -> Option<f64>| -> Option<f64> {
        let values: Option<Vec<f64>> = scores.iter().map(f).collect();
        values.map(|v| v.iter().sum::<f64>() / v.len().max(1) as f64)
    };
    Ok(ReadoutScore {
        metrics,
        lr_keep: mean_of(|s| s.lr_keep),
        gt_lr_epe: mean_of(|s| s.gt_lr_epe),
        large,
    })
}

impl EvalReport {
    /// The human-readable table: one row per precision and readout (mean), SGBM, then per
    /// pair epe.
    pub fn table(&self) -> String {
        use std::fmt::Write;
        let o = &self.options;
        let mut t = String::new();
        let _ = writeln!(
            t,
            "bino {} eval: {} {} pairs of {} at {}, {} pathway, {} candidates (head {}), SGM p1 {} p2 {}{}, LR tolerance {} col",
            env!("CARGO_PKG_VERSION"),
            self.pairs.len(),
            o.split,
            o.data.display(),
            o.profile,
            o.pathway,
            o.max_cols,
            o.profile
                .width()
                .map_or("by width".to_string(), |w| head_candidates(w).to_string()),
            o.penalties.p1,
            o.penalties.p2,
            match o.penalties.edge {
                0 => String::new(),
                e => format!(" edge {e}"),
            },
            o.lr_max_diff
        );
        let _ = writeln!(
            t,
            "\n{:<18} {:>8} {:>10} {:>8} {:>8} {:>8} {:>10} {:>10} {:>11}",
            "readout", "epe px", "bad1tok %", "bad2 %", "density", "LRkeep", "GT+LR epe", "large epe", "large b1t %"
        );
        let opt = |v: Option<f64>, prec: usize| v.map_or("-".to_string(), |v| format!("{v:.prec$}"));
        for ((p, r), s) in o.rows().iter().zip(&self.mean) {
            let m = s.metrics;
            let _ = writeln!(
                t,
                "{:<18} {:>8.3} {:>10.2} {:>8.2} {:>8.1} {:>8} {:>10} {:>10.3} {:>11.2}",
                format!("{} {}", p.name(), r.name()),
                m.epe,
                m.bad1tok,
                m.bad2,
                m.density,
                opt(s.lr_keep, 1),
                opt(s.gt_lr_epe, 3),
                s.large.epe,
                s.large.bad1tok
            );
        }
        if let (Some(m), Some(l)) = (self.sgbm_mean, self.sgbm_large_mean) {
            let _ = writeln!(
                t,
                "{:<18} {:>8.3} {:>10.2} {:>8.2} {:>8.1} {:>8} {:>10} {:>10.3} {:>11.2}",
                "StereoSGBM", m.epe, m.bad1tok, m.bad2, m.density, "-", "-", l.epe, l.bad1tok
            );
        }
        if !self.nuisances.is_empty() {
            let _ = writeln!(
                t,
                "\nrobust accuracy: right view degraded (seed {}), epe px / bad1tok %, epe rise over clean; \
                 * = rise below StereoSGBM's",
                o.seed
            );
            let _ = write!(t, "{:<18} {:>14}", "readout", "clean");
            for n in &self.nuisances {
                let _ = write!(t, " {:>22}", n.nuisance.name());
            }
            let cell = |m: &Metrics| format!("{:.3}/{:.2}", m.epe, m.bad1tok);
            for (r, ((p, readout), clean)) in o.rows().iter().zip(&self.mean).enumerate() {
                let _ = write!(
                    t,
                    "\n{:<18} {:>14}",
                    format!("{} {}", p.name(), readout.name()),
                    cell(&clean.metrics)
                );
                for n in &self.nuisances {
                    let m = n.set.mean[r].metrics;
                    let rise = m.epe - clean.metrics.epe;
                    let below = match self.sgbm_rise(n) {
                        Some(sgbm) if rise < sgbm => "*",
                        Some(_) => " ",
                        None => "",
                    };
                    let _ = write!(t, " {:>22}", format!("{} {rise:+.3}{below}", cell(&m)));
                }
            }
            if let Some(clean) = self.sgbm_mean {
                let _ = write!(t, "\n{:<18} {:>14}", "StereoSGBM", cell(&clean));
                for n in &self.nuisances {
                    if let Some(m) = n.set.sgbm_mean {
                        let _ = write!(t, " {:>22}", format!("{} {:+.3} ", cell(&m), m.epe - clean.epe));
                    }
                }
            }
            t.push('\n');
        }
        self.occlusion_table(&mut t);
        let _ = write!(t, "\n{:<24}", "pair (epe px)");
        for (p, r) in o.rows() {
            let _ = write!(t, " {:>18}", format!("{} {}", p.name(), r.name()));
        }
        if self.sgbm_mean.is_some() {
            let _ = write!(t, " {:>18}", "SGBM");
        }
        for pair in &self.pairs {
            let _ = write!(t, "\n{:<24}", pair.pair_id);
            for s in &pair.scores {
                let _ = write!(t, " {:>18.3}", s.metrics.epe);
            }
            if let Some(m) = pair.sgbm {
                let _ = write!(t, " {:>18.3}", m.epe);
            }
        }
        t
    }

    /// The one-view occlusion section of [`EvalReport::table`] (nothing without `--occlude`):
    /// epe / bad1tok clean and at each severity, then OccAUC and Δ at the largest.
    fn occlusion_table(&self, t: &mut String) {
        use std::fmt::Write;
        let Some(summary) = self.occlusion_summary() else {
            return;
        };
        let top = self.occlusions.last().map_or(0, |o| o.percent);
        let _ = writeln!(
            t,
            "\none-view occlusion: right view, token-aligned mid-grey blocks (seed {}), epe px / bad1tok %",
            self.options.seed
        );
        let _ = write!(t, "{:<18} {:>14}", "readout", "clean");
        for o in &self.occlusions {
            let _ = write!(t, " {:>14}", format!("occ{}", o.percent));
        }
        let _ = write!(t, " {:>14} {:>16}", "OccAUC", format!("delta{top}"));
        let cell = |epe: f64, bad: f64| format!("{epe:.3}/{bad:.2}");
        for row in &summary {
            let _ = write!(t, "\n{:<18} {:>14}", row.name, cell(row.clean.epe, row.clean.bad1tok));
            for m in &row.severities {
                let _ = write!(t, " {:>14}", cell(m.epe, m.bad1tok));
            }
            let _ = write!(
                t,
                " {:>14} {:>16}",
                cell(row.auc_epe, row.auc_bad1tok),
                format!("{:+.3}/{:+.2}", row.delta_epe, row.delta_bad1tok)
            );
        }
        t.push('\n');
    }

    /// Per row (and SGBM last, when it ran) the occlusion curve and its summary; `None`
    /// without `--occlude`.
    pub fn occlusion_summary(&self) -> Option<Vec<OcclusionSummary>> {
        if self.occlusions.is_empty() {
            return None;
        }
        let rows = self.options.rows();
        let mut summary: Vec<OcclusionSummary> = (rows.iter().enumerate())
            .map(|(r, (p, readout))| {
                OcclusionSummary::new(
                    format!("{} {}", p.name(), readout.name()),
                    self.mean[r].metrics,
                    self.occlusions.iter().map(|o| o.set.mean[r].metrics).collect(),
                )
            })
            .collect();
        let sgbm: Option<Vec<Metrics>> = self.occlusions.iter().map(|o| o.set.sgbm_mean).collect();
        if let (Some(clean), Some(curve)) = (self.sgbm_mean, sgbm) {
            summary.push(OcclusionSummary::new("StereoSGBM".to_string(), clean, curve));
        }
        Some(summary)
    }

    /// StereoSGBM's mean epe rise under `n` over its clean epe, when SGBM ran.
    pub fn sgbm_rise(&self, n: &NuisanceEval) -> Option<f64> {
        Some(n.set.sgbm_mean?.epe - self.sgbm_mean?.epe)
    }

    /// Every number as JSON.
    pub fn to_json<'a>(&'a self) -> String {
        let o = &self.options;
        let rows = o.rows();
        let readouts = |scores: &[ReadoutScore], sgbm: Option<Metrics>, sgbm_large: Option<Metrics>| ReadoutsJson {
            rows: Keyed(
                (rows.iter().zip(scores))
                    .map(|((p, r), s)| (format!("{}_{}", p.name(), r.name()), *s))
                    .collect(),
            ),
            sgbm,
            sgbm_large,
        };
        let per_pair = |pairs: &'a [PairEval]| -> Vec<PairJson<'a>> {
            (pairs.iter())
                .map(|p| PairJson {
                    pair_id: &p.pair_id,
                    readouts: readouts(&p.scores, p.sgbm, p.sgbm_large),
                    seconds: p.elapsed.as_secs_f64(),
                })
                .collect()
        };
        let json = EvalJson {
            tool: "bino eval",
            version: env!("CARGO_PKG_VERSION"),
            blob: o.blob.display().to_string(),
            onnx: o.onnx.display().to_string(),
            head_onnx: o.head_onnx.display().to_string(),
            pathway: o.pathway.name(),
            native_head_onnx: o.native_head_onnx.display().to_string(),
            data: o.data.display().to_string(),
            split: &o.split,
            profile: o.profile.to_string(),
            max_cols: o.max_cols,
            head_candidates: o.profile.width().map(head_candidates),
            sgm_p1: o.penalties.p1,
            sgm_p2: o.penalties.p2,
            sgm_edge: o.penalties.edge,
            lr_max_diff: o.lr_max_diff as f64,
            pairs: self.pairs.len(),
            seed: o.seed,
            nuisance_params: NuisanceParams {
                gain: crate::nuisance::GAIN,
                offset: crate::nuisance::OFFSET,
                gamma: crate::nuisance::GAMMA,
                noise_sigma: crate::nuisance::NOISE_SIGMA,
                blur_radius: crate::nuisance::BLUR_RADIUS,
                occlude_share: crate::nuisance::OCCLUDE_SHARE,
                occlude_fill: crate::nuisance::OCCLUDE_FILL,
            },
            mean: readouts(&self.mean, self.sgbm_mean, self.sgbm_large_mean),
            per_pair: per_pair(&self.pairs),
            nuisances: Keyed(
                (self.nuisances.iter())
                    .map(|n| {
                        let sgbm_rise = self.sgbm_rise(n);
                        let rise: Vec<(String, f64)> = (rows.iter().zip(&n.set.mean).zip(&self.mean))
                            .map(|(((p, r), s), clean)| {
                                (format!("{}_{}", p.name(), r.name()), s.metrics.epe - clean.metrics.epe)
                            })
                            .collect();
                        let below =
                            sgbm_rise.map(|sgbm| Keyed(rise.iter().map(|(k, v)| (k.clone(), *v < sgbm)).collect()));
                        let json = NuisanceJson {
                            mean: readouts(&n.set.mean, n.set.sgbm_mean, n.set.sgbm_large_mean),
                            epe_rise: RiseJson {
                                rows: Keyed(rise),
                                sgbm: sgbm_rise,
                            },
                            rise_below_sgbm: below,
                            per_pair: per_pair(&n.set.pairs),
                        };
                        (n.nuisance.name().to_string(), json)
                    })
                    .collect(),
            ),
            occlusion: self.occlusion_summary().map(|summary| OcclusionJson {
                fill: crate::nuisance::OCCLUDE_FILL,
                severities: self.occlusions.iter().map(|o| o.percent).collect(),
                summary: Keyed(summary.into_iter().map(|s| (s.name.replace(' ', "_"), s)).collect()),
                per_severity: Keyed(
                    (self.occlusions.iter())
                        .map(|o| {
                            let json = SeverityJson {
                                mean: readouts(&o.set.mean, o.set.sgbm_mean, o.set.sgbm_large_mean),
                                per_pair: per_pair(&o.set.pairs),
                            };
                            (o.percent.to_string(), json)
                        })
                        .collect(),
                ),
            }),
        };
        serde_json::to_string_pretty(&json).expect("plain structs serialise")
    }
}

// The report's JSON, in the file's field order.
#[derive(Serialize)]
struct EvalJson<'a> {
    tool: &'static str,
    version: &'static str,
    blob: String,
    onnx: String,
    head_onnx: String,
    pathway: &'static str,
    native_head_onnx: String,
    data: String,
    split: &'a str,
    profile: String,
    max_cols: usize,
    // The heads' candidates at the profile's width (head_candidates); absent for the native
    // profile, whose width varies by pair.
    #[serde(skip_serializing_if = "Option::is_none")]
    head_candidates: Option<usize>,
    sgm_p1: u16,
    sgm_p2: u16,
    sgm_edge: u8,
    lr_max_diff: f64,
    pairs: usize,
    seed: u64,
    nuisance_params: NuisanceParams,
    // Clean: the right view as loaded.
    mean: ReadoutsJson,
    per_pair: Vec<PairJson<'a>>,
    // Keyed by nuisance name, in --nuisance order; empty without --nuisance.
    nuisances: Keyed<NuisanceJson<'a>>,
    // The one-view occlusion benchmark; absent without --occlude.
    #[serde(skip_serializing_if = "Option::is_none")]
    occlusion: Option<OcclusionJson<'a>>,
}

#[derive(Serialize)]
struct OcclusionJson<'a> {
    fill: u8,
    severities: Vec<u32>,
    // Keyed `<precision>_<readout>` and `StereoSGBM`.
    summary: Keyed<OcclusionSummary>,
    // Keyed by severity in %.
    per_severity: Keyed<SeverityJson<'a>>,
}

#[derive(Serialize)]
struct SeverityJson<'a> {
    mean: ReadoutsJson,
    per_pair: Vec<PairJson<'a>>,
}

// The constants of crate::nuisance.
#[derive(Serialize)]
struct NuisanceParams {
    gain: f32,
    offset: f32,
    gamma: f32,
    noise_sigma: f32,
    blur_radius: usize,
    occlude_share: f64,
    occlude_fill: u8,
}

#[derive(Serialize)]
struct NuisanceJson<'a> {
    mean: ReadoutsJson,
    // Mean epe under the nuisance minus the clean mean epe, per row and SGBM.
    epe_rise: RiseJson,
    // Per row: its epe rise is below SGBM's (absent when SGBM did not run).
    #[serde(skip_serializing_if = "Option::is_none")]
    rise_below_sgbm: Option<Keyed<bool>>,
    per_pair: Vec<PairJson<'a>>,
}

#[derive(Serialize)]
struct RiseJson {
    #[serde(flatten)]
    rows: Keyed<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    sgbm: Option<f64>,
}

#[derive(Serialize)]
struct PairJson<'a> {
    pair_id: &'a str,
    readouts: ReadoutsJson,
    seconds: f64,
}

// Scores keyed `<precision>_<readout>` in row order, then SGBM's when it ran.
#[derive(Serialize)]
struct ReadoutsJson {
    #[serde(flatten)]
    rows: Keyed<ReadoutScore>,
    #[serde(skip_serializing_if = "Option::is_none")]
    sgbm: Option<Metrics>,
    #[serde(skip_serializing_if = "Option::is_none")]
    sgbm_large: Option<Metrics>,
}

/// One row's one-view occlusion curve (means over the set) and its summary, the paper's
/// columns: `Occ` at the largest severity, `OccAUC` the mean over the non-zero severities,
/// `Δ` the largest severity minus clean.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct OcclusionSummary {
    /// `<precision> <readout>` or `StereoSGBM`.
    #[serde(skip)]
    pub name: String,
    /// Clean.
    pub clean: Metrics,
    /// At each severity, in order.
    pub severities: Vec<Metrics>,
    /// Mean epe over the severities.
    pub auc_epe: f64,
    /// Mean bad1tok over the severities.
    pub auc_bad1tok: f64,
    /// epe at the largest severity minus clean.
    pub delta_epe: f64,
    /// bad1tok at the largest severity minus clean.
    pub delta_bad1tok: f64,
}

impl OcclusionSummary {
    fn new(name: String, clean: Metrics, severities: Vec<Metrics>) -> Self {
        let n = severities.len().max(1) as f64;
        let last = severities.last().copied().unwrap_or(clean);
        Self {
            name,
            auc_epe: severities.iter().map(|m| m.epe).sum::<f64>() / n,
            auc_bad1tok: severities.iter().map(|m| m.bad1tok).sum::<f64>() / n,
            delta_epe: last.epe - clean.epe,
            delta_bad1tok: last.bad1tok - clean.bad1tok,
            clean,
            severities,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The rule `train/bino_train/head.py::head_candidates` repeats (its test pins the same
    /// values): SGBM's range at the width, never below the trained 12, at most the limit.
    #[test]
    fn head_candidates_follow_the_sgbm_range_of_the_width() {
        let counts: Vec<usize> = [32, 160, 320, 400, 4000].into_iter().map(head_candidates).collect();
        assert_eq!(counts, [12, 12, 16, 20, 64]);
    }

    #[test]
    fn bad_options_are_errors() {
        let opts = EvalOptions {
            data: PathBuf::from("/nonexistent"),
            split: "train".into(),
            profile: Profile::W160,
            blob: PathBuf::from("/nonexistent/blob.bin"),
            onnx: PathBuf::from("/nonexistent/encoder.onnx"),
            head_onnx: PathBuf::from("/nonexistent/head.onnx"),
            pathway: Pathway::Export,
            native_head_onnx: PathBuf::from("/nonexistent/native_head.onnx"),
            precisions: vec![Precision::Int8],
            readouts: vec![Readout::NOLINK],
            max_cols: 10,
            penalties: Penalties { p1: 8, p2: 32, edge: 0 },
            lr_max_diff: 1.0,
            sgbm: false,
            limit: None,
            nuisances: vec![],
            seed: 0,
            occlusions: vec![],
        };
        let err = evaluate(&opts, |_, _, _| {}).unwrap_err().to_string();
        assert!(err.contains("only eval and val pairs"), "{err}");
        let none = EvalOptions {
            readouts: vec![],
            ..opts.clone()
        };
        assert!(evaluate(&none, |_, _, _| {}).is_err());
        let missing = EvalOptions {
            split: "eval".into(),
            ..opts
        };
        let err = format!("{:#}", evaluate(&missing, |_, _, _| {}).unwrap_err());
        assert!(err.contains("/nonexistent/blob.bin"), "{err}");
        let native_sgm = EvalOptions {
            pathway: Pathway::Native,
            ..missing
        };
        let err = format!("{:#}", evaluate(&native_sgm, |_, _, _| {}).unwrap_err());
        assert!(err.contains("--readout nolink needs the export pathway"), "{err}");
    }
}
