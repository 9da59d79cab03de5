//! The int8 shared head against the float head (tract) on the same pair: the logits' cosine
//! over the candidates inside the right view, and the soft-argmin disparity difference.
//!
//! Each runs on its own engine's descriptors (int8 head on int8 descriptors, float head on
//! float descriptors), so the numbers measure the whole int8 path up to the head's output.

use std::path::Path;

use anyhow::{ensure, Context, Result};
use bino_core::config::HEAD_MAX_DISP;
use tract_onnx::prelude::*;

use super::stages::cosine;
use crate::float::reference::FeatureMap;
use crate::float::taps::TappedModel;
use crate::int8::HeadMaps;

/// The float head's logits `(HEAD_MAX_DISP, rows, cols)` and disparity `(rows, cols)`.
pub struct FloatHeadOutput {
    /// Logits, candidate-major as the ONNX export lays them out.
    pub logits: Vec<f32>,
    /// Soft-argmin disparity per cell, in patch columns.
    pub disparity: Vec<f32>,
}

impl FloatHeadOutput {
    /// The largest candidate probability per cell in the core's Q8 (`255` x the probability, as
    /// the int8 head's `confidence_q8`): the float twin of what the fused readout weighs the
    /// head by ([`bino_core::lr::fuse_row`]).
    pub fn confidence_q8(&self) -> Vec<u16> {
        let cells = self.disparity.len();
        let candidates = self.logits.len().checked_div(cells).unwrap_or(0);
        (0..cells)
            .map(|cell| {
                let logits = (0..candidates).map(|k| self.logits[k * cells + cell]);
                let max = logits.clone().fold(f32::NEG_INFINITY, f32::max);
                let total: f32 = logits.map(|l| (l - max).exp()).sum();
                if total > 0.0 {
                    (255.0 / total).round() as u16
                } else {
                    0
                }
            })
            .collect()
    }

    /// The right view's disparity per cell (patch columns) of `(rows, cols)` maps, read from
    /// the logits' diagonal: right cell `q` soft-argmins over `k` the logit of left cell
    /// `q + k` at `k`, candidates with `q + k` outside the row excluded (the float twin of
    /// `bino_core::model::head::right_view_row`, the native pathway's one-pass check).
    pub fn right_view(&self, rows: usize, cols: usize) -> Vec<f32> {
        let cells = rows * cols;
        let candidates = self.logits.len().checked_div(cells).unwrap_or(0);
        let mut out = vec![0.0f32; cells];
        for (cell, o) in out.iter_mut().enumerate() {
            let (row, q) = (cell / cols, cell % cols);
            let diagonal: Vec<(usize, f32)> = (0..candidates)
                .filter(|&k| q + k < cols)
                .map(|k| (k, self.logits[k * cells + row * cols + q + k]))
                .collect();
            let max = diagonal.iter().map(|&(_, l)| l).fold(f32::NEG_INFINITY, f32::max);
            let (mut total, mut moment) = (0.0f32, 0.0f32);
            for &(k, l) in &diagonal {
                let w = (l - max).exp();
                total += w;
                moment += k as f32 * w;
            }
            *o = if total > 0.0 { moment / total } else { 0.0 };
        }
        out
    }
}

/// The ONNX head with its logits exposed (the export's `logits` node is tapped, so any head
/// export works, with or without `--logits`).
pub struct FloatHeadRunner {
    model: TappedModel,
}

impl FloatHeadRunner {
    /// Loads a head export (`python -m bino_train.head`).
    pub fn load(path: &Path) -> Result<Self> {
        let taps = ["logits".to_string(), "disparity".to_string()];
        let model =
            TappedModel::load(path, &taps, 2).with_context(|| format!("loading the float head {}", path.display()))?;
        Ok(Self { model })
    }

    /// Runs the head on two descriptor maps of the same shape.
    pub fn run(&mut self, left: &FeatureMap, right: &FeatureMap) -> Result<FloatHeadOutput> {
        ensure!(
            (left.rows, left.cols, left.dim) == (right.rows, right.cols, right.dim),
            "descriptor maps differ in shape"
        );
        let tensor = |m: &FeatureMap| -> Result<Tensor> {
            Ok(tract_ndarray::Array4::from_shape_vec((1, m.rows, m.cols, m.dim), m.data.clone())?.into())
        };
        let mut outputs = self.model.run(vec![tensor(left)?, tensor(right)?])?.into_iter();
        let (logits_shape, logits) = outputs.next().context("the head gave no logits")?;
        let (_, disparity) = outputs.next().context("the head gave no disparity")?;
        ensure!(
            logits_shape == [1, HEAD_MAX_DISP, left.rows, left.cols],
            "head logits have shape {logits_shape:?}, expected [1, {HEAD_MAX_DISP}, {}, {}]",
            left.rows,
            left.cols
        );
        ensure!(
            disparity.len() == left.rows * left.cols,
            "head disparity has the wrong size"
        );
        Ok(FloatHeadOutput { logits, disparity })
    }
}

