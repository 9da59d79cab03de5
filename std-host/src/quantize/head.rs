//! The heads' int8 tensors: calibration on float input maps of train-split pairs (tract taps
//! of the head ONNX) and the integer parameters of `core/src/model/head.rs`. The export head
//! reads descriptor maps D(L), D(R); the native head the two phase maps of the pair's
//! de-positioned fused grid (even and odd fused columns), each as a map of `DIM` channels.

use std::path::Path;

use anyhow::{ensure, Context, Result};
use bino_core::config::{DIM, HEAD_GROUPS, HEAD_HIDDEN, HEAD_MAX_DISP, HEAD_MIDDLE_LAYERS};
use bino_core::kernels::types::layernorm::Z_FRAC_BITS;
use bino_core::model::ids::{self, kind, HeadKind, Linear, HEAD_CONVS};
use tract_onnx::prelude::*;

use super::calibrate::{z_scores, Samples};
use super::scales::{asymmetric_format, percentile_sorted, quantize_rows, requant_of, symmetric_mse_scale};
use crate::data::nuisance::{degrade_view, Nuisance};
use crate::float::head::{FloatConv3d, FloatHead};
use crate::float::reference::FeatureMap;
use crate::float::taps::TappedModel;
use crate::float::weights::FloatLinear;
use crate::int8::blob_writer::BlobWriter;

/// Values kept per tensor per calibration map.
const SAMPLES_PER_MAP: usize = 16_384;
/// The engine's LayerNorm input unit for descriptors (`core/src/model/head.rs`, `DESC_REL`).
const DESC_REL: f64 = 256.0;
/// Upper percentile of the non-negative hidden activations.
const HIDDEN_UPPER_PERCENTILE: f64 = 0.9999;
const KERNEL: usize = 27;
/// Upper percentiles of `|correlation|` tried as its clipping bound, besides the MSE choice.
/// The volume's matching peaks are a heavy tail (on the shipped weights the maximum is ~6x
/// the 99th percentile) that MSE spends most codes on, while the stem conv needs resolution
/// in the bulk; which bound serves the head best is measured, not assumed.
const CORRELATION_PERCENTILES: [f64; 5] = [0.9999, 0.999, 0.995, 0.99, 0.98];

/// Tap names of the head ONNX (`python -m bino_train.head`): projected left and right,
/// correlation volume, stem output, the middle layers' residual outputs.
pub fn head_taps(head: HeadKind) -> Vec<String> {
    let (left, right) = match head {
        HeadKind::Export => ("/head/proj/Add_output_0", "/head/proj_1/Add_output_0"),
        HeadKind::Native => ("/head/proj_left/Add_output_0", "/head/proj_right/Add_output_0"),
    };
    let mut names = vec![
        left.to_string(),
        right.to_string(),
        "/head/Transpose_output_0".to_string(),
        "/head/Relu_output_0".to_string(),
    ];
    names.extend((1..=HEAD_MIDDLE_LAYERS).map(|i| format!("/head/Add_{i}_output_0")));
    names
}

/// What head calibration measured.
#[derive(Debug, Clone, Default)]
pub struct HeadStats {
    /// LayerNorm z-scores of the descriptors.
    pub normalised: Samples,
    /// Projected descriptors (both views).
    pub projected: Samples,
    /// Correlation volume.
    pub correlation: Samples,
    /// Stem output, then each middle layer's output.
    pub hidden: Vec<Samples>,
    /// Descriptor map pairs seen.
    pub maps: usize,
    /// The float head's disparity (patch columns) on each calibration pair.
    pub float_disparity: Vec<Vec<f32>>,
}

