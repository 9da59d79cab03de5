//! Calibration: the float encoder (tract) on train-split bands, with the intermediate
//! tensors ("taps") the int8 formats are chosen from.

use crate::compare::stages::EmbedSource;
use std::path::Path;

use anyhow::{ensure, Context, Result};
use bino_core::band::BandPlan;
use bino_core::config::{BAND_ROWS, DEPTH, DIM, PATCH_H};
use tract_onnx::prelude::*;

use crate::data::pairs::{read_index, Split};
use crate::data::profile::{Profile, View};
use crate::float::taps::TappedModel;
use crate::io::image_io::load_gray;

/// Values kept per tensor per band: enough for percentiles, bounded memory.
const SAMPLES_PER_BAND: usize = 8192;
/// Residual tokens kept per band (every n-th token, all channels).
const RESIDUAL_TOKENS_PER_BAND: usize = 240;
/// LayerNorm epsilon of the float model.
const LN_EPS: f64 = 1e-5;

/// A bounded sample of one tensor's values.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Samples(Vec<f32>);

impl Samples {
    /// Keeps an evenly spaced subset of at most `limit` of `values`.
    pub fn add(&mut self, values: impl ExactSizeIterator<Item = f32>, limit: usize) {
        let step = values.len().div_ceil(limit.max(1)).max(1);
        self.0.extend(values.step_by(step));
    }

    /// The kept values.
    pub fn values(&self) -> &[f32] {
        &self.0
    }

    /// The kept values, sorted.
    pub fn sorted(&self) -> Vec<f32> {
        let mut v = self.0.clone();
        v.sort_by(f32::total_cmp);
        v
    }
}

/// What calibration measured.
#[derive(Debug, Clone, Default)]
pub struct EncoderStats {
    /// Per residual format, per channel.
    pub residual: Vec<Vec<Samples>>,
    /// LayerNorm z-scores (before gamma), per LayerNorm `2b`, `2b + 1`.
    pub layernorm: Vec<Samples>,
    /// Per block: queries after RoPE.
    pub queries: Vec<Samples>,
    /// Per block: keys after RoPE.
    pub keys: Vec<Samples>,
    /// Per block: values.
    pub values: Vec<Samples>,
    /// Per block: attention output.
    pub attended: Vec<Samples>,
    /// Per block: fc1 output.
    pub gelu_input: Vec<Samples>,
    /// Per block: GELU output.
    pub gelu_output: Vec<Samples>,
    /// Descriptors (phase-averaged de-positioned tokens).
    pub descriptors: Samples,
    /// Bands seen.
    pub bands: usize,
}

/// ONNX value names of block `b`'s calibration taps: queries and keys after RoPE, values,
/// attention output, residual after attention, fc1 output, GELU output, block output (the
/// names the torch exporter gives `train/bino_train/model.py`; checked when the model loads).
pub fn block_taps(b: usize) -> [String; 8] {
    [
        format!("/blocks.{b}/attn/Add_output_0"),
        format!("/blocks.{b}/attn/Add_1_output_0"),
        format!("/blocks.{b}/attn/Gather_5_output_0"),
        format!("/blocks.{b}/attn/Reshape_1_output_0"),
        format!("/blocks.{b}/Add_output_0"),
        format!("/blocks.{b}/fc1/Add_output_0"),
        format!("/blocks.{b}/Mul_1_output_0"),
        format!("/blocks.{b}/Add_2_output_0"),
    ]
}

/// Tap names, in the order [`collect`] reads them; the embedding is read from `embed`.
pub fn tap_names(embed: EmbedSource) -> Vec<String> {
    let mut names = vec![embed.name().to_string(), "tokens".to_string()];
    for b in 0..DEPTH {
        names.extend(block_taps(b));
    }
    names
}

/// The band views calibration uses: the middle band of each view of the first `max_pairs`
/// train-split pairs of `data_dir` at `profile`. Never the eval split.
pub fn calibration_bands(data_dir: &Path, profile: Profile, max_pairs: usize) -> Result<Vec<View>> {
    let index = read_index(data_dir)?;
    let train: Vec<_> = index.iter().filter(|p| p.split == Split::Train).collect();
    ensure!(!train.is_empty(), "{} lists no train-split pairs", data_dir.display());
    let step = train.len().div_ceil(max_pairs.max(1)).max(1);
    let mut bands = Vec::new();
    for pair in train.iter().step_by(step) {
        for path in [&pair.left, &pair.right] {
            let view = profile.apply(&load_gray(path)?)?;
            bands.push(middle_band(&view)?);
        }
    }
    Ok(bands)
}

fn middle_band(view: &View) -> Result<View> {
    let plan = BandPlan::new(view.height / PATCH_H).map_err(anyhow::Error::msg)?;
    let band = plan.get(plan.len() / 2).context("empty band plan")?;
    let (start, rows) = (band.start * PATCH_H, (band.rows * PATCH_H).min(BAND_ROWS));
    Ok(View {
        width: view.width,
        height: rows,
        pixels: view.pixels[start * view.width..(start + rows) * view.width].to_vec(),
    })
}

