//! Float twins of the core's streaming readouts, over the float similarity volume of the
//! tract descriptors: SGM on the same four paths (`bino_core::sgm`), the right view's
//! readout from the reindexed volume and the left-right check (`bino_core::lr`). Int8 and
//! float then differ only by the arithmetic, so `bino eval` can compare them readout by readout.

use bino_core::sgm::{Penalties, COST_EXCLUDED, COST_ONE};

use super::nolink::SimilarityVolume;
use super::DisparityMap;

/// The right view's similarities: right cell `q` at disparity `k` is left cell `q + k` at `k`
/// (`-inf` where `q + k` leaves the row), as `bino_core::lr::right_view_costs` builds it.
pub fn right_view(volume: &SimilarityVolume) -> SimilarityVolume {
    let (cols, d) = (volume.cols, volume.candidates);
    let mut values = vec![f32::NEG_INFINITY; volume.values.len()];
    for r in 0..volume.rows {
        for q in 0..cols {
            for k in 0..d {
                if q + k < cols {
                    values[(r * cols + q) * d + k] = volume.at(r, q + k)[k];
                }
            }
        }
    }
    SimilarityVolume {
        values,
        ..volume.clone()
    }
}

/// SGM over the costs `1 - cos` (2 outside the view) with `penalties` in the core's cost units
/// (4096 = cosine 1): left to right, right to left, top to bottom and the top-left diagonal,
/// summed, then the first minimum and its parabola step (clamped to half a column). With
/// `guide` (each cell's mean grey level, `rows x cols`, [`crate::int8::guide_map`]) and `penalties.edge > 0`
/// the jump penalty between two cells is the core's [`Penalties::jump`] of theirs.
pub fn sgm(volume: &SimilarityVolume, penalties: Penalties, guide: Option<&[u8]>) -> DisparityMap {
    let (rows, cols, d) = (volume.rows, volume.cols, volume.candidates);
    let unit = COST_ONE as f32;
    let p1 = penalties.p1 as f32 / unit;
    let at = |r: usize, p: usize| guide.and_then(|g| g.get(r * cols + p)).copied().unwrap_or(0);
    let p2 = |r: usize, p: usize, from_r: usize, q: usize| penalties.jump(at(r, p), at(from_r, q)) as f32 / unit;
    let excluded = COST_EXCLUDED as f32 / unit;
    let cost = |r: usize, p: usize| -> Vec<f32> {
        volume
            .at(r, p)
            .iter()
            .map(|&s| if s.is_finite() { 1.0 - s } else { excluded })
            .collect()
    };
    let mut vertical = vec![0f32; cols * d];
    let mut diagonal = vec![0f32; cols * d];
    let mut values = Vec::with_capacity(rows * cols);
    for r in 0..rows {
        let costs: Vec<Vec<f32>> = (0..cols).map(|p| cost(r, p)).collect();
        let mut sum = vec![0f32; cols * d];
        for order in [false, true] {
            let mut running: Vec<f32> = Vec::new();
            for i in 0..cols {
                let p = if order { cols - 1 - i } else { i };
                running = if i == 0 {
                    costs[p].clone()
                } else {
                    let from = if order { p + 1 } else { p - 1 };
                    step(&costs[p], &running, p1, p2(r, p, r, from))
                };
                add(&mut sum[p * d..(p + 1) * d], &running);
            }
        }
        // Columns right to left so the diagonal reads the previous row's column p - 1.
        for p in (0..cols).rev() {
            let cell = p * d..(p + 1) * d;
            let down = if r == 0 {
                costs[p].clone()
            } else {
                step(&costs[p], &vertical[cell.clone()], p1, p2(r, p, r - 1, p))
            };
            vertical[cell.clone()].copy_from_slice(&down);
            add(&mut sum[cell.clone()], &down);
            let diag = if r == 0 || p == 0 {
                costs[p].clone()
            } else {
                step(&costs[p], &diagonal[(p - 1) * d..p * d], p1, p2(r, p, r - 1, p - 1))
            };
            diagonal[cell.clone()].copy_from_slice(&diag);
            add(&mut sum[cell], &diag);
        }
        values.extend(sum.chunks_exact(d).map(refine_min));
    }
    DisparityMap {
        width: cols,
        height: rows,
        values,
    }
}

/// 1 where the left disparity lands on a right cell (`p - round(d)`) that reads within
/// `max_diff` columns of it.
pub fn consistent(left: &DisparityMap, right: &DisparityMap, max_diff: f32) -> Vec<bool> {
    let cols = left.width.max(1);
    left.values
        .iter()
        .enumerate()
        .map(|(i, &d)| {
            let (row, p) = (i / cols, i % cols);
            let q = p as i64 - d.round() as i64;
            q >= 0
                && right
                    .values
                    .get(row * cols + q as usize)
                    .is_some_and(|&r| (r - d).abs() <= max_diff)
        })
        .collect()
}

fn step(cost: &[f32], prev: &[f32], p1: f32, p2: f32) -> Vec<f32> {
    let min_prev = prev.iter().copied().fold(f32::INFINITY, f32::min);
    (0..cost.len())
        .map(|k| {
            let mut best = prev[k];
            if k > 0 {
                best = best.min(prev[k - 1] + p1);
            }
            if k + 1 < prev.len() {
                best = best.min(prev[k + 1] + p1);
            }
            cost[k] + best.min(min_prev + p2) - min_prev
        })
        .collect()
}

fn add(sum: &mut [f32], path: &[f32]) {
    sum.iter_mut().zip(path).for_each(|(s, v)| *s += v);
}

