//! `bino eval`: BINO's readouts on every pair of a split that has ground truth, in int8 (the
//! core pipeline) and in float (tract descriptors through the float twins of the same
//! readouts), next to OpenCV StereoSGBM on the same profile images, scored with EVAL.md's
//! metrics per pair and on average.
//!
//! Readouts: `nolink` (cosine WTA + parabola), `sgm` (4 streaming paths + parabola) and `head`
//! (the shared head), each also `+lr` and each of those also `+ref` (the integer pixel
//! refinement, the same for both precisions: [`crate::readout::refine`]). Each method's left-right check
//! also gives `LRkeep` (% of ground-truth pixels whose cell passes it) and the error on those
//! pixels only (`GT+LR`). Every score also exists on the large-disparity subset (`large`: the
//! top quartile of each pair's ground-truth disparities, the paper's stress test), and
//! `--occlude` adds the paper's one-view occlusion benchmark ([`crate::data::occlusion`]).

use std::time::Instant;

use anyhow::{bail, ensure, Context, Result};

use super::float_twins::{consistent, right_view, sgm};
use super::int8_pair::{host_only, int8_pair};
use super::sgbm::{GrayPair, SgbmRunner};
use super::{
    density, load_eval_item, mean_metrics, score, score_sparse, similarity_volume, upsample_mask, wta_subtoken,
    Degradation, DisparityMap, EvalItem, EvalOptions, EvalReport, GroundTruthMap, Metrics, NuisanceEval, OcclusionEval,
    PairEval, Precision, ReadoutScore, SetEval,
};
use crate::data::nuisance::degrade_item;
use crate::data::occlusion::{check_severities, occlude_item};
use crate::data::pairs::{read_index, Split};
use crate::float::head::FloatHead;
use crate::float::reference::ReferenceEncoder;
use crate::int8::{guide_map, to_u8, Int8Model};
use crate::readout::pathway::Pathway;
use crate::readout::refine::GrayViews;
use crate::readout::{head_candidates, MethodMaps, Readout};

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
            let (maps, refined) = match precision {
                Precision::Int8 => {
                    let pair = int8_pair(opts, model.context("int8 model")?, item)?;
                    (pair.maps, pair.refined)
                }
                Precision::F32 => {
                    let (encoder, head) = float.as_mut().context("float model")?;
                    (
                        float_maps(opts, encoder, head.as_mut(), item)?,
                        vec![None; opts.readouts.len()],
                    )
                }
            };
            for (&readout, core_pixels) in opts.readouts.iter().zip(&refined) {
                let host_only = precision == Precision::Int8 && host_only(opts, readout);
                let score = score_readout(&maps, readout, core_pixels.as_ref(), &item.gt)
                    .with_context(|| format!("pair {}: {} {}", item.pair_id, precision.name(), readout.name()))?;
                scores.push(ReadoutScore { host_only, ..score });
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

/// Scores `readout` against `gt`: the metrics of its pixel disparity (`core_pixels`, the core's
/// refined rows, when given, else from `maps`), and the method's left-right keep rate and the
/// error on the pixels it keeps.
fn score_readout(
    maps: &MethodMaps,
    readout: Readout,
    core_pixels: Option<&DisparityMap>,
    gt: &GroundTruthMap,
) -> Result<ReadoutScore> {
    let grid = maps.grid(readout)?;
    let pixels = match core_pixels {
        Some(pixels) => std::borrow::Cow::Borrowed(pixels),
        None => std::borrow::Cow::Owned(maps.grid_pixels(&grid, readout)?),
    };
    let metrics = score(&pixels, gt)?;
    let large = score(&pixels, &gt.large_disparity_subset())?;
    let (lr_keep, gt_lr_epe) = match grid.mask {
        Some(mask) => {
            let keep = upsample_mask(&mask, grid.tokens.width, pixels.width, pixels.height);
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
        host_only: false,
    })
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
    let left_bands = encoder.descriptor_bands(&item.left).context("left view")?;
    let right_bands = encoder.descriptor_bands(&item.right).context("right view")?;
    let (left, right) = (left_bands.assemble(), right_bands.assemble());
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
    let (head, head_consistent, head_confidence) = match head {
        Some(h) => {
            let map = |values: Vec<f32>| DisparityMap {
                width: left.cols,
                height: left.rows,
                values,
            };
            let nd = head_candidates(item.left.width);
            // Each band's head on its own rows, as the core's export pathway runs it.
            let out = h.forward_pair_banded(&left_bands, &right_bands, nd)?;
            let confidence = out.confidence_q8();
            let head_left = map(out.disparity);
            // The right view: the head on the mirrored pair, mirrored back.
            let mirrored = h.forward_pair_banded(&right_bands.mirrored(), &left_bands.mirrored(), nd)?;
            let head_right = mirror(&map(mirrored.disparity));
            let mask = consistent(&head_left, &head_right, opts.lr_max_diff);
            (Some(head_left), Some(mask), Some(confidence))
        }
        None => (None, None, None),
    };
    Ok(MethodMaps {
        nolink: Some(wta),
        sgm: Some(sgm_left),
        head,
        nolink_consistent: wta_consistent,
        sgm_consistent,
        head_consistent,
        head_confidence,
        // The refinement reads the pipeline's 8-bit views in both precisions.
        views: GrayViews::from_views(&item.left, &item.right)?,
        census: Default::default(),
    })
}

/// The native pathway in float: the native head on the phase maps of one pass on (L, R), each
/// band's on its own ([`FloatHead::forward_banded`]); its
/// check reads the right view from the same logits' diagonal
/// ([`crate::compare::head::FloatHeadOutput::right_view`]).
fn float_native_maps(
    opts: &EvalOptions,
    encoder: &mut ReferenceEncoder,
    head: &mut FloatHead,
    item: &EvalItem,
) -> Result<MethodMaps> {
    let tokens = encoder
        .token_bands(&item.left, &item.right)
        .context("native pass on (L, R)")?;
    // Each band's head on its own rows, as the core's native pathway runs it.
    let out = head.forward_banded(&tokens, head_candidates(item.left.width))?;
    let (rows, cols) = (tokens.rows.rows, tokens.cols / 2);
    let map = |values: Vec<f32>| DisparityMap {
        width: cols,
        height: rows,
        values,
    };
    let head_right = map(out.right_view(rows, cols));
    let head_confidence = Some(out.confidence_q8());
    let head_left = map(out.disparity);
    let mask = consistent(&head_left, &head_right, opts.lr_max_diff);
    Ok(MethodMaps {
        nolink: None,
        sgm: None,
        head: Some(head_left),
        nolink_consistent: Vec::new(),
        sgm_consistent: Vec::new(),
        head_consistent: Some(mask),
        head_confidence,
        views: GrayViews::from_views(&item.left, &item.right)?,
        census: Default::default(),
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
        host_only: scores.iter().any(|s| s.host_only),
    })
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use bino_core::sgm::Penalties;

    use super::*;
    use crate::data::profile::Profile;

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
