//! The no-linkage readout (`probe.similarity_volume` + `probe.wta_subtoken`): each left cell
//! is compared with right cells 0 .. `max_cols` - 1 patch columns to its left by cosine
//! similarity, and the best candidate is refined by a parabola through its neighbours.

use anyhow::{ensure, Result};

use super::DisparityMap;
use crate::float::reference::FeatureMap;

/// Disparity candidates (patch columns) the Python probe uses by default.
pub const DEFAULT_MAX_COLS: usize = 10;

// `F.normalize`'s floor on the norm, so that zero descriptors give zero similarities.
const NORM_EPS: f32 = 1e-8;

/// Cosine similarities `(rows, cols, candidates)`: entry (r, p, k) compares left cell (r, p)
/// with right cell (r, p - k); `-inf` where p - k < 0.
#[derive(Debug, Clone, PartialEq)]
pub struct SimilarityVolume {
    /// Token rows.
    pub rows: usize,
    /// Patch columns.
    pub cols: usize,
    /// Disparity candidates per cell (`max_cols`, even when larger than `cols`).
    pub candidates: usize,
    /// `rows * cols * candidates` similarities, candidates fastest.
    pub values: Vec<f32>,
}

impl SimilarityVolume {
    /// The `candidates` similarities of left cell (`row`, `col`).
    pub fn at(&self, row: usize, col: usize) -> &[f32] {
        let start = (row * self.cols + col) * self.candidates;
        &self.values[start..start + self.candidates]
    }
}

/// Builds the cosine similarity volume of two descriptor maps of the same shape.
pub fn similarity_volume(left: &FeatureMap, right: &FeatureMap, max_cols: usize) -> Result<SimilarityVolume> {
    ensure!(
        (left.rows, left.cols, left.dim) == (right.rows, right.cols, right.dim),
        "descriptor maps differ in shape: left {}x{}x{}, right {}x{}x{}",
        left.rows,
        left.cols,
        left.dim,
        right.rows,
        right.cols,
        right.dim
    );
    ensure!(max_cols > 0, "max_cols must be at least 1");
    let (dl, dr) = (normalized(left), normalized(right));
    let (rows, cols, dim) = (left.rows, left.cols, left.dim);
    let mut values = vec![f32::NEG_INFINITY; rows * cols * max_cols];
    for r in 0..rows {
        for p in 0..cols {
            let a = &dl[(r * cols + p) * dim..][..dim];
            let out = &mut values[(r * cols + p) * max_cols..][..max_cols];
            for (k, slot) in out.iter_mut().enumerate().take(p + 1) {
                let b = &dr[(r * cols + p - k) * dim..][..dim];
                *slot = a.iter().zip(b).map(|(x, y)| x * y).sum();
            }
        }
    }
    Ok(SimilarityVolume {
        rows,
        cols,
        candidates: max_cols,
        values,
    })
}

// Each descriptor divided by max(|d|, eps), as `F.normalize` does.
fn normalized(map: &FeatureMap) -> Vec<f32> {
    let mut data = map.data.clone();
    if map.dim == 0 {
        return data;
    }
    for d in data.chunks_exact_mut(map.dim) {
        let norm = d.iter().map(|v| v * v).sum::<f32>().sqrt().max(NORM_EPS);
        d.iter_mut().for_each(|v| *v /= norm);
    }
    data
}

/// Winner-take-all disparity in patch columns (`rows` x `cols`) with the parabola sub-token
/// step clamped to [-0.5, 0.5]. The step is only taken when the winner has two finite
/// neighbours inside the candidate range and the parabola opens downwards.
pub fn wta_subtoken(volume: &SimilarityVolume) -> DisparityMap {
    let mut values = Vec::with_capacity(volume.rows * volume.cols);
    for r in 0..volume.rows {
        for p in 0..volume.cols {
            values.push(refine(volume.at(r, p)));
        }
    }
    DisparityMap {
        width: volume.cols,
        height: volume.rows,
        values,
    }
}

// One cell: argmax (first maximum; NaN wins, as in torch.argmax) plus the parabola step.
fn refine(sims: &[f32]) -> f32 {
    let mut best = 0;
    for (k, &s) in sims.iter().enumerate().skip(1) {
        let current = sims[best];
        if !current.is_nan() && (s > current || s.is_nan()) {
            best = k;
        }
    }
    let last = sims.len() - 1;
    let at = sims[best];
    let left = sims[best.saturating_sub(1)];
    let right = sims[(best + 1).min(last)];
    let inside = best > 0 && best < last && left.is_finite() && right.is_finite();
    let denom = left - 2.0 * at + right;
    let step = if inside && denom < 0.0 {
        (left - right) / (2.0 * denom)
    } else {
        0.0
    };
    best as f32 + step.clamp(-0.5, 0.5)
}

/// The whole readout: descriptor maps of the left and right views -> token-grid disparity in
/// patch columns.
pub fn no_linkage_disparity(left: &FeatureMap, right: &FeatureMap, max_cols: usize) -> Result<DisparityMap> {
    Ok(wta_subtoken(&similarity_volume(left, right, max_cols)?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn excluded_candidates_are_negative_infinity() {
        let map = FeatureMap {
            rows: 1,
            cols: 3,
            dim: 2,
            data: vec![1.0, 0.0, 0.0, 2.0, 3.0, 3.0],
        };
        let v = similarity_volume(&map, &map, 4).unwrap();
        assert_eq!(v.at(0, 0)[0], 1.0);
        assert!(v.at(0, 0)[1..].iter().all(|s| *s == f32::NEG_INFINITY));
        assert_eq!(v.at(0, 1)[1], 0.0, "orthogonal descriptors");
        assert!((v.at(0, 2)[2] - 0.5f32.sqrt()).abs() < 1e-6);
        assert_eq!(v.at(0, 2)[3], f32::NEG_INFINITY);
    }

    #[test]
    fn parabola_step_follows_the_python_rules() {
        // Symmetric neighbours: no step; lopsided: vertex of the parabola.
        assert_eq!(refine(&[0.0, 1.0, 0.0]), 1.0);
        assert!((refine(&[0.5, 1.0, 0.0]) - (1.0 - 0.5 / 3.0)).abs() < 1e-6);
        // Winner at either end of the range or next to an excluded candidate: no step.
        assert_eq!(refine(&[1.0, 0.9, 0.0]), 0.0);
        assert_eq!(refine(&[0.2, 0.9, 1.0]), 2.0);
        assert_eq!(refine(&[0.2, 1.0, f32::NEG_INFINITY]), 1.0);
        // Ties go to the first maximum; the step then reaches the clamp.
        assert_eq!(refine(&[0.5, 1.0, 1.0, 0.2]), 1.5);
        assert_eq!(refine(&[1.0, 1.0, 1.0, 1.0]), 0.0);
        // A NaN wins the argmax (torch.argmax) and takes no step.
        assert_eq!(refine(&[0.5, f32::NAN, 1.0, 0.2]), 1.0);
    }

    #[test]
    fn rejects_mismatched_maps() {
        let a = FeatureMap {
            rows: 1,
            cols: 2,
            dim: 1,
            data: vec![1.0, 1.0],
        };
        let b = FeatureMap {
            cols: 1,
            data: vec![1.0],
            ..a.clone()
        };
        assert!(similarity_volume(&a, &b, 4).is_err());
        assert!(similarity_volume(&a, &a, 0).is_err());
    }
}
