//! `bino compare`: the float encoder (tract-onnx) against the int8 engine on the eval pairs.
//!
//! For every view of every pair:
//! - **stages**: the residual stream after the embedding and after each block's attention and
//!   MLP halves, band by band (the int8 engine's [`BandPlan`]), as the mean per-token cosine.
//!   The float model gets the same 8-bit pixels the engine sees ([`to_u8`], divided by 255),
//!   so that only the engines differ;
//! - **descriptors**: the float reference on the exact view against the int8 engine, as the
//!   mean per-cell cosine.
//!
//! Per pair, from those descriptor maps: how often the integer winner-take-all disparity
//! (argmax of the cosine similarity volume) agrees, and the `EVAL.md` metrics of the
//! no-linkage readout for each model, upsampled (`nolink`) and refined (`nolink+ref`, the
//! readouts' one refinement, [`crate::readout::refine`]); the same for the head when it runs. Pairs are
//! averaged without weights, like the metrics.

pub mod head;
pub mod report;
pub mod stages;
mod wta;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context, Result};
use bino_core::band::BandPlan;
use bino_core::config::{DIM, PATCH_H};
use bino_core::model::ids::HeadKind;
use bino_core::model::probe::Stage;

use crate::data::nuisance::{degrade_item, Nuisance};
use crate::data::pairs::{read_index, Split};
use crate::data::profile::{Profile, View};
use crate::eval::{
    load_eval_item, mean_metrics, score, similarity_volume, upsample_disparity, wta_subtoken, DisparityMap, EvalItem,
    Metrics,
};
use crate::float::head::FloatHead;
use crate::float::reference::{FeatureMap, ReferenceEncoder};
use crate::int8::{dequantise_residual, to_u8, HeadMaps, Int8Model, StageRecorder};
use crate::io::files::sha256_hex;
use crate::readout::head_candidates;
use crate::readout::refine::{refine_pixels, GrayViews};
use stages::{mean_token_cosine, EmbedSource, FloatStages, STAGE_COUNT};
pub use wta::{top2_gap_median, wta_agreement, wta_flip_loss, wta_integer};

/// What to compare, and on which pairs.
#[derive(Debug, Clone)]
pub struct CompareOptions {
    /// Float encoder (ONNX).
    pub onnx: PathBuf,
    /// Int8 weight blob made from it by `bino quantize`.
    pub blob: PathBuf,
    /// Float shared head (ONNX); compared with the blob's int8 head when given.
    pub head: Option<PathBuf>,
    /// Float native-pathway head (ONNX); when given, the native pathway is compared too: the
    /// pair tokens of one pass on (L, R) and the blob's int8 native head on them.
    pub native_head: Option<PathBuf>,
    /// Folder holding `PAIRS.tsv`.
    pub data: PathBuf,
    /// Split to read: only `eval` (the metrics need ground truth).
    pub split: String,
    /// Resolution profile of the views.
    pub profile: Profile,
    /// Disparity candidates of the no-linkage readout, in patch columns.
    pub max_cols: usize,
    /// Only the first this many pairs of the split.
    pub limit: Option<usize>,
    /// Degrade each right view first (`bino eval --nuisance`'s images, seed 0): where under
    /// that nuisance the two engines part.
    pub nuisance: Option<Nuisance>,
}

/// The int8 head against the float head on one pair or on average (`bino compare --head`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadComparison {
    /// Cosine of the int8 and float logits over the valid candidates.
    pub logit_cosine: f64,
    /// Mean |int8 - float| soft-argmin disparity, in patch columns.
    pub disparity_mean_abs: f64,
    /// EVAL.md metrics of the float head's disparity.
    pub float: Metrics,
    /// EVAL.md metrics of the int8 head's disparity.
    pub int8: Metrics,
    /// The float head's disparity refined (`head+ref`).
    pub float_ref: Metrics,
    /// The int8 head's disparity refined (`head+ref`).
    pub int8_ref: Metrics,
}

impl HeadComparison {
    /// Relative epe change of the int8 head over the float head, in %.
    pub fn epe_change_pct(&self) -> f64 {
        (self.int8.epe - self.float.epe) / self.float.epe * 100.0
    }

