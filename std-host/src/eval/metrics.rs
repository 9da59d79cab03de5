//! The `EVAL.md` metrics (`probe.score`, `probe.fill_invalid`, `probe.mean_metrics`): errors
//! over ground-truth-valid pixels of one pair, then the unweighted mean over pairs.

use anyhow::{ensure, Result};
use serde::Serialize;

use super::gt::GroundTruthMap;
use super::DisparityMap;

/// Errors above this many pixels (one patch column) count towards `bad1tok`.
const BAD1TOK_PX: f32 = 4.0;
/// Errors above this many pixels count towards `bad2`.
const BAD2_PX: f32 = 2.0;

/// Scores of one pair, or their mean over pairs; in JSON a non-finite value is `null`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Metrics {
    /// Mean absolute disparity error in pixels at the profile's resolution.
    pub epe: f64,
    /// % of pixels with error > 4 px.
    pub bad1tok: f64,
    /// % of pixels with error > 2 px.
    pub bad2: f64,
    /// % of pixels with a valid prediction before filling.
    pub density: f64,
}

/// Scores a dense per-pixel prediction (in pixels) against ground truth; density 100.
pub fn score(pred: &DisparityMap, gt: &GroundTruthMap) -> Result<Metrics> {
    ensure!(
        (pred.width, pred.height) == (gt.width, gt.height),
        "prediction is {}x{}, ground truth {}x{}",
        pred.width,
        pred.height,
        gt.width,
        gt.height
    );
    let errors: Vec<f32> = (pred.values.iter().zip(&gt.disparity).zip(&gt.valid))
        .filter(|(_, &valid)| valid)
        .map(|((&p, &g), _)| (p - g).abs())
        .collect();
    ensure!(!errors.is_empty(), "ground truth has no valid pixel");
    let n = errors.len() as f64;
    let percent_above = |limit: f32| 100.0 * errors.iter().filter(|&&e| e > limit).count() as f64 / n;
    Ok(Metrics {
        epe: errors.iter().map(|&e| e as f64).sum::<f64>() / n,
        bad1tok: percent_above(BAD1TOK_PX),
        bad2: percent_above(BAD2_PX),
        density: 100.0,
    })
}

/// Scores a prediction whose pixels are valid only where `pred_valid` says: invalid pixels are
/// filled with [`fill_invalid`] first, and `density` is measured before filling.
pub fn score_sparse(pred: &DisparityMap, pred_valid: &[bool], gt: &GroundTruthMap) -> Result<Metrics> {
    ensure!(
        pred_valid.len() == pred.values.len(),
        "validity mask has {} entries for {} disparities",
        pred_valid.len(),
        pred.values.len()
    );
    let filled = score(&fill_invalid(pred, pred_valid), gt)?;
    Ok(Metrics {
        density: density(pred_valid, gt)?,
        ..filled
    })
}

/// % of ground-truth-valid pixels where the prediction is valid.
pub fn density(pred_valid: &[bool], gt: &GroundTruthMap) -> Result<f64> {
    ensure!(
        pred_valid.len() == gt.valid.len(),
        "validity mask has {} entries, ground truth {}",
        pred_valid.len(),
        gt.valid.len()
    );
    let (mut labeled, mut predicted) = (0usize, 0usize);
    for (&p, &g) in pred_valid.iter().zip(&gt.valid) {
        labeled += g as usize;
        predicted += (g && p) as usize;
    }
    ensure!(labeled > 0, "ground truth has no valid pixel");
    Ok(100.0 * predicted as f64 / labeled as f64)
}

/// Fills invalid pixels row by row: each takes the last valid value to its left; leading
/// invalid pixels take the row's first valid value; a row without any valid pixel becomes 0.
pub fn fill_invalid(pred: &DisparityMap, valid: &[bool]) -> DisparityMap {
    assert_eq!(valid.len(), pred.values.len(), "mask and disparity sizes differ");
    let mut values = pred.values.clone();
    if pred.width > 0 {
        for (row, mask) in values.chunks_exact_mut(pred.width).zip(valid.chunks_exact(pred.width)) {
            fill_row(row, mask);
        }
    }
    DisparityMap { values, ..*pred }
}

