//! The quantiser's arithmetic: real factors as fixed-point `Requant`s, and choosing ranges
//! that survive the outliers of ViT activations.

use anyhow::{bail, Result};
use bino_core::fixed::{Requant, MAX_SHIFT};

/// A positive real factor as `mult / 2^shift` with `mult` in `[2^30, 2^31)`.
pub fn requant_of(real: f64) -> Result<Requant> {
    if !(real.is_finite() && real > 0.0) {
        bail!("cannot represent the factor {real} in fixed point");
    }
    let exponent = real.log2().floor() as i32 + 1; // real = m * 2^exponent, m in [0.5, 1)
    let shift = 31 - exponent;
    let mut mult = (real * 2f64.powi(shift)).round();
    let mut shift = shift;
    if mult >= 2f64.powi(31) {
        // Rounding reached 2^31: one bit less.
        mult /= 2.0;
        shift -= 1;
    }
    if shift < 1 || shift as u32 > MAX_SHIFT {
        bail!("factor {real:e} is outside the fixed-point range (shift {shift})");
    }
    Ok(Requant {
        mult: mult as i32,
        shift: shift as u32,
    })
}

/// The real value of a `Requant`.
pub fn requant_value(r: Requant) -> f64 {
    r.mult as f64 / 2f64.powi(r.shift as i32)
}

/// Symmetric int8 scale (`[-127, 127]` codes) minimising the quantisation MSE of `values`:
/// the clipping bound is searched from the 99th percentile of `|x|` to the maximum.
/// (Bare min/max wastes the codes on rare outliers; a fixed percentile clips tails that
/// carry meaning. The MSE search picks per tensor.)
pub fn symmetric_mse_scale(values: &[f32]) -> f64 {
    let mut abs: Vec<f32> = values.iter().map(|v| v.abs()).filter(|v| v.is_finite()).collect();
    if abs.is_empty() {
        return 1.0;
    }
    abs.sort_by(f32::total_cmp);
    let max = *abs.last().unwrap_or(&1.0) as f64;
    if max == 0.0 {
        return 1.0 / 127.0;
    }
    let low = percentile_sorted(&abs, 0.99).max(max * 1e-3);
    let sample = subsample(&abs, 200_000);
    let mut best = (f64::INFINITY, max / 127.0);
    for i in 0..=64 {
        let bound = low + (max - low) * i as f64 / 64.0;
        let scale = bound / 127.0;
        let err: f64 = sample
            .iter()
            .map(|&v| {
                let q = (v as f64 / scale).round().min(127.0) * scale;
                (q - v as f64).powi(2)
            })
            .sum();
        if err < best.0 {
            best = (err, scale);
        }
    }
    best.1
}

/// An asymmetric int8 format (`real = scale * (q - zero)`, codes `[-128, 127]`) for values in
/// `[lo, hi]`; the zero point need not be representable (ranges away from zero are fine).
pub fn asymmetric_format(lo: f64, hi: f64) -> (f64, i32) {
    let (lo, hi) = if hi - lo < 1e-6 {
        (lo - 5e-7, hi + 5e-7)
    } else {
        (lo, hi)
    };
    let scale = (hi - lo) / 255.0;
    let zero = (-128.0 - lo / scale).round();
    (scale, zero as i32)
}

/// The `q`-quantile (`0..=1`) of sorted values, by linear interpolation.
pub fn percentile_sorted(sorted: &[f32], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let pos = q.clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let (i, frac) = (pos.floor() as usize, pos.fract());
    let a = sorted[i] as f64;
    let b = sorted[(i + 1).min(sorted.len() - 1)] as f64;
    a + (b - a) * frac
}

/// Every `len / n`-th value (all of them when short).
pub fn subsample(values: &[f32], n: usize) -> Vec<f32> {
    let step = values.len().div_ceil(n.max(1)).max(1);
    values.iter().step_by(step).copied().collect()
}