/// Runs the float `head` on its input map pairs (D(L), D(R), or the even and odd phase maps)
/// and gathers the statistics.
pub fn collect(head_onnx: &Path, head: HeadKind, pairs: &[(FeatureMap, FeatureMap)]) -> Result<HeadStats> {
    let mut names = head_taps(head);
    names.push("disparity".to_string());
    let mut model = TappedModel::load(head_onnx, &names, 2)?;
    let mut stats = HeadStats {
        hidden: vec![Samples::default(); 1 + HEAD_MIDDLE_LAYERS],
        ..Default::default()
    };
    for (left, right) in pairs {
        ensure!(
            left.dim == DIM && right.dim == DIM && (left.rows, left.cols) == (right.rows, right.cols),
            "head input maps differ"
        );
        match head {
            HeadKind::Export => {
                for map in [left, right] {
                    let z: Vec<f32> = map.data.chunks_exact(DIM).step_by(4).flat_map(z_scores).collect();
                    stats.normalised.add(z.into_iter(), SAMPLES_PER_MAP);
                }
            }
            HeadKind::Native => {
                // The LayerNorm sees the pair feature u = [a, b] of each cell.
                let cells = left.data.chunks_exact(DIM).zip(right.data.chunks_exact(DIM));
                let z: Vec<f32> = cells.step_by(2).flat_map(|(a, b)| z_scores(&[a, b].concat())).collect();
                stats.normalised.add(z.into_iter(), SAMPLES_PER_MAP);
            }
        }
        let outputs = model.run(vec![map_tensor(left)?, map_tensor(right)?])?;
        stats.projected.add(outputs[0].1.iter().copied(), SAMPLES_PER_MAP);
        stats.projected.add(outputs[1].1.iter().copied(), SAMPLES_PER_MAP);
        stats.correlation.add(outputs[2].1.iter().copied(), SAMPLES_PER_MAP);
        for (i, samples) in stats.hidden.iter_mut().enumerate() {
            samples.add(outputs[3 + i].1.iter().copied(), SAMPLES_PER_MAP);
        }
        stats.float_disparity.push(outputs[names.len() - 1].1.clone());
        stats.maps += 1;
    }
    Ok(stats)
}

fn map_tensor(map: &FeatureMap) -> Result<Tensor> {
    let array = tract_ndarray::Array4::from_shape_vec((1, map.rows, map.cols, map.dim), map.data.clone())?;
    Ok(array.into())
}

/// The head's activation formats.
#[derive(Debug, Clone, PartialEq)]
pub struct HeadFormats {
    /// LayerNorm output scale.
    pub normalised: f64,
    /// Projection output scale.
    pub projected: f64,
    /// Correlation scale.
    pub correlation: f64,
    /// Hidden formats (scale, zero point): stem, middle layers.
    pub hidden: Vec<(f64, i32)>,
}

impl HeadFormats {
    /// Chooses every format from the statistics.
    pub fn choose(stats: &HeadStats) -> Self {
        let hidden = stats
            .hidden
            .iter()
            .map(|s| {
                let hi = percentile_sorted(&s.sorted(), HIDDEN_UPPER_PERCENTILE).max(1e-4);
                asymmetric_format(0.0, hi)
            })
            .collect();
        Self {
            normalised: symmetric_mse_scale(stats.normalised.values()),
            projected: symmetric_mse_scale(stats.projected.values()),
            correlation: symmetric_mse_scale(stats.correlation.values()),
            hidden,
        }
    }

    /// The formats to try, labelled: [`HeadFormats::choose`] (MSE correlation bound), then the
    /// same with the correlation clipped at each of `CORRELATION_PERCENTILES`.
    pub fn candidates(stats: &HeadStats) -> Vec<(String, Self)> {
        let mse = Self::choose(stats);
        let mut abs: Vec<f32> = stats.correlation.values().iter().map(|v| v.abs()).collect();
        abs.sort_by(f32::total_cmp);
        let mut out = vec![("correlation MSE".to_string(), mse.clone())];
        for q in CORRELATION_PERCENTILES {
            let bound = percentile_sorted(&abs, q).max(1e-6);
            let label = format!("correlation p{}", q * 100.0);
            out.push((
                label,
                Self {
                    correlation: bound / 127.0,
                    ..mse.clone()
                },
            ));
        }
        out
    }
}

