//! The float heads run in Rust on their ONNX parameters ([`FloatHead`]), for any number of
//! disparity candidates.
//!
//! The ONNX exports bake their candidate count (12) into the graph, but no weight depends on
//! it: the correlation and the 3D convolutions slide along the disparity axis. Views wider than
//! the heads' training crops (w320) reach further disparities, and the int8 engine searches more
//! candidates there ([`crate::readout::head_candidates`]); this forward pass is their float
//! twin. At the exported count it matches tract on the ONNX graph (tested below).

use anyhow::{ensure, Result};
use bino_core::model::ids::HeadKind;

use crate::band_maps::{per_band, BandedRows, ROW_REACH};
use crate::compare::head::FloatHeadOutput;
use crate::float::head::{FloatConv3d, FloatHead};
use crate::float::reference::{FeatureMap, TokenBands};
use crate::float::weights::FloatLinear;

/// Per-cell logits `(cells, candidates)` from candidate-major `(candidates, cells)`: with
/// cells row-major, each token row's logits lie together, so rows can be cut and stitched.
fn cell_major(candidate_major: &[f32], candidates: usize) -> Vec<f32> {
    let cells = candidate_major.len() / candidates.max(1);
    let mut out = vec![0.0f32; cells * candidates];
    for (k, plane) in candidate_major.chunks_exact(cells.max(1)).enumerate() {
        for (cell, &l) in plane.iter().enumerate() {
            out[cell * candidates + k] = l;
        }
    }
    out
}

/// Candidate-major logits from per-cell ones ([`cell_major`]'s inverse).
fn candidate_major(cell_major: &[f32], candidates: usize) -> Vec<f32> {
    let cells = cell_major.len() / candidates.max(1);
    let mut out = vec![0.0f32; cells * candidates];
    for (cell, logits) in cell_major.chunks_exact(candidates.max(1)).enumerate() {
        for (k, &l) in logits.iter().enumerate() {
            out[k * cells + cell] = l;
        }
    }
    out
}

/// Subtracted from the logits of candidates outside the right view (`MASKED_LOGIT` of
/// `train/bino_train/head.py`).
const MASKED_LOGIT: f32 = 1e4;

/// Lanes of the dot products (independent accumulators, so the compiler vectorises them).
const LANES: usize = 8;

impl FloatHead {
    /// Runs the head on its two input maps (the export head: D(L), D(R); the native head: the
    /// even and odd phase maps of one pass on the pair) over `candidates` disparities.
    /// Logits are candidate-major `(candidates, rows, cols)` as the ONNX export lays them out.
    pub fn forward(&self, first: &FeatureMap, second: &FeatureMap, candidates: usize) -> Result<FloatHeadOutput> {
        ensure!(
            (first.rows, first.cols, first.dim) == (second.rows, second.cols, second.dim),
            "the head's input maps differ in shape"
        );
        ensure!(candidates > 0, "the head needs at least one disparity candidate");
        let (rows, cols) = (first.rows, first.cols);
        let (f_left, f_right) = self.features(first, second)?;
        let volume = self.correlation(&f_left, &f_right, (rows, cols, candidates));
        let shape = Volume { rows, cols, candidates };
        let mut x = conv3d(&volume, shape, &self.stem);
        x.iter_mut().for_each(|v| *v = v.max(0.0));
        for layer in &self.middle {
            let y = conv3d(&x, shape, layer);
            x.iter_mut().zip(&y).for_each(|(a, b)| *a += b.max(0.0));
        }
        let out = conv3d(&x, shape, &self.out);
        let cells = rows * cols;
        let mut logits = vec![0.0f32; candidates * cells];
        let mut disparity = vec![0.0f32; cells];
        for cell in 0..cells {
            let p = cell % cols;
            let cell_logits: Vec<f32> = (0..candidates)
                .map(|d| {
                    let masked = if d <= p { 0.0 } else { MASKED_LOGIT };
                    out[cell * candidates + d] - masked
                })
                .collect();
            let max = cell_logits.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            let weights: Vec<f32> = cell_logits.iter().map(|l| (l - max).exp()).collect();
            let total: f32 = weights.iter().sum();
            disparity[cell] = weights.iter().enumerate().map(|(d, w)| d as f32 * w).sum::<f32>() / total;
            for (d, l) in cell_logits.into_iter().enumerate() {
                logits[d * cells + cell] = l;
            }
        }
        Ok(FloatHeadOutput { logits, disparity })
    }

