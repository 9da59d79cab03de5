//! The float shared stereo head (`python -m bino_train.head --checkpoint ... --out`), run by
//! tract on a pair of descriptor maps. The head is fully convolutional, so it takes the whole
//! (banded) descriptor map of any height at once.

use std::path::Path;

use anyhow::{ensure, Context, Result};
use tract_onnx::prelude::*;

use crate::float::onnx::OnnxModel;
use crate::float::reference::FeatureMap;

/// Disparity on the token grid, in patch columns (multiply by 4 for view pixels).
#[derive(Debug, Clone, PartialEq)]
pub struct TokenDisparity {
    /// Token rows.
    pub rows: usize,
    /// Patch columns.
    pub cols: usize,
    /// `rows * cols` disparities; left patch column p matches right column p - d.
    pub data: Vec<f32>,
}

/// The ONNX shared head.
pub struct ReferenceHead {
    model: OnnxModel,
}

impl ReferenceHead {
    /// Loads a head export (inputs `desc_left`, `desc_right`; output `disparity`).
    pub fn load(path: &Path) -> Result<Self> {
        let model = OnnxModel::load(path, "disparity", 2)
            .context("the head is exported by `python -m bino_train.head` (inputs desc_left, desc_right)")?;
        Ok(Self { model })
    }

    /// Disparity of the left descriptor map against the right one.
    pub fn disparity(&mut self, left: &FeatureMap, right: &FeatureMap) -> Result<TokenDisparity> {
        ensure!(
            (left.rows, left.cols, left.dim) == (right.rows, right.cols, right.dim),
            "descriptor maps differ: left {}x{}x{}, right {}x{}x{}",
            left.rows,
            left.cols,
            left.dim,
            right.rows,
            right.cols,
            right.dim
        );
        let tensor = |m: &FeatureMap| -> Result<Tensor> {
            Ok(tract_ndarray::Array4::from_shape_vec((1, m.rows, m.cols, m.dim), m.data.clone())?.into())
        };
        let (shape, data) = self.model.run(vec![tensor(left)?, tensor(right)?])?;
        ensure!(
            shape == [1, left.rows, left.cols],
            "head output `disparity` has shape {shape:?}, expected [1, {}, {}]",
            left.rows,
            left.cols
        );
        Ok(TokenDisparity {
            rows: left.rows,
            cols: left.cols,
            data,
        })
    }
}
