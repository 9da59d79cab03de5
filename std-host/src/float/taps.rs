//! Intermediate tensors ("taps") of an ONNX graph computed by tract: the float values int8
//! calibration chooses its formats from, and the reference the int8 kernels are checked against.

use std::path::Path;

use anyhow::{ensure, Result};
use tract_onnx::prelude::*;

use crate::float::onnx::OnnxModel;

/// An ONNX model computing a chosen list of named values, with one optimised plan per input
/// shape.
pub struct TappedModel {
    model: OnnxModel,
    taps: Vec<String>,
}

impl TappedModel {
    /// Loads `path` computing `taps` (graph outputs or internal value names, e.g. from
    /// [`encoder_block_taps`]); fails naming the first tap the file lacks, or unless the model
    /// takes `inputs` inputs.
    pub fn load(path: &Path, taps: &[String], inputs: usize) -> Result<Self> {
        let model = OnnxModel::load_outputs(path, taps, inputs)?;
        Ok(Self {
            model,
            taps: taps.to_vec(),
        })
    }

    /// The tap names, in the order [`TappedModel::run`] returns them.
    pub fn taps(&self) -> &[String] {
        &self.taps
    }

    /// Runs the model on `inputs` (f32 tensors); returns every tap's shape and row-major
    /// values, in the order of [`TappedModel::taps`].
    pub fn run(&mut self, inputs: Vec<Tensor>) -> Result<Vec<(Vec<usize>, Vec<f32>)>> {
        let outputs = self.model.run_outputs(inputs)?;
        ensure!(
            outputs.len() == self.taps.len(),
            "{} computed {} tensors for {} taps",
            self.model.path().display(),
            outputs.len(),
            self.taps.len()
        );
        Ok(outputs)
    }
}

/// The calibration taps of one encoder block, in the order of [`BlockTap::ALL`]. Shapes are
/// for a band of `n` tokens (token rows x fused columns), `h` = 4 heads of `hd` = 32 channels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BlockTap {
    /// First LayerNorm output, (1, n, 128).
    Norm1,
    /// Queries after RoPE, (1, h, n, hd).
    Queries,
    /// Keys after RoPE, (1, h, n, hd).
    Keys,
    /// Values, (1, h, n, hd).
    Values,
    /// Attention output with the heads concatenated, before `proj`, (1, n, 128).
    Attended,
    /// Residual stream after attention, (1, n, 128).
    Middle,
    /// `fc1` output = GELU input, (1, n, 480).
    Fc1,
    /// GELU output = `fc2` input, (1, n, 480).
    Gelu,
    /// Block output (residual stream), (1, n, 128); equals the graph output `block{b}`.
    Output,
}

impl BlockTap {
    /// Every tap, in the order [`encoder_block_taps`] lists them.
    pub const ALL: [BlockTap; 9] = [
        BlockTap::Norm1,
        BlockTap::Queries,
        BlockTap::Keys,
        BlockTap::Values,
        BlockTap::Attended,
        BlockTap::Middle,
        BlockTap::Fc1,
        BlockTap::Gelu,
        BlockTap::Output,
    ];

    /// The ONNX value name of this tap in block `block`: the names the torch exporter gives
    /// `train/bino_train/model.py` (checked against `tests/fixtures/encoder_random_seed0.onnx`).
    pub fn name(self, block: usize) -> String {
        let suffix = match self {
            BlockTap::Norm1 => "norm1/LayerNormalization_output_0",
            BlockTap::Queries => "attn/Add_output_0",
            BlockTap::Keys => "attn/Add_1_output_0",
            BlockTap::Values => "attn/Gather_5_output_0",
            BlockTap::Attended => "attn/Reshape_1_output_0",
            BlockTap::Middle => "Add_output_0",
            BlockTap::Fc1 => "fc1/Add_output_0",
            BlockTap::Gelu => "Mul_1_output_0",
            BlockTap::Output => "Add_2_output_0",
        };
        format!("/blocks.{block}/{suffix}")
    }

    /// The tap's shape for a band of `tokens` tokens in the paper's encoder.
    pub fn shape(self, tokens: usize) -> Vec<usize> {
        use bino_core::config::{DIM, HEADS, HEAD_DIM, MLP_HIDDEN};
        match self {
            BlockTap::Queries | BlockTap::Keys | BlockTap::Values => vec![1, HEADS, tokens, HEAD_DIM],
            BlockTap::Fc1 | BlockTap::Gelu => vec![1, tokens, MLP_HIDDEN],
            BlockTap::Norm1 | BlockTap::Attended | BlockTap::Middle | BlockTap::Output => vec![1, tokens, DIM],
        }
    }
}

/// The ONNX value names of block `block`'s taps, in the order of [`BlockTap::ALL`]:
/// LN1 output, queries, keys, values, attention output, residual after attention, fc1 output,
/// GELU output, block output.
pub fn encoder_block_taps(block: usize) -> Vec<String> {
    BlockTap::ALL.iter().map(|tap| tap.name(block)).collect()
}

/// One tapped run of the random-init encoder fixture on a random 48x160 pair, shared by the
/// tests of this crate (the plan takes seconds to build).
#[cfg(test)]
pub(crate) mod fixture_run {
    use std::path::PathBuf;
    use std::sync::OnceLock;

    use super::*;

    /// Band height and width of the run.
    pub const HEIGHT: usize = 48;
    /// Band width in pixels.
    pub const WIDTH: usize = 160;
    /// Tokens in the band: 12 rows x 80 fused columns.
    pub const TOKENS: usize = (HEIGHT / 4) * (WIDTH / 2);