    /// The native head as the core's native pathway runs it: on each band's own rows within
    /// [`ROW_REACH`] of those it keeps, the kept rows stitched into one output (one band: the
    /// head on the whole grid).
    pub fn forward_banded(&self, tokens: &TokenBands, candidates: usize) -> Result<FloatHeadOutput> {
        let (fused_cols, dim) = (tokens.cols, tokens.dim);
        self.banded(&tokens.rows, fused_cols / 2, candidates, |values, rows| {
            let grid = FeatureMap {
                rows,
                cols: fused_cols,
                dim,
                data: values.to_vec(),
            };
            grid.phase_maps()
        })
    }

    /// The export head as the core's export pathway runs it: on each band's own rows of both
    /// descriptor maps ([`crate::float::reference::ReferenceEncoder::descriptor_bands`]) within
    /// [`ROW_REACH`] of those it keeps, the kept rows stitched into one output (one band: the
    /// head on the whole maps).
    pub fn forward_pair_banded(
        &self,
        first: &TokenBands,
        second: &TokenBands,
        candidates: usize,
    ) -> Result<FloatHeadOutput> {
        let (cols, dim) = (first.cols, first.dim);
        ensure!(
            (second.cols, second.dim) == (cols, dim),
            "the head's input maps differ in shape"
        );
        let row_len = cols * dim;
        self.banded(&first.rows.beside(&second.rows)?, cols, candidates, |values, rows| {
            let (a, b): (Vec<&[f32]>, Vec<&[f32]>) =
                values.chunks_exact(2 * row_len).map(|r| r.split_at(row_len)).unzip();
            let map = |data: Vec<&[f32]>| FeatureMap {
                rows,
                cols,
                dim,
                data: data.concat(),
            };
            (map(a), map(b))
        })
    }

    /// The head on each band's rows within [`ROW_REACH`] of those it keeps, its two input maps
    /// of `cols` columns made from a band's rows by `inputs(values, rows)`; the kept rows
    /// stitched into one output.
    fn banded(
        &self,
        rows: &BandedRows<f32>,
        cols: usize,
        candidates: usize,
        inputs: impl Fn(&[f32], usize) -> (FeatureMap, FeatureMap),
    ) -> Result<FloatHeadOutput> {
        let planes = per_band(rows, ROW_REACH, &[cols, candidates * cols], |values, rows| {
            let (first, second) = inputs(values, rows);
            let out = self.forward(&first, &second, candidates)?;
            Ok(vec![out.disparity, cell_major(&out.logits, candidates)])
        })?;
        let [disparity, logits] = <[Vec<f32>; 2]>::try_from(planes)
            .map_err(|p| anyhow::anyhow!("the banded head gave {} planes", p.len()))?;
        Ok(FloatHeadOutput {
            logits: candidate_major(&logits, candidates),
            disparity,
        })
    }

    /// (f_L, f_R), `rows * cols * proj` each: the shared projection of each LayerNorm-ed view
    /// (export), or `P_L`, `P_R` of the LayerNorm-ed pair feature `u = [a, b]` (native).
    fn features(&self, first: &FeatureMap, second: &FeatureMap) -> Result<(Vec<f32>, Vec<f32>)> {
        let norm = |cell: &[f32]| layer_norm(cell, &self.norm_weight, &self.norm_bias, self.ln_eps);
        match (self.kind, &self.proj_right) {
            (HeadKind::Export, _) => {
                let project = |map: &FeatureMap| -> Vec<f32> {
                    map.data
                        .chunks_exact(map.dim)
                        .flat_map(|cell| linear(&self.proj, &norm(cell)))
                        .collect()
                };
                Ok((project(first), project(second)))
            }
            (HeadKind::Native, Some(right)) => {
                let (mut f_left, mut f_right) = (Vec::new(), Vec::new());
                for (a, b) in first
                    .data
                    .chunks_exact(first.dim)
                    .zip(second.data.chunks_exact(second.dim))
                {
                    let u = norm(&[a, b].concat());
                    f_left.extend(linear(&self.proj, &u));
                    f_right.extend(linear(right, &u));
                }
                Ok((f_left, f_right))
            }
            (HeadKind::Native, None) => anyhow::bail!("the native head has no right projection"),
        }
    }