/// Mean |int8 - float| head disparity in patch columns over the calibration pairs: the int8
/// `head` of `model` on the float input maps quantised to its input codes (`desc_scale`).
pub fn disagreement(
    model: &crate::int8::Int8Model,
    head: HeadKind,
    pairs: &[(FeatureMap, FeatureMap)],
    float_disparity: &[Vec<f32>],
    desc_scale: f64,
) -> Result<f64> {
    ensure!(
        pairs.len() == float_disparity.len() && !pairs.is_empty(),
        "head calibration saw {} maps and {} float disparities",
        pairs.len(),
        float_disparity.len()
    );
    let codes = |map: &FeatureMap| -> Vec<i8> {
        map.data
            .iter()
            .map(|&x| (x as f64 / desc_scale).round().clamp(-127.0, 127.0) as i8)
            .collect()
    };
    let (mut sum, mut cells) = (0.0f64, 0usize);
    for ((left, right), float) in pairs.iter().zip(float_disparity) {
        let maps = match head {
            HeadKind::Export => model.head(&codes(left), &codes(right), left.rows, left.cols)?,
            HeadKind::Native => {
                let tokens = crate::int8::interleave_phases(&codes(left), &codes(right), DIM);
                model.native_head(&tokens, left.rows, left.cols)?
            }
        };
        ensure!(maps.disparity.len() == float.len(), "head maps differ in size");
        sum += maps
            .disparity
            .iter()
            .zip(float)
            .map(|(a, b)| (a - b).abs() as f64)
            .sum::<f64>();
        cells += float.len();
    }
    Ok(sum / cells as f64)
}

/// Writes every tensor of `float`'s head (export or native, [`FloatHead::kind`]); `desc_scale`
/// is the encoder's descriptor scale (the unit of both heads' input codes).
pub fn write_head(float: &FloatHead, f: &HeadFormats, desc_scale: f64, w: &mut BlobWriter) -> Result<()> {
    let head = float.kind;
    let at = head.index();
    ensure!(
        float.middle.len() == HEAD_MIDDLE_LAYERS,
        "head has {} middle layers",
        float.middle.len()
    );
    ensure!(f.hidden.len() == 1 + HEAD_MIDDLE_LAYERS, "head formats incomplete");
    let unit = desc_scale / DESC_REL;
    let eps = (float.ln_eps as f64 / (unit * unit)).round() as i64;
    let out = requant_of(1.0 / (f.normalised * (1u64 << Z_FRAC_BITS) as f64))?;
    w.add_i64(
        ids::id(kind::LAYERNORM, head.layernorm()),
        &[eps, out.mult as i64, out.shift as i64],
    )?;

    let projections = match (head, &float.proj_right) {
        (HeadKind::Export, None) => vec![(Linear::HeadProj, &float.proj)],
        (HeadKind::Native, Some(right)) => {
            vec![(Linear::NativeProjLeft, &float.proj), (Linear::NativeProjRight, right)]
        }
        _ => anyhow::bail!("the {} head's projections are incomplete", head.pathway()),
    };
    for (layer, linear) in projections {
        let proj = fold_layernorm(linear, &float.norm_weight, &float.norm_bias);
        let (codes, scales) = quantize_rows(&proj.weight, head.input_dim());
        let bias: Result<Vec<i32>> = scales
            .iter()
            .zip(&proj.bias)
            .map(|(&s, &b)| to_i32(b as f64 / (f.normalised * s)))
            .collect();
        let mults: Result<Vec<_>> = scales
            .iter()
            .map(|&s| requant_of(f.normalised * s / f.projected))
            .collect();
        write_linear(w, layer, &codes, &bias?, &mults?)?;
    }

    let per_group = (head.proj_dim() / HEAD_GROUPS) as f64;
    let corr = requant_of(f.projected * f.projected / per_group / f.correlation)?;
    w.add_i32(ids::id(kind::HEAD_CORRELATION, at), &[corr.mult, corr.shift as i32])?;

    let convs: Vec<&FloatConv3d> = std::iter::once(&float.stem)
        .chain(float.middle.iter())
        .chain(std::iter::once(&float.out))
        .collect();
    let mut zeros = vec![0i32; HEAD_CONVS];
    let mut carries = Vec::new();
    for (layer, conv) in convs.iter().enumerate() {
        let (in_scale, in_zero) = if layer == 0 {
            (f.correlation, 0)
        } else {
            f.hidden[layer - 1]
        };
        zeros[layer] = in_zero;
        let weight = kernel_major(conv);
        let (codes, scales) = quantize_rows(&weight, KERNEL * conv.in_channels);
        let inputs = KERNEL * conv.in_channels;
        let bias: Result<Vec<i32>> = (0..conv.out_channels)
            .map(|n| {
                let sum: i64 = codes[n * inputs..(n + 1) * inputs].iter().map(|&c| c as i64).sum();
                to_i32(conv.bias[n] as f64 / (in_scale * scales[n]) - in_zero as f64 * sum as f64)
            })
            .collect();
        let out_scale = if layer + 1 < HEAD_CONVS { f.hidden[layer].0 } else { 1.0 };
        let mults: Result<Vec<_>> = scales.iter().map(|&s| requant_of(in_scale * s / out_scale)).collect();
        write_linear(w, head.conv(layer), &codes, &bias?, &mults?)?;
        if (1..HEAD_CONVS - 1).contains(&layer) {
            let carry = requant_of(in_scale / f.hidden[layer].0)?;
            carries.extend([carry.mult, carry.shift as i32]);
        }
        if layer + 1 == HEAD_CONVS {
            let logit_scale = in_scale * scales[0];
            let softmax = requant_of(logit_scale * std::f64::consts::LOG2_E * 256.0)?;
            w.add_i32(ids::id(kind::HEAD_SOFTMAX, at), &[softmax.mult, softmax.shift as i32])?;
            w.add_f32(ids::id(kind::META_HEAD_LOGIT_SCALE, at), &[logit_scale as f32])?;
        }
    }
    w.add_i32(ids::id(kind::HEAD_ZERO, at), &zeros)?;
    w.add_i32(ids::id(kind::HEAD_CARRY, at), &carries)?;
    ensure!(
        HEAD_HIDDEN == float.stem.out_channels && HEAD_MAX_DISP == float.max_disp,
        "head shape differs"
    );
    Ok(())
}

