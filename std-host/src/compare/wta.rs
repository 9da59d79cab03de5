//! Statistics of similarity volumes for `bino compare`: the integer winner-take-all disparity,
//! how often two volumes agree on it, the similarity lost where they do not, and the margin of
//! the winners.

use anyhow::{ensure, Result};

use crate::eval::SimilarityVolume;

/// Integer winner-take-all disparity of every cell: the first candidate with the largest
/// similarity (candidates outside the right view are `-inf` in the volume, so never win).
pub fn wta_integer(volume: &SimilarityVolume) -> Vec<usize> {
    volume
        .values
        .chunks_exact(volume.candidates.max(1))
        .map(|sims| {
            sims.iter()
                .enumerate()
                .fold(
                    (0, f32::NEG_INFINITY),
                    |best, (k, &s)| if s > best.1 { (k, s) } else { best },
                )
                .0
        })
        .collect()
}

/// % of cells where two similarity volumes of the same shape have the same integer WTA winner.
pub fn wta_agreement(a: &SimilarityVolume, b: &SimilarityVolume) -> Result<f64> {
    ensure!(
        (a.rows, a.cols, a.candidates) == (b.rows, b.cols, b.candidates),
        "similarity volumes differ in shape"
    );
    let (wa, wb) = (wta_integer(a), wta_integer(b));
    ensure!(!wa.is_empty(), "empty similarity volume");
    let same = wa.iter().zip(&wb).filter(|(x, y)| x == y).count();
    Ok(100.0 * same as f64 / wa.len() as f64)
}

/// Mean float similarity lost where the int8 WTA winner differs from the float one: `float`
/// at its own winner minus `float` at the int8 winner (0 when they always agree).
pub fn wta_flip_loss(float: &SimilarityVolume, int8: &SimilarityVolume) -> Result<f64> {
    ensure!(
        (float.rows, float.cols, float.candidates) == (int8.rows, int8.cols, int8.candidates),
        "similarity volumes differ in shape"
    );
    let (wf, wi) = (wta_integer(float), wta_integer(int8));
    let sims = float.values.chunks_exact(float.candidates.max(1));
    let (mut lost, mut flips) = (0.0f64, 0usize);
    for ((s, &a), &b) in sims.zip(&wf).zip(&wi) {
        if a != b && s[b].is_finite() {
            lost += (s[a] - s[b]) as f64;
            flips += 1;
        }
    }
    Ok(if flips == 0 { 0.0 } else { lost / flips as f64 })
}

/// Median over cells with two or more finite candidates of best minus second-best similarity.
pub fn top2_gap_median(volume: &SimilarityVolume) -> f64 {
    let mut gaps: Vec<f32> = volume
        .values
        .chunks_exact(volume.candidates.max(1))
        .filter_map(|sims| {
            let mut top = [f32::NEG_INFINITY; 2];
            for &s in sims.iter().filter(|s| s.is_finite()) {
                if s > top[0] {
                    top = [s, top[0]];
                } else if s > top[1] {
                    top[1] = s;
                }
            }
            top[1].is_finite().then(|| top[0] - top[1])
        })
        .collect();
    if gaps.is_empty() {
        return 0.0;
    }
    gaps.sort_by(f32::total_cmp);
    gaps[gaps.len() / 2] as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn volume(values: Vec<f32>, candidates: usize) -> SimilarityVolume {
        SimilarityVolume {
            rows: 1,
            cols: values.len() / candidates,
            candidates,
            values,
        }
    }

    #[test]
    fn wta_takes_the_first_maximum_and_skips_excluded_candidates() {
        let ninf = f32::NEG_INFINITY;
        let v = volume(vec![0.5, ninf, ninf, 0.1, 0.9, ninf, 0.3, 0.3, 0.2], 3);
        assert_eq!(wta_integer(&v), [0, 1, 0]);
        let w = volume(vec![0.5, ninf, ninf, 0.95, 0.9, ninf, 0.3, 0.3, 0.2], 3);
        assert!((wta_agreement(&v, &w).unwrap() - 200.0 / 3.0).abs() < 1e-9);
        // The one flip (cell 1: float picks 0.9, the other volume's winner has 0.1 there).
        assert!((wta_flip_loss(&v, &w).unwrap() - 0.8).abs() < 1e-6);
        assert_eq!(wta_flip_loss(&v, &v).unwrap(), 0.0);
        // Gaps: cell 0 has one finite candidate (skipped), cell 1: 0.8, cell 2: 0.0.
        let gap = top2_gap_median(&v);
        assert!((gap - 0.8).abs() < 1e-6, "{gap}");
    }
}