    /// The groupwise correlation volume, `[row][col][candidate][group]`: group means of
    /// f_L[p] * f_R[p - k], zero where p - k < 0.
    fn correlation(
        &self,
        f_left: &[f32],
        f_right: &[f32],
        (rows, cols, candidates): (usize, usize, usize),
    ) -> Vec<f32> {
        let proj = self.proj.out_features;
        let groups = self.groups.max(1);
        let per_group = proj / groups;
        let mut volume = vec![0.0f32; rows * cols * candidates * groups];
        for r in 0..rows {
            for p in 0..cols {
                let left = &f_left[(r * cols + p) * proj..][..proj];
                for d in 0..candidates.min(p + 1) {
                    let right = &f_right[(r * cols + p - d) * proj..][..proj];
                    let out = &mut volume[((r * cols + p) * candidates + d) * groups..][..groups];
                    for (g, o) in out.iter_mut().enumerate() {
                        let span = g * per_group..(g + 1) * per_group;
                        let sum: f32 = left[span.clone()].iter().zip(&right[span]).map(|(a, b)| a * b).sum();
                        *o = sum / per_group as f32;
                    }
                }
            }
        }
        volume
    }
}

/// A head volume's extent; values are laid out `[row][col][candidate][channel]`.
#[derive(Clone, Copy)]
struct Volume {
    rows: usize,
    cols: usize,
    candidates: usize,
}

/// A 3x3x3 convolution (padding 1) over (candidate, row, column); `x` has `conv.in_channels`
/// channels per voxel, the result `conv.out_channels`.
fn conv3d(x: &[f32], shape: Volume, conv: &FloatConv3d) -> Vec<f32> {
    let (cin, cout) = (conv.in_channels, conv.out_channels);
    let taps = 27 * cin;
    // Weights as [out][kd][kr][kc][in]: the order `gather` lays the inputs out in.
    let mut weight = vec![0.0f32; cout * taps];
    for o in 0..cout {
        for i in 0..cin {
            for k in 0..27 {
                weight[o * taps + k * cin + i] = conv.weight[(o * cin + i) * 27 + k];
            }
        }
    }
    let Volume { rows, cols, candidates } = shape;
    let mut out = vec![0.0f32; rows * cols * candidates * cout];
    let mut gathered = vec![0.0f32; taps];
    for r in 0..rows {
        for p in 0..cols {
            for d in 0..candidates {
                let mut k = 0;
                for dd in [d.wrapping_sub(1), d, d + 1] {
                    for rr in [r.wrapping_sub(1), r, r + 1] {
                        for pp in [p.wrapping_sub(1), p, p + 1] {
                            let dst = &mut gathered[k * cin..(k + 1) * cin];
                            if dd < candidates && rr < rows && pp < cols {
                                dst.copy_from_slice(&x[((rr * cols + pp) * candidates + dd) * cin..][..cin]);
                            } else {
                                dst.fill(0.0);
                            }
                            k += 1;
                        }
                    }
                }
                let voxel = &mut out[((r * cols + p) * candidates + d) * cout..][..cout];
                for (o, v) in voxel.iter_mut().enumerate() {
                    *v = conv.bias[o] + dot(&weight[o * taps..(o + 1) * taps], &gathered);
                }
            }
        }
    }
    out
}

/// Dot product in [`LANES`] independent sums.
fn dot(a: &[f32], b: &[f32]) -> f32 {
    let mut lanes = [0.0f32; LANES];
    let (a_chunks, b_chunks) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let tail: f32 = a_chunks
        .remainder()
        .iter()
        .zip(b_chunks.remainder())
        .map(|(x, y)| x * y)
        .sum();
    for (x, y) in a_chunks.zip(b_chunks) {
        for l in 0..LANES {
            lanes[l] += x[l] * y[l];
        }
    }
    lanes.iter().sum::<f32>() + tail
}