/// Conv3d weights `(out, in, kd, kh, kw)` (volume dims disparity, row, column) reordered to the
/// engine's `[out][kh][kd][kw][in]`.
fn kernel_major(conv: &FloatConv3d) -> Vec<f32> {
    let (co, ci) = (conv.out_channels, conv.in_channels);
    let mut out = Vec::with_capacity(co * ci * KERNEL);
    for o in 0..co {
        for kh in 0..3 {
            for kd in 0..3 {
                for kw in 0..3 {
                    for i in 0..ci {
                        out.push(conv.weight[(((o * ci + i) * 3 + kd) * 3 + kh) * 3 + kw]);
                    }
                }
            }
        }
    }
    out
}

fn fold_layernorm(linear: &FloatLinear, gamma: &[f32], beta: &[f32]) -> FloatLinear {
    let k = linear.in_features;
    let mut weight = linear.weight.clone();
    let mut bias = linear.bias.clone();
    for (n, row) in weight.chunks_exact_mut(k).enumerate() {
        let shift: f64 = row.iter().zip(beta).map(|(&w, &b)| w as f64 * b as f64).sum();
        row.iter_mut().zip(gamma).for_each(|(w, &g)| *w *= g);
        bias[n] += shift as f32;
    }
    FloatLinear {
        out_features: linear.out_features,
        in_features: k,
        weight,
        bias,
    }
}

fn write_linear(
    w: &mut BlobWriter,
    layer: Linear,
    codes: &[i8],
    bias: &[i32],
    mults: &[bino_core::fixed::Requant],
) -> Result<()> {
    w.add_i8(layer.id(kind::LINEAR_WEIGHT), codes)?;
    w.add_i32(layer.id(kind::LINEAR_BIAS), bias)?;
    w.add_i32(
        layer.id(kind::LINEAR_MULT),
        &mults.iter().map(|r| r.mult).collect::<Vec<_>>(),
    )?;
    w.add_u8(
        layer.id(kind::LINEAR_SHIFT),
        &mults.iter().map(|r| r.shift as u8).collect::<Vec<_>>(),
    )?;
    Ok(())
}

