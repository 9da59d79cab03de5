//! The float reference: the exported ONNX encoder executed by `tract-onnx`.
//!
//! The ONNX graph takes one band (at most 48 rows); taller views go through the same
//! overlapping band plan as the int8 engine ([`bino_core::band::BandPlan`]), so reference and
//! int8 outputs are comparable row for row.

use std::path::Path;

use anyhow::{ensure, Context, Result};
use bino_core::band::BandPlan;
use bino_core::config::{check_view_size, IN_CHANS, PATCH_H};
use tract_onnx::prelude::*;

use crate::band_maps::BandedRows;
use crate::data::profile::View;
use crate::float::onnx::OnnxModel;

/// A feature grid as the bands computed them: a pair's fused token grid
/// ([`ReferenceEncoder::token_bands`]) or a view's descriptor map
/// ([`ReferenceEncoder::descriptor_bands`]).
#[derive(Debug, Clone, PartialEq)]
pub struct TokenBands {
    /// Fused columns (token grid) or patch columns (descriptor map).
    pub cols: usize,
    /// Channels per token.
    pub dim: usize,
    /// Every band's rows, `cols x dim` values a row.
    pub rows: BandedRows<f32>,
}

impl TokenBands {
    /// The whole grid, each row from the band that keeps it.
    pub fn assemble(&self) -> FeatureMap {
        FeatureMap {
            rows: self.rows.rows,
            cols: self.cols,
            dim: self.dim,
            data: self.rows.assemble(),
        }
    }

    /// Each band's [`FeatureMap::phase_average`]: the descriptor map of a token grid computed
    /// on (I, I), band by band.
    pub fn phase_average(&self) -> TokenBands {
        let bands = (self.rows.bands.iter())
            .map(|(band, values)| {
                let grid = FeatureMap {
                    rows: band.rows,
                    cols: self.cols,
                    dim: self.dim,
                    data: values.clone(),
                };
                (*band, grid.phase_average().data)
            })
            .collect();
        let cols = self.cols / 2;
        TokenBands {
            cols,
            dim: self.dim,
            rows: BandedRows {
                rows: self.rows.rows,
                row_len: cols * self.dim,
                bands,
            },
        }
    }

    /// Each band's [`FeatureMap::mirrored`]: the grid of the horizontally mirrored view.
    pub fn mirrored(&self) -> TokenBands {
        TokenBands {
            rows: self.rows.mirrored(self.dim),
            ..self.clone()
        }
    }
}

/// A token grid or descriptor map: `rows x cols x dim`, row-major (`dim` is 128 for the
/// paper's encoder; smaller test configurations have fewer channels).
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureMap {
    /// Token rows (view rows / 4).
    pub rows: usize,
    /// Fused columns (token grid) or patch columns (descriptor map).
    pub cols: usize,
    /// Channels per token.
    pub dim: usize,
    /// `rows * cols * dim` values.
    pub data: Vec<f32>,
}

impl FeatureMap {
    /// The map with each row's columns in reverse order (a mirrored view's map).
    pub fn mirrored(&self) -> FeatureMap {
        let mut data = Vec::with_capacity(self.data.len());
        for row in self.data.chunks_exact((self.cols * self.dim).max(1)) {
            for cell in row.chunks_exact(self.dim.max(1)).rev() {
                data.extend_from_slice(cell);
            }
        }
        FeatureMap { data, ..*self }
    }

    /// The `dim` channels at (`row`, `col`).
    pub fn at(&self, row: usize, col: usize) -> &[f32] {
        let start = (row * self.cols + col) * self.dim;
        &self.data[start..start + self.dim]
    }

    /// The two phase maps of a token grid: (even fused columns 2p, odd fused columns 2p + 1),
    /// each `rows x cols/2 x dim` — the native head's inputs `phase_even`, `phase_odd`.
    pub fn phase_maps(&self) -> (FeatureMap, FeatureMap) {
        let cols = self.cols / 2;
        let (mut even, mut odd) = (Vec::with_capacity(self.rows * cols * self.dim), Vec::new());
        odd.reserve(even.capacity());
        for r in 0..self.rows {
            for p in 0..cols {
                even.extend_from_slice(self.at(r, 2 * p));
                odd.extend_from_slice(self.at(r, 2 * p + 1));
            }
        }
        let map = |data| FeatureMap {
            rows: self.rows,
            cols,
            dim: self.dim,
            data,
        };
        (map(even), map(odd))
    }