fn layer_norm(x: &[f32], weight: &[f32], bias: &[f32], eps: f32) -> Vec<f32> {
    let n = x.len().max(1) as f32;
    let mean = x.iter().sum::<f32>() / n;
    let var = x.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / n;
    let inv = 1.0 / (var + eps).sqrt();
    x.iter()
        .zip(weight.iter().zip(bias))
        .map(|(v, (w, b))| (v - mean) * inv * w + b)
        .collect()
}

fn linear(layer: &FloatLinear, x: &[f32]) -> Vec<f32> {
    layer
        .weight
        .chunks_exact(layer.in_features)
        .zip(&layer.bias)
        .map(|(row, b)| b + dot(row, x))
        .collect()
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;
    use crate::compare::head::FloatHeadRunner;
    use crate::data::rng::SplitMix64;

    fn fixture(name: &str) -> PathBuf {
        PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../tests/fixtures")
            .join(name)
    }

    fn random_map(rng: &mut SplitMix64, rows: usize, cols: usize, dim: usize) -> FeatureMap {
        let data = (0..rows * cols * dim).map(|_| rng.unit() as f32 * 2.0 - 1.0).collect();
        FeatureMap { rows, cols, dim, data }
    }

    /// At the exported candidate count the Rust forward pass is tract on the ONNX graph.
    #[test]
    fn the_forward_pass_matches_tract_on_both_fixture_heads() {
        for name in ["head_random_seed0.onnx", "native_head_random_seed0.onnx"] {
            let path = fixture(name);
            let head = FloatHead::from_onnx(&path).unwrap();
            let mut rng = SplitMix64::new(7);
            let dim = head.norm_weight.len() / if head.kind == HeadKind::Native { 2 } else { 1 };
            let (a, b) = (random_map(&mut rng, 5, 14, dim), random_map(&mut rng, 5, 14, dim));
            let ours = head.forward(&a, &b, head.max_disp).unwrap();
            let tract = FloatHeadRunner::load(&path).unwrap().run(&a, &b).unwrap();
            let worst = |x: &[f32], y: &[f32]| x.iter().zip(y).map(|(p, q)| (p - q).abs()).fold(0.0f32, f32::max);
            assert_eq!(ours.logits.len(), tract.logits.len(), "{name}");
            assert!(worst(&ours.disparity, &tract.disparity) < 1e-3, "{name}");
            // Masked logits are about -1e4: compare the valid ones.
            let valid: Vec<(f32, f32)> = ours
                .logits
                .iter()
                .zip(&tract.logits)
                .filter(|(p, _)| **p > -1e3)
                .map(|(p, q)| (*p, *q))
                .collect();
            let (x, y): (Vec<f32>, Vec<f32>) = valid.into_iter().unzip();
            assert!(worst(&x, &y) < 1e-3, "{name}: logits differ by {}", worst(&x, &y));
        }
    }

    /// More candidates change the output (they reach further) but not the logits of the
    /// candidates the disparity edge's zero padding cannot reach through six convolutions.
    #[test]
    fn more_candidates_extend_the_search_and_keep_the_near_logits() {
        let head = FloatHead::from_onnx(&fixture("head_random_seed0.onnx")).unwrap();
        let mut rng = SplitMix64::new(3);
        let (rows, cols) = (4, 24);
        let (a, b) = (
            random_map(&mut rng, rows, cols, 128),
            random_map(&mut rng, rows, cols, 128),
        );
        let d12 = head.forward(&a, &b, 12).unwrap();
        let d16 = head.forward(&a, &b, 16).unwrap();
        assert_eq!(d16.logits.len(), 16 * rows * cols);
        let cells = rows * cols;
        for d in 0..4 {
            for cell in 0..cells {
                let (x, y) = (d12.logits[d * cells + cell], d16.logits[d * cells + cell]);
                if x > -1e3 {
                    assert!((x - y).abs() < 1e-3, "candidate {d} cell {cell}: {x} vs {y}");
                }
            }
        }
        assert!(d16.disparity.iter().zip(&d12.disparity).any(|(x, y)| x != y));
    }
}