fn to_i32(x: f64) -> Result<i32> {
    let r = x.round();
    ensure!(
        r.is_finite() && r.abs() < 2f64.powi(31),
        "a head bias does not fit in 32 bits ({x:e})"
    );
    Ok(r as i32)
}

/// Seed of the calibration nuisances (`bino eval --nuisance`'s default).
pub const CALIBRATION_NUISANCE_SEED: u64 = 0;

/// Float input maps of the `head` on the first `max_pairs` train pairs (spread over the split)
/// for head calibration: D(L), D(R), or the even and odd phase maps of the pair's token grid;
/// then the same pair again with its right view under each of `nuisances`.
pub fn calibration_maps(
    encoder_onnx: &Path,
    head: HeadKind,
    data: &Path,
    profile: crate::data::profile::Profile,
    max_pairs: usize,
    nuisances: &[Nuisance],
) -> Result<Vec<(FeatureMap, FeatureMap)>> {
    use crate::data::pairs::{read_index, Split};
    use crate::io::image_io::load_gray;
    let index = read_index(data)?;
    let train: Vec<_> = index.iter().filter(|p| p.split == Split::Train).collect();
    ensure!(!train.is_empty(), "{} lists no train-split pairs", data.display());
    let step = train.len().div_ceil(max_pairs.max(1)).max(1);
    let mut encoder = crate::float::reference::ReferenceEncoder::load(encoder_onnx)?;
    let mut maps = Vec::new();
    for pair in train.iter().step_by(step) {
        let left = profile.apply(&load_gray(&pair.left)?)?;
        let right = profile.apply(&load_gray(&pair.right)?)?;
        let degraded = nuisances
            .iter()
            .map(|&n| degrade_view(&right, n, CALIBRATION_NUISANCE_SEED, &pair.pair_id));
        for right in std::iter::once(right.clone()).chain(degraded) {
            let inputs = match head {
                HeadKind::Export => encoder
                    .descriptors(&left)
                    .and_then(|dl| Ok((dl, encoder.descriptors(&right)?))),
                HeadKind::Native => encoder.tokens(&left, &right).map(|t| t.phase_maps()),
            };
            maps.push(inputs.with_context(|| pair.pair_id.clone())?);
        }
    }
    Ok(maps)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn samples(values: impl IntoIterator<Item = f32>) -> Samples {
        let values: Vec<f32> = values.into_iter().collect();
        let mut s = Samples::default();
        s.add(values.into_iter(), usize::MAX);
        s
    }

    #[test]
    fn correlation_candidates_start_with_mse_and_tighten() {
        // A bulk in [-10, 10] and a heavy tail of matching peaks up to 170.
        let bulk = (0..10_000).map(|i| (i % 200) as f32 / 10.0 - 10.0);
        let peaks = (0..50).map(|i| 20.0 + 3.0 * i as f32);
        let stats = HeadStats {
            normalised: samples([1.0, -1.0]),
            projected: samples([1.0, -1.0]),
            correlation: samples(bulk.chain(peaks)),
            hidden: vec![samples([0.0, 1.0]); 1 + HEAD_MIDDLE_LAYERS],
            ..Default::default()
        };
        let candidates = HeadFormats::candidates(&stats);
        assert_eq!(candidates.len(), 1 + CORRELATION_PERCENTILES.len());
        assert_eq!(candidates[0].1, HeadFormats::choose(&stats));
        let bounds: Vec<f64> = candidates[1..].iter().map(|(_, f)| f.correlation * 127.0).collect();
        assert!(bounds.windows(2).all(|w| w[0] > w[1]), "{bounds:?}");
        assert!(bounds[0] <= 170.0 && *bounds.last().unwrap() >= 9.0, "{bounds:?}");
        // Only the correlation format differs between candidates.
        for (_, f) in &candidates[1..] {
            assert_eq!(
                (f.projected, &f.hidden),
                (candidates[0].1.projected, &candidates[0].1.hidden)
            );
        }
    }
}
