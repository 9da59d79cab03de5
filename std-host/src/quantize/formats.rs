//! Activation formats chosen from calibration statistics (docs/int8-model.md, "Formats").

use super::calibrate::{EncoderStats, Samples};
use super::scales::{asymmetric_format, percentile_sorted, symmetric_mse_scale};

/// Percentiles bounding each residual channel: wide enough to keep the real outliers of a ViT
/// residual stream (whole channels with large values get their own scale anyway).
pub const RESIDUAL_PERCENTILES: (f64, f64) = (0.0001, 0.9999);
/// Upper percentile of the GELU output (its lower bound is the GELU minimum, about -0.17).
pub const GELU_UPPER_PERCENTILE: f64 = 0.9999;
/// Zero points are kept within +-2^15 so the LayerNorm's 64-bit sums cannot overflow.
const ZERO_LIMIT: i32 = 1 << 15;

/// A per-channel residual format.
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelFormat {
    /// `real = scale[c] * (q - zero[c])`.
    pub scale: Vec<f64>,
    /// Zero points.
    pub zero: Vec<i32>,
}

/// An asymmetric per-tensor format.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TensorFormat {
    /// Scale.
    pub scale: f64,
    /// Zero point (0 for symmetric formats).
    pub zero: i32,
}

/// Every activation format of the encoder.
#[derive(Debug, Clone, PartialEq)]
pub struct EncoderFormats {
    /// Residual formats `0..=2 DEPTH`.
    pub residual: Vec<ChannelFormat>,
    /// LayerNorm output scales, `2b` and `2b + 1`.
    pub layernorm: Vec<f64>,
    /// Per block: queries, keys, values, attention output, fc1 output (GELU input).
    pub queries: Vec<f64>,
    /// Keys after RoPE.
    pub keys: Vec<f64>,
    /// Values.
    pub values: Vec<f64>,
    /// Attention output (projection input).
    pub attended: Vec<f64>,
    /// fc1 output.
    pub gelu_input: Vec<f64>,
    /// GELU output (fc2 input), asymmetric.
    pub gelu_output: Vec<TensorFormat>,
    /// Descriptors.
    pub descriptor: f64,
}

impl EncoderFormats {
    /// Chooses every format from the statistics.
    pub fn choose(stats: &EncoderStats) -> Self {
        let symmetric = |s: &Vec<Samples>| s.iter().map(|x| symmetric_mse_scale(x.values())).collect();
        Self {
            residual: stats.residual.iter().map(|channels| channel_format(channels)).collect(),
            layernorm: symmetric(&stats.layernorm),
            queries: symmetric(&stats.queries),
            keys: symmetric(&stats.keys),
            values: symmetric(&stats.values),
            attended: symmetric(&stats.attended),
            gelu_input: symmetric(&stats.gelu_input),
            gelu_output: stats.gelu_output.iter().map(gelu_format).collect(),
            descriptor: symmetric_mse_scale(stats.descriptors.values()),
        }
    }
}

fn channel_format(channels: &[Samples]) -> ChannelFormat {
    let mut scale = Vec::with_capacity(channels.len());
    let mut zero = Vec::with_capacity(channels.len());
    for samples in channels {
        let sorted = samples.sorted();
        let lo = percentile_sorted(&sorted, RESIDUAL_PERCENTILES.0);
        let hi = percentile_sorted(&sorted, RESIDUAL_PERCENTILES.1);
        let (mut s, mut z) = asymmetric_format(lo, hi);
        if z.abs() > ZERO_LIMIT {
            // A narrow channel far from zero: widen the scale until the zero point fits.
            s = lo.abs().max(hi.abs()) / (ZERO_LIMIT - 128) as f64;
            z = (-128.0 - lo / s).round() as i32;
        }
        scale.push(s);
        zero.push(z.clamp(-ZERO_LIMIT, ZERO_LIMIT));
    }
    ChannelFormat { scale, zero }
}

fn gelu_format(samples: &Samples) -> TensorFormat {
    let sorted = samples.sorted();
    let lo = sorted.first().copied().unwrap_or(0.0).min(0.0) as f64;
    let hi = percentile_sorted(&sorted, GELU_UPPER_PERCENTILE).max(1e-3);
    let (scale, zero) = asymmetric_format(lo, hi);
    TensorFormat { scale, zero }
}