fn fill_row(row: &mut [f32], mask: &[bool]) {
    let Some(first) = mask.iter().position(|&v| v) else {
        row.fill(0.0);
        return;
    };
    let mut carried = row[first];
    for (value, &valid) in row.iter_mut().zip(mask) {
        if valid {
            carried = *value;
        } else {
            *value = carried;
        }
    }
}

/// Unweighted mean of each metric over pairs.
pub fn mean_metrics(per_pair: &[Metrics]) -> Result<Metrics> {
    ensure!(!per_pair.is_empty(), "no pairs to average");
    let mean = |get: fn(&Metrics) -> f64| per_pair.iter().map(get).sum::<f64>() / per_pair.len() as f64;
    Ok(Metrics {
        epe: mean(|m| m.epe),
        bad1tok: mean(|m| m.bad1tok),
        bad2: mean(|m| m.bad2),
        density: mean(|m| m.density),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(width: usize, height: usize, values: Vec<f32>) -> DisparityMap {
        DisparityMap { width, height, values }
    }

    #[test]
    fn fill_matches_python_fill_invalid() {
        // probe.fill_invalid(np.arange(12).reshape(3, 4), [[0,1,0,1],[0,0,0,0],[1,0,0,1]]).
        let pred = map(4, 3, (0..12).map(|v| v as f32).collect());
        let valid = [
            false, true, false, true, false, false, false, false, true, false, false, true,
        ];
        let filled = fill_invalid(&pred, &valid);
        assert_eq!(
            filled.values,
            vec![1.0, 1.0, 1.0, 3.0, 0.0, 0.0, 0.0, 0.0, 8.0, 8.0, 8.0, 11.0]
        );
    }

    #[test]
    fn scores_only_ground_truth_valid_pixels() {
        let gt = GroundTruthMap {
            width: 4,
            height: 1,
            disparity: vec![10.0, 10.0, 10.0, 10.0],
            valid: vec![true, true, true, false],
        };
        let pred = map(4, 1, vec![10.0, 13.0, 15.0, 99.0]);
        let m = score(&pred, &gt).unwrap();
        assert!((m.epe - 8.0 / 3.0).abs() < 1e-12);
        assert!((m.bad1tok - 100.0 / 3.0).abs() < 1e-12);
        assert!((m.bad2 - 200.0 / 3.0).abs() < 1e-12);
        assert_eq!(m.density, 100.0);
        // Pixel 1 invalid: filled from pixel 0 (error 0); density counts 2 of 3 labeled pixels.
        let m = score_sparse(&pred, &[true, false, true, false], &gt).unwrap();
        assert!((m.epe - 5.0 / 3.0).abs() < 1e-12);
        assert!((m.density - 200.0 / 3.0).abs() < 1e-12);
        let no_labels = GroundTruthMap {
            valid: vec![false; 4],
            ..gt
        };
        assert!(score(&pred, &no_labels).is_err());
    }

    #[test]
    fn mean_is_unweighted_and_json_is_flat() {
        let a = Metrics {
            epe: 1.0,
            bad1tok: 2.0,
            bad2: 4.0,
            density: 100.0,
        };
        let b = Metrics {
            epe: 3.0,
            density: 50.0,
            ..a
        };
        let m = mean_metrics(&[a, b]).unwrap();
        assert_eq!((m.epe, m.bad1tok, m.density), (2.0, 2.0, 75.0));
        assert_eq!(
            serde_json::to_string(&m).unwrap(),
            r#"{"epe":2.0,"bad1tok":2.0,"bad2":4.0,"density":75.0}"#
        );
        let nan = Metrics { epe: f64::NAN, ..m };
        assert!(serde_json::to_string(&nan).unwrap().starts_with(r#"{"epe":null,"#));
        assert!(mean_metrics(&[]).is_err());
    }
}