    /// Unweighted mean over pairs.
    fn mean(heads: &[HeadComparison]) -> Result<HeadComparison> {
        let n = heads.len() as f64;
        let of = |get: fn(&HeadComparison) -> Metrics| mean_metrics(&heads.iter().map(get).collect::<Vec<_>>());
        Ok(HeadComparison {
            logit_cosine: heads.iter().map(|x| x.logit_cosine).sum::<f64>() / n,
            disparity_mean_abs: heads.iter().map(|x| x.disparity_mean_abs).sum::<f64>() / n,
            float: of(|x| x.float)?,
            int8: of(|x| x.int8)?,
            float_ref: of(|x| x.float_ref)?,
            int8_ref: of(|x| x.int8_ref)?,
        })
    }
}

/// The native pathway, int8 against float (`bino compare --native-head`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NativeComparison {
    /// Mean per-token cosine of the de-positioned fused token grids of one pass on (L, R)
    /// (the native head's input).
    pub pair_token_cosine: f64,
    /// The int8 native head on the int8 pair tokens against the float one on the float tokens.
    pub head: HeadComparison,
}

/// The numbers of one pair, or their unweighted mean over pairs.
#[derive(Debug, Clone, PartialEq)]
pub struct Comparison {
    /// Mean per-token cosine of each stage, indexed by residual format
    /// ([`stages::stage_label`] names them).
    pub stage_cosine: Vec<f64>,
    /// Mean per-cell cosine of the descriptor maps.
    pub descriptor_cosine: f64,
    /// % of left-view cells whose integer WTA disparity is the same for both models.
    pub wta_agreement: f64,
    /// Where the winners differ: mean float similarity the int8 winner gives up against the
    /// float winner (0 without flips). Small against `wta_top2_gap` means flips are near-ties.
    pub wta_flip_loss: f64,
    /// Median over cells of the float volume's gap between its best and second-best candidate.
    pub wta_top2_gap: f64,
    /// Metrics of the no-linkage readout of the float descriptors.
    pub float: Metrics,
    /// Metrics of the no-linkage readout of the int8 descriptors.
    pub int8: Metrics,
    /// The float no-linkage readout refined (`nolink+ref`).
    pub float_ref: Metrics,
    /// The int8 no-linkage readout refined (`nolink+ref`).
    pub int8_ref: Metrics,
    /// The head comparison, once there is one.
    pub head: Option<HeadComparison>,
    /// The native pathway's comparison, with `--native-head`.
    pub native: Option<NativeComparison>,
}

impl Comparison {
    /// Relative epe change of int8 over float, in %: `(int8 - float) / float * 100`.
    pub fn epe_change_pct(&self) -> f64 {
        (self.int8.epe - self.float.epe) / self.float.epe * 100.0
    }

    /// Unweighted mean over pairs; the head only when every pair has one.
    pub fn mean<'a>(items: impl IntoIterator<Item = &'a Comparison>) -> Result<Comparison> {
        let items: Vec<&Comparison> = items.into_iter().collect();
        ensure!(!items.is_empty(), "no pairs to average");
        let n = items.len() as f64;
        let mean = |get: &dyn Fn(&Comparison) -> f64| items.iter().map(|c| get(c)).sum::<f64>() / n;
        let heads: Option<Vec<HeadComparison>> = items.iter().map(|c| c.head).collect();
        let natives: Option<Vec<NativeComparison>> = items.iter().map(|c| c.native).collect();
        let all = |get: fn(&Comparison) -> Metrics| mean_metrics(&items.iter().map(|c| get(c)).collect::<Vec<_>>());
        Ok(Comparison {
            stage_cosine: (0..STAGE_COUNT).map(|s| mean(&|c| c.stage_cosine[s])).collect(),
            descriptor_cosine: mean(&|c| c.descriptor_cosine),
            wta_agreement: mean(&|c| c.wta_agreement),
            wta_flip_loss: mean(&|c| c.wta_flip_loss),
            wta_top2_gap: mean(&|c| c.wta_top2_gap),
            float: all(|c| c.float)?,
            int8: all(|c| c.int8)?,
            float_ref: all(|c| c.float_ref)?,
            int8_ref: all(|c| c.int8_ref)?,
            head: heads.map(|h| HeadComparison::mean(&h)).transpose()?,
            native: match natives {
                Some(v) => Some(NativeComparison {
                    pair_token_cosine: v.iter().map(|x| x.pair_token_cosine).sum::<f64>() / n,
                    head: HeadComparison::mean(&v.iter().map(|x| x.head).collect::<Vec<_>>())?,
                }),
                None => None,
            },
        })
    }
}