    /// Averages the two phase tokens (fused columns 2p, 2p + 1) of each patch column:
    /// the descriptor map of a token grid computed on (I, I).
    pub fn phase_average(&self) -> FeatureMap {
        let cols = self.cols / 2;
        let mut data = Vec::with_capacity(self.rows * cols * self.dim);
        for r in 0..self.rows {
            for p in 0..cols {
                let (a, b) = (self.at(r, 2 * p), self.at(r, 2 * p + 1));
                data.extend(a.iter().zip(b).map(|(x, y)| 0.5 * (x + y)));
            }
        }
        FeatureMap {
            rows: self.rows,
            cols,
            dim: self.dim,
            data,
        }
    }
}

/// The ONNX encoder, with one optimised plan per band shape it has seen.
pub struct ReferenceEncoder {
    model: OnnxModel,
}

impl ReferenceEncoder {
    /// Loads an encoder exported by `python -m bino_train.export`, computing its `tokens` output.
    pub fn load(path: &Path) -> Result<Self> {
        Self::load_stage(path, "tokens")
    }

    /// Loads an encoder computing output `stage` instead: `embed` or `block0`..`block6` exist
    /// in exports made with `--intermediates`; all share the token-grid layout.
    pub fn load_stage(path: &Path, stage: &str) -> Result<Self> {
        let model = OnnxModel::load(path, stage, 2)
            .context("the encoder is exported by `python -m bino_train.export` (inputs left, right)")?;
        Ok(Self { model })
    }

    /// The file the model came from.
    pub fn path(&self) -> &Path {
        self.model.path()
    }

    /// The de-positioned fused token grid of a pair: (H/4) x (W/2) x dim, each row from the
    /// band that keeps it.
    pub fn tokens(&mut self, left: &View, right: &View) -> Result<FeatureMap> {
        Ok(self.token_bands(left, right)?.assemble())
    }

    /// [`ReferenceEncoder::tokens`] as the bands computed them, overlaps included.
    pub fn token_bands(&mut self, left: &View, right: &View) -> Result<TokenBands> {
        ensure!(
            (left.width, left.height) == (right.width, right.height),
            "left view is {}x{} but right view is {}x{}",
            left.width,
            left.height,
            right.width,
            right.height
        );
        let (token_rows, patch_cols) = check_view_size(left.height, left.width).map_err(anyhow::Error::msg)?;
        let fused_cols = 2 * patch_cols;
        let plan = BandPlan::new(token_rows).map_err(anyhow::Error::msg)?;
        let (mut bands, mut dim) = (Vec::with_capacity(plan.len()), 0);
        for band in plan.iter() {
            let rows = band.start * PATCH_H..(band.start + band.rows) * PATCH_H;
            let l = band_tensor(left, rows.clone());
            let r = band_tensor(right, rows);
            let (band_dim, out) = self.run_band(band.rows * PATCH_H, left.width, l, r)?;
            ensure!(
                dim == 0 || band_dim == dim,
                "bands differ in channels: {dim} and {band_dim}"
            );
            dim = band_dim;
            bands.push((band, out));
        }
        Ok(TokenBands {
            cols: fused_cols,
            dim,
            rows: BandedRows {
                rows: token_rows,
                row_len: fused_cols * dim,
                bands,
            },
        })
    }

    /// The descriptor map of one view: the encoder on (I, I), phase-averaged; (H/4) x (W/4) x
    /// dim, each row from the band that keeps it.
    pub fn descriptors(&mut self, view: &View) -> Result<FeatureMap> {
        Ok(self.descriptor_bands(view)?.assemble())
    }

    /// [`ReferenceEncoder::descriptors`] as the bands computed them, overlaps included: what
    /// the export head reads band by band ([`crate::float::head::FloatHead::forward_pair_banded`]).
    pub fn descriptor_bands(&mut self, view: &View) -> Result<TokenBands> {
        Ok(self.token_bands(view, view)?.phase_average())
    }

    // Runs one band; returns the channel count and the (rows, fused cols, dim) values.
    fn run_band(&mut self, height: usize, width: usize, left: Tensor, right: Tensor) -> Result<(usize, Vec<f32>)> {
        let (shape, values) = self.model.run(vec![left, right])?;
        let grid = [1, height / PATCH_H, 2 * width / PATCH_H];
        ensure!(
            shape.len() == 4 && shape[..3] == grid && shape[3] > 0,
            "ONNX output has shape {shape:?}, expected {grid:?} x channels"
        );
        Ok((shape[3], values))
    }
}

// Rows `rows` of a view as a (1, 3, h, W) tensor, the gray channel replicated.
fn band_tensor(view: &View, rows: std::ops::Range<usize>) -> Tensor {
    let h = rows.len();
    let start = rows.start;
    tract_ndarray::Array4::from_shape_fn((1, IN_CHANS, h, view.width), |(_, _, y, x)| {
        view.pixels[(start + y) * view.width + x]
    })
    .into()
}