fn refine_min(costs: &[f32]) -> f32 {
    let mut best = 0;
    for (k, &c) in costs.iter().enumerate() {
        if c < costs[best] {
            best = k;
        }
    }
    let step = match (best.checked_sub(1).map(|k| costs[k]), costs.get(best + 1)) {
        (Some(l), Some(&r)) => {
            let denom = l - 2.0 * costs[best] + r;
            if denom > 0.0 {
                ((l - r) / (2.0 * denom)).clamp(-0.5, 0.5)
            } else {
                0.0
            }
        }
        _ => 0.0,
    };
    best as f32 + step
}

#[cfg(test)]
mod tests {
    use super::*;

    fn volume(cols: usize, d: usize, values: Vec<f32>) -> SimilarityVolume {
        SimilarityVolume {
            rows: values.len() / (cols * d),
            cols,
            candidates: d,
            values,
        }
    }

    #[test]
    fn right_view_reindexes_like_the_core() {
        let ninf = f32::NEG_INFINITY;
        let v = volume(3, 2, vec![0.1, ninf, 0.2, 0.21, 0.3, 0.31]);
        assert_eq!(right_view(&v).values, [0.1, 0.21, 0.2, 0.31, 0.3, ninf]);
    }

    #[test]
    fn sgm_smooths_a_weak_outlier_and_keeps_clear_minima() {
        // 3 rows x 4 cells x 3 candidates; everyone prefers candidate 0 strongly except a weak
        // outlier in the middle (cells as similarities: cost = 1 - s).
        let strong = [1.0, 0.8, 0.8];
        let mut values: Vec<f32> = (0..12).flat_map(|_| strong).collect();
        values[(4 + 2) * 3..(4 + 3) * 3].copy_from_slice(&[0.985, 0.8, 1.0]);
        let out = sgm(
            &volume(4, 3, values),
            Penalties {
                p1: 100,
                p2: 400,
                edge: 0,
            },
            None,
        );
        assert!(out.values.iter().all(|&d| d.round() == 0.0), "{:?}", out.values);
    }

    #[test]
    fn sgm_agrees_with_the_integer_stream_on_a_clear_volume() {
        // Costs that are exact in both arithmetics: the same winners.
        let cols = 6;
        let d = 4;
        let values: Vec<f32> = (0..2 * cols)
            .flat_map(|i| (0..d).map(move |k| if k == (i % cols) % d { 1.0 } else { 0.5 }))
            .collect();
        let float = sgm(
            &volume(cols, d, values.clone()),
            Penalties { p1: 8, p2: 32, edge: 0 },
            None,
        );
        let (mut v, mut g, mut s) = (vec![0u16; cols * d], vec![0u16; cols * d], vec![0u32; cols * d]);
        let mut stream =
            bino_core::sgm::SgmStream::new(cols, d, Penalties { p1: 8, p2: 32, edge: 0 }, &mut v, &mut g, &mut s)
                .unwrap();
        let mut out = vec![0u16; cols];
        for (r, row) in values.chunks_exact(cols * d).enumerate() {
            let costs: Vec<u16> = row.iter().map(|&s| ((1.0 - s) * 4096.0) as u16).collect();
            stream.push_row(&costs, &mut out).unwrap();
            for (p, &q8) in out.iter().enumerate() {
                assert_eq!(
                    (q8 as f32 / 256.0).round(),
                    float.values[r * cols + p].round(),
                    "row {r} cell {p}"
                );
            }
        }
    }

    #[test]
    fn guided_sgm_agrees_with_the_guided_integer_stream() {
        // One row: cells 0-2 want candidate 0, cells 3-5 weakly prefer 2; a bright edge between
        // cells 2 and 3 lets both arithmetics jump there (and only the guide does).
        let (cols, d) = (6, 3);
        let want0 = [1.0f32, 0.8, 0.8];
        let weak2 = [0.99f32, 0.8, 1.0];
        let values: Vec<f32> = (0..cols).flat_map(|p| if p < 3 { want0 } else { weak2 }).collect();
        let guide = [30u8, 30, 30, 200, 200, 200];
        let pen = Penalties {
            p1: 100,
            p2: 1600,
            edge: 8,
        };
        let float = sgm(&volume(cols, d, values.clone()), pen, Some(&guide));
        let plain = sgm(&volume(cols, d, values.clone()), pen, None);
        let (mut v, mut g, mut s, mut prev) = (
            vec![0u16; cols * d],
            vec![0u16; cols * d],
            vec![0u32; cols * d],
            vec![0u8; cols],
        );
        let mut stream = bino_core::sgm::SgmStream::new(cols, d, pen, &mut v, &mut g, &mut s)
            .unwrap()
            .with_guide(&mut prev)
            .unwrap();
        let costs: Vec<u16> = values.iter().map(|&s| ((1.0 - s) * 4096.0).round() as u16).collect();
        let mut out = vec![0u16; cols];
        stream.push_row_guided(&costs, &guide, &mut out).unwrap();
        let int: Vec<f32> = out.iter().map(|&q8| (q8 as f32 / 256.0).round()).collect();
        let float: Vec<f32> = float.values.iter().map(|v| v.round()).collect();
        assert_eq!(int, float);
        assert_eq!(float, [0.0, 0.0, 0.0, 2.0, 2.0, 2.0]);
        assert!(plain.values.iter().all(|v| v.round() == 0.0), "{:?}", plain.values);
    }

    #[test]
    fn consistency_follows_the_core_rule() {
        let left = DisparityMap {
            width: 5,
            height: 1,
            values: vec![0.0, 1.0, 2.0, 2.0, 2.0],
        };
        let right = DisparityMap {
            values: vec![2.0, 2.0, 2.0, 0.0, 0.0],
            ..left.clone()
        };
        assert_eq!(consistent(&left, &right, 0.5), [false, false, true, true, true]);
    }
}
