//! [`Comparer`]: the float encoder and the int8 engine loaded side by side, and the
//! comparison of one pair's views between them.

use std::path::Path;
use std::time::Instant;

use anyhow::{ensure, Context, Result};
use bino_core::band::BandPlan;
use bino_core::config::{DIM, PATCH_H};
use bino_core::model::ids::HeadKind;
use bino_core::model::probe::Stage;

use super::stages::{self, mean_token_cosine, EmbedSource, FloatStages, STAGE_COUNT};
use super::wta::{top2_gap_median, wta_agreement, wta_flip_loss};
use super::{head, Comparison, HeadComparison, NativeComparison, PairComparison};
use crate::band_maps::BandedRows;
use crate::data::profile::View;
use crate::eval::{score, similarity_volume, upsample_disparity, wta_subtoken, DisparityMap, EvalItem, Metrics};
use crate::float::head::FloatHead;
use crate::float::reference::{FeatureMap, ReferenceEncoder, TokenBands};
use crate::int8::{dequantise_residual, to_u8, HeadMaps, Int8Model, StageRecorder};
use crate::readout::head_candidates;
use crate::readout::refine::{refine_pixels, GrayViews};

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
    /// The maps as the bands computed them, what the export head reads band by band.
    float_bands: TokenBands,
    int8_bands: BandedRows<i8>,
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
        // Each band's head on its own rows, as the core's export pathway runs it.
        let nd = head_candidates(item.left.width);
        let int8 = (self.int8).head_banded(&left.int8_bands, &right.int8_bands, left.int8.cols, nd)?;
        let float = float_head.forward_pair_banded(&left.float_bands, &right.float_bands, nd)?;
        head_comparison(&int8, &float, views, item).map(Some)
    }

    /// The native pathway on one pair: the fused token grids of one pass on (L, R), int8 (on
    /// the engine's 8-bit pixels) against float (on the exact views), and each precision's
    /// native head on its own tokens.
    fn compare_native(&mut self, views: &GrayViews, item: &EvalItem) -> Result<Option<NativeComparison>> {
        let Some(float_head) = self.native_head.as_mut() else {
            return Ok(None);
        };
        let (cols, int8_bands) = self.int8.pair_token_bands(&item.left, &item.right)?;
        let int8_tokens: Vec<f32> = int8_bands
            .assemble()
            .iter()
            .map(|&c| c as f32 * self.descriptor_scale)
            .collect();
        let float_bands = self.reference.token_bands(&item.left, &item.right)?;
        let float_tokens = float_bands.assemble();
        let pair_token_cosine = mean_token_cosine(&int8_tokens, &float_tokens.data, DIM).context("pair tokens")?;
        // Each band's head on its own rows, as the core's native pathway runs it.
        let nd = head_candidates(item.left.width);
        let int8 = self.int8.native_head_banded(&int8_bands, cols, nd)?;
        let float = float_head.forward_banded(&float_bands, nd)?;
        Ok(Some(NativeComparison {
            pair_token_cosine,
            head: head_comparison(&int8, &float, views, item)?,
        }))
    }

    fn compare_view(&mut self, view: &View) -> Result<ViewComparison> {
        let mut recorder = StageRecorder::default();
        let (cols, int8_bands) = self.int8.descriptor_bands_probed(view, &mut recorder)?;
        let (rows, codes) = (int8_bands.rows, int8_bands.assemble());
        let int8 = FeatureMap {
            rows,
            cols,
            dim: DIM,
            data: codes.iter().map(|&c| c as f32 * self.descriptor_scale).collect(),
        };
        let float_bands = self.reference.descriptor_bands(view)?;
        let float = float_bands.assemble();
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
            float_bands,
            int8_bands,
        })
    }
}

// The recorder's stages grouped by band (each band starts with its embedding), and within a
// band indexed by residual format; fails unless every band shows every stage once.
pub(super) fn split_bands(recorded: Vec<(Stage, usize, usize, Vec<i8>)>) -> Result<Vec<Vec<Vec<i8>>>> {
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
