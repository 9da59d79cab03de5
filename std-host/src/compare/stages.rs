//! The float encoder's residual stream at every stage the int8 engine shows its probe
//! ([`Stage`]), for one band on (I, I), and the cosine measure the comparison uses.

use std::path::Path;

use anyhow::{bail, ensure, Result};
use bino_core::config::{DEPTH, IN_CHANS};
use bino_core::model::probe::Stage;
use tract_onnx::prelude::{tract_ndarray, Tensor};

use crate::float::taps::{BlockTap, TappedModel};

/// Stages compared per band: the embedding, then attention and MLP halves of every block.
/// A stage's index in this order is its residual format ([`Stage::residual_format`]).
pub const STAGE_COUNT: usize = 1 + 2 * DEPTH;

/// Short name of the stage with residual format `format`: `embed`, `attn{b}`, `block{b}`.
pub fn stage_label(format: usize) -> String {
    match format {
        0 => "embed".to_string(),
        f if f % 2 == 1 => format!("attn{}", f / 2),
        f => format!("block{}", f / 2 - 1),
    }
}

/// The stage with residual format `format`.
pub fn stage_of_format(format: usize) -> Stage {
    match format {
        0 => Stage::Embed,
        f if f % 2 == 1 => Stage::Attention(f / 2),
        f => Stage::Block(f / 2 - 1),
    }
}

/// Where the embedding stage is read from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EmbedSource {
    /// The `embed` graph output of an export made with `--intermediates`.
    GraphOutput,
    /// The internal value `/Add_output_0` (patch plus row embedding) of a plain export.
    InternalValue,
}

impl EmbedSource {
    /// The ONNX value name.
    pub fn name(self) -> &'static str {
        match self {
            EmbedSource::GraphOutput => "embed",
            // The value the `--intermediates` export renames to `embed` (checked on a plain
            // export of the seed-0 encoder).
            EmbedSource::InternalValue => "/Add_output_0",
        }
    }
}

/// The ONNX value names of every stage, in residual-format order. Blocks use the internal
/// names of `taps.rs`, which exist with and without `--intermediates`.
pub fn stage_value_names(embed: EmbedSource) -> Vec<String> {
    (0..STAGE_COUNT)
        .map(|format| match stage_of_format(format) {
            Stage::Embed => embed.name().to_string(),
            Stage::Attention(b) => BlockTap::Middle.name(b),
            Stage::Block(b) => BlockTap::Output.name(b),
        })
        .collect()
}

/// The float encoder computing every stage's residual stream.
pub struct FloatStages {
    model: TappedModel,
    embed: EmbedSource,
}

impl FloatStages {
    /// Loads the encoder `path`, reading the embedding from the `embed` output when the file
    /// has one and from its internal value otherwise.
    pub fn load(path: &Path) -> Result<Self> {
        ensure!(path.is_file(), "ONNX model {} does not exist", path.display());
        let graph = TappedModel::load(path, &stage_value_names(EmbedSource::GraphOutput), 2);
        let (model, embed) = match graph {
            Ok(model) => (model, EmbedSource::GraphOutput),
            Err(graph_err) => match TappedModel::load(path, &stage_value_names(EmbedSource::InternalValue), 2) {
                Ok(model) => (model, EmbedSource::InternalValue),
                Err(internal_err) => bail!(
                    "cannot read the stage outputs of {}: with the `embed` output: {graph_err:#}; \
                     with its internal value: {internal_err:#}",
                    path.display()
                ),
            },
        };
        Ok(Self { model, embed })
    }

    /// Where the embedding stage comes from.
    pub fn embed_source(&self) -> EmbedSource {
        self.embed
    }

    /// Runs one band of gray pixels in [0, 1] (`height x width`, row-major) as (I, I);
    /// returns every stage's `tokens x DIM` values, indexed by residual format.
    pub fn run_band(&mut self, pixels: &[f32], width: usize, height: usize) -> Result<Vec<Vec<f32>>> {
        ensure!(
            pixels.len() == width * height,
            "band has {} pixels, expected {width}x{height}",
            pixels.len()
        );
        let tensor: Tensor =
            tract_ndarray::Array4::from_shape_fn((1, IN_CHANS, height, width), |(_, _, y, x)| pixels[y * width + x])
                .into();
        let outputs = self.model.run(vec![tensor.clone(), tensor])?;
        Ok(outputs.into_iter().map(|(_, values)| values).collect())
    }
}

/// Cosine similarity of two vectors, accumulated in f64; 0 when either is zero.
pub fn cosine(a: &[f32], b: &[f32]) -> f64 {
    let (mut dot, mut na, mut nb) = (0.0f64, 0.0f64, 0.0f64);
    for (&x, &y) in a.iter().zip(b) {
        let (x, y) = (x as f64, y as f64);
        dot += x * y;
        na += x * x;
        nb += y * y;
    }
    dot / (na * nb).sqrt().max(1e-30)
}

/// Mean over tokens of the per-token cosine of two `tokens x dim` arrays.
pub fn mean_token_cosine(a: &[f32], b: &[f32], dim: usize) -> Result<f64> {
    ensure!(
        a.len() == b.len() && dim > 0 && a.len().is_multiple_of(dim) && !a.is_empty(),
        "cannot compare {} values with {} values as tokens of {dim}",
        a.len(),
        b.len()
    );
    let tokens = a.len() / dim;
    let sum: f64 = a
        .chunks_exact(dim)
        .zip(b.chunks_exact(dim))
        .map(|(x, y)| cosine(x, y))
        .sum();
    Ok(sum / tokens as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stage_order_is_the_residual_format() {
        for format in 0..STAGE_COUNT {
            assert_eq!(stage_of_format(format).residual_format(), format);
        }
        let labels: Vec<String> = (0..5).map(stage_label).collect();
        assert_eq!(labels, ["embed", "attn0", "block0", "attn1", "block1"]);
        assert_eq!(stage_label(STAGE_COUNT - 1), "block6");
    }

    #[test]
    fn value_names_follow_the_stages() {
        let names = stage_value_names(EmbedSource::InternalValue);
        assert_eq!(names[0], "/Add_output_0");
        assert_eq!(names[1], "/blocks.0/Add_output_0");
        assert_eq!(names[2], "/blocks.0/Add_2_output_0");
        assert_eq!(names[STAGE_COUNT - 1], "/blocks.6/Add_2_output_0");
    }

    #[test]
    fn cosine_per_token() {
        let a = [1.0, 0.0, 1.0, 1.0];
        let b = [2.0, 0.0, -1.0, -1.0];
        assert!((mean_token_cosine(&a, &b, 2).unwrap() - 0.0).abs() < 1e-12);
        assert_eq!(cosine(&[0.0, 0.0], &[1.0, 0.0]), 0.0);
        assert!(mean_token_cosine(&a, &b[..2], 2).is_err());
    }
}