/// One pair's comparison.
#[derive(Debug, Clone, PartialEq)]
pub struct PairComparison {
    /// The pair's `pair_id`.
    pub pair_id: String,
    /// View width at the profile.
    pub width: usize,
    /// View height at the profile.
    pub height: usize,
    /// Bands per view.
    pub bands: usize,
    /// Its numbers.
    pub values: Comparison,
    /// Wall time spent on the pair.
    pub elapsed: Duration,
}

/// Everything `bino compare` measured, with what it measured it on.
#[derive(Debug, Clone)]
pub struct CompareReport {
    /// `bino` version.
    pub version: String,
    /// Float encoder file.
    pub onnx: PathBuf,
    /// Int8 blob file.
    pub blob: PathBuf,
    /// The float head compared, if any.
    pub head: Option<PathBuf>,
    /// The float native head compared, if any.
    pub native_head: Option<PathBuf>,
    /// SHA-256 of the blob's bytes.
    pub blob_sha256: String,
    /// Data folder.
    pub data: PathBuf,
    /// Split compared.
    pub split: Split,
    /// Resolution profile.
    pub profile: Profile,
    /// Disparity candidates of the readout.
    pub max_cols: usize,
    /// The nuisance on every right view, if any (seed [`NUISANCE_SEED`]).
    pub nuisance: Option<Nuisance>,
    /// Where the float embedding stage came from.
    pub embed_source: EmbedSource,
    /// Per pair, in index order.
    pub pairs: Vec<PairComparison>,
    /// Unweighted mean over the pairs.
    pub mean: Comparison,
}

/// The two models, ready to compare views of any size (tract plans are cached per band shape).
pub struct Comparer {
    int8: Int8Model,
    stages: FloatStages,
    reference: ReferenceEncoder,
    // Per residual format: (scale, zero point), read once from the blob.
    formats: Vec<(Vec<f32>, Vec<i32>)>,
    descriptor_scale: f32,
    max_cols: usize,
    float_head: Option<FloatHead>,
    native_head: Option<FloatHead>,
}

// What one view gave.
struct ViewComparison {
    stage_cosine: Vec<f64>,
    bands: usize,
    descriptor_cosine: f64,
    float: FeatureMap,
    int8: FeatureMap,
    codes: Vec<i8>,
}

impl Comparer {
    /// Loads the float encoder `onnx` and the int8 blob `blob`, and the float heads `heads`
    /// (shared, native) where given (the blob must then hold the int8 head of each);
    /// `max_cols` disparity candidates.
    pub fn load(onnx: &Path, blob: &Path, heads: [Option<&Path>; 2], max_cols: usize) -> Result<Self> {
        ensure!(max_cols > 0, "--max-cols must be at least 1");
        let int8 = Int8Model::load(blob)?;
        let [head, native] = heads;
        let float_head = head.map(FloatHead::from_onnx).transpose()?;
        ensure!(
            float_head.is_none() || int8.has_head(),
            "blob {} has no shared head to compare: quantise with `bino quantize --head`",
            blob.display()
        );
        let native_head = native.map(FloatHead::from_onnx).transpose()?;
        ensure!(
            native_head.is_none() || int8.has_head_of(HeadKind::Native),
            "blob {} has no native head to compare: quantise with `bino quantize --native-head`",
            blob.display()
        );
        let formats = (0..STAGE_COUNT)
            .map(|s| int8.residual_format(s))
            .collect::<Result<Vec<_>>>()
            .with_context(|| format!("blob {} lacks residual format metadata", blob.display()))?;
        let descriptor_scale = int8.descriptor_scale()?;
        let stages = FloatStages::load(onnx)?;
        let reference = ReferenceEncoder::load(onnx)?;
        Ok(Self {
            int8,
            stages,
            reference,
            formats,
            descriptor_scale,
            max_cols,
            float_head,
            native_head,
        })
    }

    /// The int8 model.
    pub fn int8(&self) -> &Int8Model {
        &self.int8
    }

    /// Where the float embedding stage comes from.
    pub fn embed_source(&self) -> EmbedSource {
        self.stages.embed_source()
    }