/// Runs the float encoder on `(band, band)` for every band and gathers the statistics.
pub fn collect(onnx: &Path, bands: &[View], mut progress: impl FnMut(usize, usize)) -> Result<EncoderStats> {
    // A plain export has the embedding only as an internal value; block taps exist in both.
    let (names, mut model) = match TappedModel::load(onnx, &tap_names(EmbedSource::GraphOutput), 2) {
        Ok(model) => (tap_names(EmbedSource::GraphOutput), model),
        Err(graph_err) => {
            let names = tap_names(EmbedSource::InternalValue);
            let model = TappedModel::load(onnx, &names, 2).map_err(|internal_err| {
                anyhow::anyhow!(
                    "cannot read the calibration tensors of {}: with the `embed` output: {graph_err:#}; \
                     with its internal value: {internal_err:#}",
                    onnx.display()
                )
            })?;
            (names, model)
        }
    };
    let embed = names[0].clone();
    let formats = 2 * DEPTH + 1;
    let mut stats = EncoderStats {
        residual: vec![vec![Samples::default(); DIM]; formats],
        layernorm: vec![Samples::default(); 2 * DEPTH],
        queries: vec![Samples::default(); DEPTH],
        keys: vec![Samples::default(); DEPTH],
        values: vec![Samples::default(); DEPTH],
        attended: vec![Samples::default(); DEPTH],
        gelu_input: vec![Samples::default(); DEPTH],
        gelu_output: vec![Samples::default(); DEPTH],
        ..Default::default()
    };
    for (i, band) in bands.iter().enumerate() {
        let input = band_tensor(band);
        let outputs = model.run(vec![input.clone(), input])?;
        let values = |name: &str| -> Result<&Vec<f32>> {
            let at = names.iter().position(|n| n == name).context("unknown tap")?;
            Ok(&outputs[at].1)
        };
        add_residual(&mut stats, 0, values(&embed)?);
        let tokens = values("tokens")?;
        stats
            .descriptors
            .add(phase_average(tokens).into_iter(), SAMPLES_PER_BAND);
        for b in 0..DEPTH {
            let [q, k, v, attended, middle, fc1, gelu, out] = block_taps(b);
            stats.queries[b].add(values(&q)?.iter().copied(), SAMPLES_PER_BAND);
            stats.keys[b].add(values(&k)?.iter().copied(), SAMPLES_PER_BAND);
            stats.values[b].add(values(&v)?.iter().copied(), SAMPLES_PER_BAND);
            stats.attended[b].add(values(&attended)?.iter().copied(), SAMPLES_PER_BAND);
            stats.gelu_input[b].add(values(&fc1)?.iter().copied(), SAMPLES_PER_BAND);
            stats.gelu_output[b].add(values(&gelu)?.iter().copied(), SAMPLES_PER_BAND);
            add_residual(&mut stats, 2 * b + 1, values(&middle)?);
            add_residual(&mut stats, 2 * b + 2, values(&out)?);
        }
        stats.bands += 1;
        progress(i + 1, bands.len());
    }
    // LayerNorm inputs are residual formats 2b (before attention) and 2b + 1 (before the MLP).
    Ok(stats)
}

fn add_residual(stats: &mut EncoderStats, format: usize, tokens: &[f32]) {
    let count = tokens.len() / DIM;
    let step = count.div_ceil(RESIDUAL_TOKENS_PER_BAND).max(1);
    for token in tokens.chunks_exact(DIM).step_by(step) {
        for (c, &v) in token.iter().enumerate() {
            stats.residual[format][c].0.push(v);
        }
        // The LayerNorm reading this format sees its z-scores.
        if format < 2 * DEPTH {
            let z = z_scores(token);
            stats.layernorm[format].0.extend(z.iter().step_by(4));
        }
    }
}

/// LayerNorm without gamma and beta.
pub fn z_scores(token: &[f32]) -> Vec<f32> {
    let n = token.len() as f64;
    let mean = token.iter().map(|&v| v as f64).sum::<f64>() / n;
    let var = token.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / n;
    let inv = 1.0 / (var + LN_EPS).sqrt();
    token.iter().map(|&v| ((v as f64 - mean) * inv) as f32).collect()
}

fn phase_average(tokens: &[f32]) -> Vec<f32> {
    let mut out = Vec::with_capacity(tokens.len() / 2);
    for pair in tokens.chunks_exact(2 * DIM) {
        let (a, b) = pair.split_at(DIM);
        out.extend(a.iter().zip(b).map(|(x, y)| 0.5 * (x + y)));
    }
    out
}

/// A band as the (1, 3, h, w) input of the float encoder, the gray channel replicated.
pub fn band_tensor(view: &View) -> Tensor {
    tract_ndarray::Array4::from_shape_fn((1, 3, view.height, view.width), |(_, _, y, x)| {
        view.pixels[y * view.width + x]
    })
    .into()
}
