//! The float reference: the exported ONNX encoder executed by `tract-onnx`.
//!
//! The ONNX graph takes one band (at most 48 rows); taller views go through the same
//! overlapping band plan as the int8 engine ([`bino_core::band::BandPlan`]), so reference and
//! int8 outputs are comparable row for row.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{ensure, Context, Result};
use bino_core::band::BandPlan;
use bino_core::config::{check_view_size, DIM, IN_CHANS, PATCH_H};
use tract_onnx::prelude::*;

use crate::profile::View;

type Runnable = Arc<TypedRunnableModel>;

/// A token grid or descriptor map: `rows x cols x DIM`, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureMap {
    /// Token rows (view rows / 4).
    pub rows: usize,
    /// Fused columns (token grid) or patch columns (descriptor map).
    pub cols: usize,
    /// `rows * cols * DIM` values.
    pub data: Vec<f32>,
}

impl FeatureMap {
    /// The `DIM` channels at (`row`, `col`).
    pub fn at(&self, row: usize, col: usize) -> &[f32] {
        let start = (row * self.cols + col) * DIM;
        &self.data[start..start + DIM]
    }

    /// Averages the two phase tokens (fused columns 2p, 2p + 1) of each patch column:
    /// the descriptor map of a token grid computed on (I, I).
    pub fn phase_average(&self) -> FeatureMap {
        let cols = self.cols / 2;
        let mut data = Vec::with_capacity(self.rows * cols * DIM);
        for r in 0..self.rows {
            for p in 0..cols {
                let (a, b) = (self.at(r, 2 * p), self.at(r, 2 * p + 1));
                data.extend(a.iter().zip(b).map(|(x, y)| 0.5 * (x + y)));
            }
        }
        FeatureMap {
            rows: self.rows,
            cols,
            data,
        }
    }
}

/// The ONNX encoder, with one optimised plan per band shape it has seen.
pub struct ReferenceEncoder {
    path: PathBuf,
    model: InferenceModel,
    plans: HashMap<(usize, usize), Runnable>,
}

impl ReferenceEncoder {
    /// Loads an encoder exported by `python -m bino_train.export`, computing its `tokens` output.
    pub fn load(path: &Path) -> Result<Self> {
        Self::load_stage(path, "tokens")
    }

    /// Loads an encoder computing output `stage` instead: `embed` or `block0`..`block6` exist
    /// in exports made with `--intermediates`; all share the token-grid layout.
    pub fn load_stage(path: &Path, stage: &str) -> Result<Self> {
        ensure!(
            path.is_file(),
            "ONNX model {} does not exist (export one with `python -m bino_train.export`)",
            path.display()
        );
        let mut model = tract_onnx::onnx()
            .model_for_path(path)
            .with_context(|| format!("cannot load ONNX model {}", path.display()))?;
        // Exports with --intermediates have more outputs; run only the one asked for.
        let output = model
            .find_outlet_label(stage)
            .with_context(|| format!("ONNX model {} has no output named `{stage}`", path.display()))?;
        model.select_output_outlets(&[output])?;
        ensure!(
            model.inputs.len() == 2,
            "ONNX model {} must take two inputs (left, right)",
            path.display()
        );
        Ok(Self {
            path: path.to_path_buf(),
            model,
            plans: HashMap::new(),
        })
    }

    /// The file the model came from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The de-positioned fused token grid of a pair: (H/4) x (W/2) x DIM.
    pub fn tokens(&mut self, left: &View, right: &View) -> Result<FeatureMap> {
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
        let mut data = vec![0.0f32; token_rows * fused_cols * DIM];
        for band in plan.iter() {
            let rows = band.start * PATCH_H..(band.start + band.rows) * PATCH_H;
            let l = band_tensor(left, rows.clone());
            let r = band_tensor(right, rows);
            let out = self.run_band(band.rows * PATCH_H, left.width, l, r)?;
            let row_len = fused_cols * DIM;
            let from = (band.keep_from - band.start) * row_len;
            let to = (band.keep_to - band.start) * row_len;
            data[band.keep_from * row_len..band.keep_to * row_len].copy_from_slice(&out[from..to]);
        }
        Ok(FeatureMap {
            rows: token_rows,
            cols: fused_cols,
            data,
        })
    }

    /// The descriptor map of one view: the encoder on (I, I), phase-averaged; (H/4) x (W/4) x DIM.
    pub fn descriptors(&mut self, view: &View) -> Result<FeatureMap> {
        Ok(self.tokens(view, view)?.phase_average())
    }

    fn run_band(&mut self, height: usize, width: usize, left: Tensor, right: Tensor) -> Result<Vec<f32>> {
        let plan = match self.plans.get(&(height, width)) {
            Some(plan) => plan,
            None => {
                let plan = self.optimise(height, width)?;
                self.plans.entry((height, width)).or_insert(plan)
            }
        };
        let outputs = plan
            .run(tvec!(left.into(), right.into()))
            .with_context(|| format!("running {} on a {width}x{height} band", self.path.display()))?;
        let tokens = outputs[0].to_plain_array_view::<f32>()?;
        let expected = [1, height / PATCH_H, 2 * width / PATCH_H, DIM];
        ensure!(
            tokens.shape() == expected,
            "ONNX output has shape {:?}, expected {expected:?}",
            tokens.shape()
        );
        Ok(tokens.iter().copied().collect())
    }

    fn optimise(&self, height: usize, width: usize) -> Result<Runnable> {
        let fact = f32::fact([1, IN_CHANS, height, width]);
        self.model
            .clone()
            .with_input_fact(0, fact.clone().into())?
            .with_input_fact(1, fact.into())?
            .into_optimized()
            .and_then(|m| m.into_runnable())
            .with_context(|| format!("cannot plan {} for a {width}x{height} band", self.path.display()))
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