    /// Compares both models on one eval pair.
    pub fn compare_pair(&mut self, item: &EvalItem) -> Result<PairComparison> {
        let started = Instant::now();
        let left = self.compare_view(&item.left).context("left view")?;
        let right = self.compare_view(&item.right).context("right view")?;
        let float_volume = similarity_volume(&left.float, &right.float, self.max_cols)?;
        let int8_volume = similarity_volume(&left.int8, &right.int8, self.max_cols)?;
        let views = GrayViews::from_views(&item.left, &item.right)?;
        let (float_wta, int8_wta) = (wta_subtoken(&float_volume), wta_subtoken(&int8_volume));
        let values = Comparison {
            stage_cosine: (0..STAGE_COUNT)
                .map(|s| 0.5 * (left.stage_cosine[s] + right.stage_cosine[s]))
                .collect(),
            descriptor_cosine: 0.5 * (left.descriptor_cosine + right.descriptor_cosine),
            wta_agreement: wta_agreement(&float_volume, &int8_volume)?,
            wta_flip_loss: wta_flip_loss(&float_volume, &int8_volume)?,
            wta_top2_gap: top2_gap_median(&float_volume),
            float: score(&upsample_disparity(&float_wta), &item.gt).context("float readout")?,
            int8: score(&upsample_disparity(&int8_wta), &item.gt).context("int8 readout")?,
            float_ref: refined_metrics(&float_wta, &views, item).context("float nolink+ref")?,
            int8_ref: refined_metrics(&int8_wta, &views, item).context("int8 nolink+ref")?,
            head: self.compare_head(&left, &right, &views, item).context("shared head")?,
            native: self.compare_native(&views, item).context("native pathway")?,
        };
        Ok(PairComparison {
            pair_id: item.pair_id.clone(),
            width: item.left.width,
            height: item.left.height,
            bands: left.bands,
            values,
            elapsed: started.elapsed(),
        })
    }

    fn compare_head(
        &mut self,
        left: &ViewComparison,
        right: &ViewComparison,
        views: &GrayViews,
        item: &EvalItem,
    ) -> Result<Option<HeadComparison>> {
        let Some(float_head) = self.float_head.as_mut() else {
            return Ok(None);
        };
        let (rows, cols) = (left.int8.rows, left.int8.cols);
        let nd = head_candidates(item.left.width);
        let int8 = self
            .int8
            .head_with_candidates(&left.codes, &right.codes, (rows, cols), nd)?;
        let float = float_head.forward(&left.float, &right.float, nd)?;
        head_comparison(&int8, &float, views, item).map(Some)
    }

    /// The native pathway on one pair: the fused token grids of one pass on (L, R), int8 (on
    /// the engine's 8-bit pixels) against float (on the exact views), and each precision's
    /// native head on its own tokens.
    fn compare_native(&mut self, views: &GrayViews, item: &EvalItem) -> Result<Option<NativeComparison>> {
        let Some(float_head) = self.native_head.as_mut() else {
            return Ok(None);
        };
        let (rows, cols, codes) = self.int8.pair_token_codes(&item.left, &item.right)?;
        let int8_tokens: Vec<f32> = codes.iter().map(|&c| c as f32 * self.descriptor_scale).collect();
        let float_tokens = self.reference.tokens(&item.left, &item.right)?;
        let pair_token_cosine = mean_token_cosine(&int8_tokens, &float_tokens.data, DIM).context("pair tokens")?;
        let nd = head_candidates(item.left.width);
        let int8 = self.int8.native_head_with_candidates(&codes, (rows, cols), nd)?;
        let (even, odd) = float_tokens.phase_maps();
        let float = float_head.forward(&even, &odd, nd)?;
        Ok(Some(NativeComparison {
            pair_token_cosine,
            head: head_comparison(&int8, &float, views, item)?,
        }))
    }

    fn compare_view(&mut self, view: &View) -> Result<ViewComparison> {
        let mut recorder = StageRecorder::default();
        let (rows, cols, codes) = self.int8.descriptor_codes_probed(view, &mut recorder)?;
        let int8 = FeatureMap {
            rows,
            cols,
            dim: DIM,
            data: codes.iter().map(|&c| c as f32 * self.descriptor_scale).collect(),
        };
        let float = self.reference.descriptors(view)?;
        let descriptor_cosine = mean_token_cosine(&int8.data, &float.data, DIM).context("descriptor maps")?;

        let plan = BandPlan::new(rows).map_err(anyhow::Error::msg)?;
        let bands = split_bands(recorder.stages)?;
        ensure!(
            bands.len() == plan.len(),
            "the int8 engine ran {} bands, the band plan has {}",
            bands.len(),
            plan.len()
        );
        // The engine's own pixels, back in [0, 1]: the float model sees exactly what it sees.
        let pixels: Vec<f32> = to_u8(&view.pixels).iter().map(|&p| p as f32 / 255.0).collect();
        let mut sums = [0.0f64; STAGE_COUNT];
        for (band, int8_stages) in plan.iter().zip(&bands) {
            let (y0, h) = (band.start * PATCH_H, band.rows * PATCH_H);
            let float_stages = self
                .stages
                .run_band(&pixels[y0 * view.width..(y0 + h) * view.width], view.width, h)?;
            for (format, codes) in int8_stages.iter().enumerate() {
                let (scale, zero) = &self.formats[format];
                let got = dequantise_residual(codes, scale, zero);
                sums[format] += mean_token_cosine(&got, &float_stages[format], DIM)
                    .with_context(|| format!("stage {}", stages::stage_label(format)))?;
            }
        }
        Ok(ViewComparison {
            stage_cosine: sums.iter().map(|s| s / bands.len() as f64).collect(),
            bands: bands.len(),
            descriptor_cosine,
            float,
            int8,
            codes,
        })
    }
}