    /// The encoder fixture with intermediate outputs.
    pub fn encoder_fixture() -> PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/fixtures/encoder_random_seed0.onnx")
    }

    /// Inputs and taps of the run.
    pub struct Block0Run {
        /// Left view, (3, 48, 160) row-major.
        pub left: Vec<f32>,
        /// Right view, (3, 48, 160) row-major.
        pub right: Vec<f32>,
        names: Vec<String>,
        outputs: Vec<(Vec<usize>, Vec<f32>)>,
    }

    impl Block0Run {
        /// Shape and values of tap `name`.
        pub fn get(&self, name: &str) -> (&[usize], &[f32]) {
            let at = self
                .names
                .iter()
                .position(|n| n == name)
                .unwrap_or_else(|| panic!("no tap {name}"));
            (&self.outputs[at].0, &self.outputs[at].1)
        }
    }

    /// Block 0's taps plus `embed`, `block0`, the qkv output and the fc2 output.
    pub fn block0_run() -> &'static Block0Run {
        static RUN: OnceLock<Block0Run> = OnceLock::new();
        RUN.get_or_init(|| {
            let mut names = encoder_block_taps(0);
            names.extend(
                [
                    "embed",
                    "block0",
                    "/blocks.0/attn/qkv/Add_output_0",
                    "/blocks.0/fc2/Add_output_0",
                ]
                .map(String::from),
            );
            let mut model = TappedModel::load(&encoder_fixture(), &names, 2).unwrap();
            let left = random_pixels(1, 3 * HEIGHT * WIDTH);
            let right = random_pixels(2, 3 * HEIGHT * WIDTH);
            let tensor = |pixels: &[f32]| -> Tensor {
                tract_ndarray::Array4::from_shape_vec((1, 3, HEIGHT, WIDTH), pixels.to_vec())
                    .unwrap()
                    .into()
            };
            let outputs = model.run(vec![tensor(&left), tensor(&right)]).unwrap();
            Block0Run {
                left,
                right,
                names,
                outputs,
            }
        })
    }

    /// `count` pseudo-random values in [0, 1) (xorshift; deterministic per seed).
    pub fn random_pixels(seed: u64, count: usize) -> Vec<f32> {
        let mut state = 0x9E37_79B9_7F4A_7C15u64 ^ seed;
        (0..count)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state >> 40) as f32 / (1u64 << 24) as f32
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::fixture_run::{block0_run, encoder_fixture, TOKENS};
    use super::*;

    // erf by Abramowitz & Stegun 7.1.26 (|error| < 1.5e-7): std has no stable erf.
    fn erf(x: f64) -> f64 {
        let t = 1.0 / (1.0 + 0.327_591_1 * x.abs());
        let poly =
            t * (0.254_829_592 + t * (-0.284_496_736 + t * (1.421_413_741 + t * (-1.453_152_027 + t * 1.061_405_429))));
        (1.0 - poly * (-x * x).exp()).copysign(x)
    }

    fn gelu(x: f32) -> f32 {
        let x = x as f64;
        (0.5 * x * (1.0 + erf(x / std::f64::consts::SQRT_2))) as f32
    }

    fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
        assert_eq!(a.len(), b.len());
        a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
    }

    #[test]
    fn block_taps_have_the_documented_shapes() {
        let run = block0_run();
        for tap in BlockTap::ALL {
            let (shape, values) = run.get(&tap.name(0));
            assert_eq!(shape, tap.shape(TOKENS), "{tap:?}");
            assert_eq!(values.len(), shape.iter().product::<usize>());
            assert!(values.iter().all(|v| v.is_finite()), "{tap:?}");
        }
    }

    #[test]
    fn block_output_tap_is_the_block0_output() {
        let run = block0_run();
        let (grid_shape, grid) = run.get("block0");
        assert_eq!(grid_shape, [1, 12, 80, 128]);
        let (_, tap) = run.get(&BlockTap::Output.name(0));
        assert_eq!(tap, grid);
    }

    #[test]
    fn block_output_is_middle_plus_fc2() {
        let run = block0_run();
        let (_, middle) = run.get(&BlockTap::Middle.name(0));
        let (_, fc2) = run.get("/blocks.0/fc2/Add_output_0");
        let (_, output) = run.get(&BlockTap::Output.name(0));
        let sum: Vec<f32> = middle.iter().zip(fc2).map(|(m, f)| m + f).collect();
        assert!(max_abs_diff(&sum, output) < 1e-5);
    }

    #[test]
    fn gelu_tap_is_erf_gelu_of_fc1() {
        let run = block0_run();
        let (_, fc1) = run.get(&BlockTap::Fc1.name(0));
        let (_, gelu_tap) = run.get(&BlockTap::Gelu.name(0));
        let ours: Vec<f32> = fc1.iter().map(|&x| gelu(x)).collect();
        assert!(max_abs_diff(&ours, gelu_tap) < 1e-5);
        // The random init still spreads fc1 over both signs, so the check is not trivial.
        assert!(fc1.iter().any(|&x| x < -0.5) && fc1.iter().any(|&x| x > 0.5));
    }

    #[test]
    fn block_tap_names_follow_the_documented_order() {
        let names = encoder_block_taps(3);
        assert_eq!(names.len(), BlockTap::ALL.len());
        assert_eq!(names[0], "/blocks.3/norm1/LayerNormalization_output_0");
        assert_eq!(names[3], "/blocks.3/attn/Gather_5_output_0");
        assert_eq!(names[8], "/blocks.3/Add_2_output_0");
    }

    #[test]
    fn a_missing_tap_is_named_in_the_error() {
        let taps = vec!["block0".to_string(), "/blocks.0/no_such_value".to_string()];
        let err = TappedModel::load(&encoder_fixture(), &taps, 2)
            .err()
            .expect("must fail");
        assert!(format!("{err:#}").contains("/blocks.0/no_such_value"), "{err:#}");
    }
}