/// How closely the int8 head's maps follow the float head's on the same grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadAgreement {
    /// Cosine of the int8 and float logits over the valid candidates.
    pub logit_cosine: f64,
    /// Mean |int8 - float| soft-argmin disparity, in patch columns.
    pub disparity_mean_abs: f64,
}

/// Compares the int8 head's maps with the float head's on the same grid.
pub fn compare_heads(int8: &HeadMaps, float: &FloatHeadOutput) -> Result<HeadAgreement> {
    let (rows, cols) = (int8.rows, int8.cols);
    // Both searched the same candidates (the view width's, readout::head_candidates).
    let nd = int8.logits.len() / (rows * cols).max(1);
    ensure!(
        nd > 0
            && int8.logits.len() == rows * cols * nd
            && float.logits.len() == rows * cols * nd
            && int8.disparity.len() == rows * cols
            && float.disparity.len() == rows * cols,
        "head outputs of the two engines differ in size"
    );
    // Candidate d of column p is inside the right view only for d <= p.
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for r in 0..rows {
        for p in 0..cols {
            for d in 0..=p.min(nd - 1) {
                a.push(int8.logits[(r * cols + p) * nd + d]);
                b.push(float.logits[(d * rows + r) * cols + p]);
            }
        }
    }
    let disparity_mean_abs = int8
        .disparity
        .iter()
        .zip(&float.disparity)
        .map(|(x, y)| (x - y).abs() as f64)
        .sum::<f64>()
        / (rows * cols).max(1) as f64;
    Ok(HeadAgreement {
        logit_cosine: cosine(&a, &b),
        disparity_mean_abs,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn maps(rows: usize, cols: usize, logit: impl Fn(usize, usize, usize) -> f32) -> (HeadMaps, FloatHeadOutput) {
        let mut engine = vec![0.0; rows * cols * HEAD_MAX_DISP];
        let mut float = vec![0.0; rows * cols * HEAD_MAX_DISP];
        for r in 0..rows {
            for p in 0..cols {
                for d in 0..HEAD_MAX_DISP {
                    engine[(r * cols + p) * HEAD_MAX_DISP + d] = logit(r, p, d);
                    float[(d * rows + r) * cols + p] = logit(r, p, d);
                }
            }
        }
        let disparity = vec![1.5; rows * cols];
        let int8 = HeadMaps {
            rows,
            cols,
            disparity: disparity.clone(),
            confidence: vec![1.0; rows * cols],
            logits: engine,
            right_view: vec![0.0; rows * cols],
        };
        (
            int8,
            FloatHeadOutput {
                logits: float,
                disparity,
            },
        )
    }

    #[test]
    fn equal_heads_agree_whatever_the_layouts() {
        let (int8, float) = maps(2, 5, |r, p, d| (r * 31 + p * 7 + d) as f32 - 20.0);
        let c = compare_heads(&int8, &float).unwrap();
        assert!((c.logit_cosine - 1.0).abs() < 1e-9, "{}", c.logit_cosine);
        assert_eq!(c.disparity_mean_abs, 0.0);
    }

    #[test]
    fn candidates_outside_the_view_are_ignored_and_differences_count() {
        let (mut int8, mut float) = maps(1, 3, |_, p, d| (p + d) as f32 + 1.0);
        // Column 0 has only candidate 0; this one must not matter (and may be -inf).
        int8.logits[5] = f32::NEG_INFINITY;
        let c = compare_heads(&int8, &float).unwrap();
        assert!((c.logit_cosine - 1.0).abs() < 1e-9);
        float.disparity[1] = 2.5;
        int8.logits[HEAD_MAX_DISP] = -50.0; // column 1, candidate 0: inside the view
        let c = compare_heads(&int8, &float).unwrap();
        assert!(c.logit_cosine < 0.99);
        assert!((c.disparity_mean_abs - 1.0 / 3.0).abs() < 1e-9);
    }

    /// The float head's confidence is 255 x its largest candidate probability, masked
    /// candidates (the head's large negative logits) counting for nothing.
    #[test]
    fn confidence_is_the_largest_probability_in_q8() {
        let masked = -1e4;
        // Two cells, candidate-major: a sure one, and one split evenly over 3 candidates.
        let mut logits = vec![masked; 2 * HEAD_MAX_DISP];
        logits[0] = 40.0; // cell 0, candidate 0
        for k in 0..3 {
            logits[k * 2 + 1] = 2.0;
        }
        let out = FloatHeadOutput {
            logits,
            disparity: vec![0.0; 2],
        };
        assert_eq!(out.confidence_q8(), [255, 85]);
    }

    #[test]
    fn size_mismatch_is_an_error() {
        let (mut int8, float) = maps(1, 3, |_, _, _| 1.0);
        int8.disparity.pop();
        assert!(compare_heads(&int8, &float).is_err());
    }
}