/// Symmetric per-row int8 quantisation of a weight matrix (`rows x cols`): codes and scales.
pub fn quantize_rows(weight: &[f32], cols: usize) -> (Vec<i8>, Vec<f64>) {
    let mut codes = Vec::with_capacity(weight.len());
    let mut scales = Vec::new();
    for row in weight.chunks_exact(cols) {
        let max = row.iter().fold(0f64, |m, &w| m.max((w as f64).abs()));
        let scale = if max > 0.0 { max / 127.0 } else { 1.0 };
        scales.push(scale);
        codes.extend(
            row.iter()
                .map(|&w| (w as f64 / scale).round().clamp(-127.0, 127.0) as i8),
        );
    }
    (codes, scales)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requant_of_is_accurate() {
        for real in [1e-9, 3.7e-5, 0.25, 0.999_999_9, 1.0, 1.5, 1000.0] {
            let r = requant_of(real).expect("representable");
            assert!((1 << 30..=i32::MAX).contains(&r.mult), "{real}: {r:?}");
            assert!((requant_value(r) - real).abs() <= real * 1e-9, "{real}: {r:?}");
        }
        assert!(requant_of(0.0).is_err());
        assert!(requant_of(f64::NAN).is_err());
        assert!(requant_of(1e30).is_err());
    }

    #[test]
    fn requant_applies_like_the_real_factor() {
        let r = requant_of(0.0123).expect("representable");
        for x in [-100_000, -1, 0, 7, 12345, 2_000_000] {
            let want = (x as f64 * 0.0123).round();
            assert!((r.apply(x) as f64 - want).abs() <= 1.0, "{x}");
        }
    }

    /// Quantisation MSE of `values` at `scale` (the quantity the search minimises).
    fn quantisation_error(values: &[f32], scale: f64) -> f64 {
        values
            .iter()
            .map(|&v| {
                let q = (v.abs() as f64 / scale).round().min(127.0) * scale;
                (q - v.abs() as f64).powi(2)
            })
            .sum()
    }

    #[test]
    fn mse_scale_clips_a_lone_outlier() {
        // A dense bulk in [-1, 1] and one outlier at 50: spending the codes on [-50, 50]
        // costs the bulk more than clipping the outlier somewhat costs it.
        let mut values: Vec<f32> = (0..20_000).map(|i| ((i % 200) as f32 - 100.0) / 100.0).collect();
        values.push(50.0);
        let scale = symmetric_mse_scale(&values);
        let min_max = 50.0 / 127.0;
        assert!(scale < min_max, "bound {}", scale * 127.0);
        assert!(scale * 127.0 >= 0.99, "bound {}", scale * 127.0);
        assert!(quantisation_error(&values, scale) < quantisation_error(&values, min_max));
        let p99 = 0.99 / 127.0;
        assert!(quantisation_error(&values, scale) <= quantisation_error(&values, p99));
    }

    #[test]
    fn mse_scale_keeps_the_full_range_without_outliers() {
        let values: Vec<f32> = (0..10_000).map(|i| ((i % 200) as f32 - 100.0) / 100.0).collect();
        let bound = symmetric_mse_scale(&values) * 127.0;
        assert!(bound > 0.98 && bound <= 1.0, "bound {bound}");
    }

    #[test]
    fn asymmetric_format_covers_the_range() {
        let (scale, zero) = asymmetric_format(-0.17, 3.0);
        assert!(((-128 - zero) as f64 * scale + 0.17).abs() < scale);
        assert!(((127 - zero) as f64 * scale - 3.0).abs() < scale);
        let (scale, zero) = asymmetric_format(10.0, 10.5);
        assert!(((-128 - zero) as f64 * scale - 10.0).abs() < scale);
    }

    #[test]
    fn rows_quantise_symmetrically() {
        let (codes, scales) = quantize_rows(&[0.5, -1.0, 0.25, 0.0, 0.0, 0.0], 3);
        assert_eq!(codes, vec![64, -127, 32, 0, 0, 0]);
        assert!((scales[0] - 1.0 / 127.0).abs() < 1e-12);
    }
}