// The recorder's stages grouped by band (each band starts with its embedding), and within a
// band indexed by residual format; fails unless every band shows every stage once.
fn split_bands(recorded: Vec<(Stage, usize, usize, Vec<i8>)>) -> Result<Vec<Vec<Vec<i8>>>> {
    let mut bands: Vec<Vec<Option<Vec<i8>>>> = Vec::new();
    for (stage, _, _, codes) in recorded {
        if stage == Stage::Embed {
            bands.push(vec![None; STAGE_COUNT]);
        }
        let band = bands
            .last_mut()
            .with_context(|| format!("the int8 engine showed {stage:?} before any embedding"))?;
        let slot = band
            .get_mut(stage.residual_format())
            .with_context(|| format!("unexpected stage {stage:?}"))?;
        ensure!(slot.is_none(), "the int8 engine showed {stage:?} twice in one band");
        *slot = Some(codes);
    }
    bands
        .into_iter()
        .map(|band| {
            band.into_iter()
                .enumerate()
                .map(|(format, codes)| {
                    codes.with_context(|| format!("the int8 engine never showed stage {}", stages::stage_label(format)))
                })
                .collect()
        })
        .collect()
}

/// EVAL.md metrics of an int8 and a float head's disparity on one pair, unrefined and refined,
/// with how closely their logits and disparities agree.
fn head_comparison(
    int8: &HeadMaps,
    float: &head::FloatHeadOutput,
    views: &GrayViews,
    item: &EvalItem,
) -> Result<HeadComparison> {
    let (rows, cols) = (int8.rows, int8.cols);
    let tokens = |values: &[f32]| DisparityMap {
        width: cols,
        height: rows,
        values: values.to_vec(),
    };
    let scored = |values: &[f32]| score(&upsample_disparity(&tokens(values)), &item.gt);
    let refined = |values: &[f32]| refined_metrics(&tokens(values), views, item);
    let agreement = head::compare_heads(int8, float)?;
    Ok(HeadComparison {
        logit_cosine: agreement.logit_cosine,
        disparity_mean_abs: agreement.disparity_mean_abs,
        float: scored(&float.disparity)?,
        int8: scored(&int8.disparity)?,
        float_ref: refined(&float.disparity)?,
        int8_ref: refined(&int8.disparity)?,
    })
}

// EVAL.md metrics of a token grid's refined pixels (the `+ref` readouts' rule).
fn refined_metrics(tokens: &DisparityMap, views: &GrayViews, item: &EvalItem) -> Result<Metrics> {
    score(&refine_pixels(tokens, views, None)?, &item.gt)
}

/// Seed of `CompareOptions::nuisance`: `bino eval --nuisance`'s default, so both see the same images.
pub const NUISANCE_SEED: u64 = 0;

/// Runs the comparison over the split's pairs; `progress(done, total, pair)` after each pair.
pub fn compare(
    opts: &CompareOptions,
    mut progress: impl FnMut(usize, usize, &PairComparison),
) -> Result<CompareReport> {
    let split = match opts.split.as_str() {
        "eval" => Split::Eval,
        "train" => {
            bail!("compare scores both models against ground truth, which only eval pairs have: use --split eval")
        }
        other => bail!("unknown split {other:?} (expected eval)"),
    };
    ensure!(opts.limit != Some(0), "--limit must be at least 1");
    let records: Vec<_> = read_index(&opts.data)?
        .into_iter()
        .filter(|r| r.split == split)
        .take(opts.limit.unwrap_or(usize::MAX))
        .collect();
    ensure!(!records.is_empty(), "no {split} pairs in {}", opts.data.display());
    let heads = [opts.head.as_deref(), opts.native_head.as_deref()];
    let mut comparer = Comparer::load(&opts.onnx, &opts.blob, heads, opts.max_cols)?;
    let mut pairs = Vec::with_capacity(records.len());
    for (i, record) in records.iter().enumerate() {
        let mut item = load_eval_item(record, opts.profile)?;
        if let Some(nuisance) = opts.nuisance {
            item = degrade_item(&item, nuisance, NUISANCE_SEED);
        }
        let pair = comparer
            .compare_pair(&item)
            .with_context(|| format!("pair {}", record.pair_id))?;
        progress(i + 1, records.len(), &pair);
        pairs.push(pair);
    }
    let mean = Comparison::mean(pairs.iter().map(|p| &p.values))?;
    Ok(CompareReport {
        version: env!("CARGO_PKG_VERSION").to_string(),
        onnx: opts.onnx.clone(),
        blob: opts.blob.clone(),
        head: opts.head.clone(),
        native_head: opts.native_head.clone(),
        blob_sha256: sha256_hex(comparer.int8().bytes()),
        data: opts.data.clone(),
        split,
        profile: opts.profile,
        max_cols: opts.max_cols,
        nuisance: opts.nuisance,
        embed_source: comparer.embed_source(),
        pairs,
        mean,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn metrics(epe: f64) -> Metrics {
        Metrics {
            epe,
            bad1tok: 10.0,
            bad2: 20.0,
            density: 100.0,
        }
    }

    #[test]
    fn mean_is_unweighted_and_keeps_the_head_only_when_complete() {
        let a = Comparison {
            stage_cosine: vec![1.0; STAGE_COUNT],
            descriptor_cosine: 1.0,
            wta_agreement: 100.0,
            wta_flip_loss: 0.0,
            wta_top2_gap: 0.1,
            float: metrics(2.0),
            int8: metrics(2.0),
            float_ref: metrics(1.0),
            int8_ref: metrics(1.0),
            head: Some(HeadComparison {
                logit_cosine: 1.0,
                disparity_mean_abs: 0.0,
                float: metrics(1.0),
                int8: metrics(1.5),
                float_ref: metrics(0.5),
                int8_ref: metrics(0.75),
            }),
            native: None,
        };
        let a = Comparison {
            native: Some(NativeComparison {
                pair_token_cosine: 0.9,
                head: a.head.unwrap(),
            }),
            ..a
        };
        let b = Comparison {
            stage_cosine: vec![0.5; STAGE_COUNT],
            descriptor_cosine: 0.5,
            wta_agreement: 50.0,
            int8: metrics(3.0),
            int8_ref: metrics(2.0),
            ..a.clone()
        };
        let m = Comparison::mean([&a, &b]).unwrap();
        assert_eq!(m.stage_cosine, vec![0.75; STAGE_COUNT]);
        assert_eq!((m.descriptor_cosine, m.wta_agreement), (0.75, 75.0));
        assert_eq!((m.float.epe, m.int8.epe), (2.0, 2.5));
        assert_eq!(m.epe_change_pct(), 25.0);
        assert_eq!((m.float_ref.epe, m.int8_ref.epe), (1.0, 1.5));
        assert_eq!(m.head.map(|h| h.epe_change_pct()), Some(50.0));
        let native = m.native.expect("both pairs have the native pathway");
        assert_eq!((native.pair_token_cosine, native.head.epe_change_pct()), (0.9, 50.0));
        let c = Comparison {
            head: None,
            native: None,
            ..b
        };
        let partial = Comparison::mean([&a, &c]).unwrap();
        assert!(partial.head.is_none() && partial.native.is_none());
        assert!(Comparison::mean([]).is_err());
    }

    #[test]
    fn split_bands_needs_every_stage_once_per_band() {
        let stage = |s: usize| (stages::stage_of_format(s), 1, 2, vec![s as i8; 2 * DIM]);
        let band: Vec<_> = (0..STAGE_COUNT).map(stage).collect();
        let two = [band.clone(), band.clone()].concat();
        let bands = split_bands(two).unwrap();
        assert_eq!(bands.len(), 2);
        assert_eq!(bands[1][3][0], 3);
        assert!(split_bands(band[..STAGE_COUNT - 1].to_vec()).is_err());
        assert!(split_bands(band[1..].to_vec()).is_err());
    }
}
