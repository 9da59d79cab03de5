//! The float encoder's parameters, read from its ONNX export (`python -m bino_train.export`):
//! what post-training quantisation turns into int8.
//!
//! Layouts follow PyTorch (`train/bino_train/model.py`): linear weights are `out x in`
//! row-major (the ONNX MatMul initializers are `in x out` and are transposed here), the patch
//! embedding is `(128, 3, 4, 4)`.

use std::path::Path;

use anyhow::{ensure, Context, Result};
use bino_core::config::{BAND_TOKEN_ROWS, DEPTH, DIM, HEADS, IN_CHANS, MLP_HIDDEN, PATCH_H, PATCH_W};

use crate::float::onnx_params::OnnxParams;

/// An `nn.Linear`: `y = weight · x + bias`.
#[derive(Debug, Clone, PartialEq)]
pub struct FloatLinear {
    /// Output features (weight rows).
    pub out_features: usize,
    /// Input features (weight columns).
    pub in_features: usize,
    /// `out_features x in_features`, row-major (PyTorch layout).
    pub weight: Vec<f32>,
    /// `out_features` biases.
    pub bias: Vec<f32>,
}

impl FloatLinear {
    /// Reads the linear layer the torch exporter writes as nodes `{scope}/MatMul` (weight
    /// `in x out`) and `{scope}/Add` (bias), checking its size is `in_features -> out_features`.
    pub fn from_onnx_scope(params: &OnnxParams, scope: &str, in_features: usize, out_features: usize) -> Result<Self> {
        let matmul = format!("{scope}/MatMul");
        let add = format!("{scope}/Add");
        let onnx_weight = params.node_tensor(&matmul, 1, &[in_features, out_features], &format!("{scope} weight"))?;
        let product = params
            .node(&matmul)?
            .output
            .first()
            .with_context(|| format!("node `{matmul}` of {} has no output", params.source()))?;
        let add_inputs = &params.node(&add)?.input;
        ensure!(
            add_inputs.len() == 2 && add_inputs.contains(product),
            "node `{add}` of {} does not add a bias to `{matmul}`",
            params.source()
        );
        // The exporter puts the bias first, but either order is a valid Add.
        let bias_name = add_inputs.iter().find(|name| *name != product).unwrap_or(product);
        let bias = params.tensor(bias_name, &[out_features], &format!("{scope} bias"))?;
        let mut weight = vec![0.0; out_features * in_features];
        for (i, row) in onnx_weight.chunks_exact(out_features).enumerate() {
            for (o, &w) in row.iter().enumerate() {
                weight[o * in_features + i] = w;
            }
        }
        Ok(Self {
            out_features,
            in_features,
            weight,
            bias,
        })
    }

    /// `weight · x + bias` (accumulated in f64, so it serves as a reference).
    pub fn forward(&self, x: &[f32]) -> Vec<f32> {
        assert_eq!(x.len(), self.in_features, "input length");
        self.weight
            .chunks_exact(self.in_features)
            .zip(&self.bias)
            .map(|(row, &b)| (row.iter().zip(x).map(|(&w, &v)| w as f64 * v as f64).sum::<f64>() + b as f64) as f32)
            .collect()
    }
}

/// One pre-norm transformer block: `x + proj(attn(ln1(x)))`, then `x + fc2(gelu(fc1(ln2(x))))`.
#[derive(Debug, Clone, PartialEq)]
pub struct FloatBlock {
    /// First LayerNorm's scale (128).
    pub norm1_weight: Vec<f32>,
    /// First LayerNorm's shift (128).
    pub norm1_bias: Vec<f32>,
    /// Query/key/value projection, 128 -> 384 (queries, keys, values; heads within each).
    pub qkv: FloatLinear,
    /// Attention output projection, 128 -> 128.
    pub proj: FloatLinear,
    /// Second LayerNorm's scale (128).
    pub norm2_weight: Vec<f32>,
    /// Second LayerNorm's shift (128).
    pub norm2_bias: Vec<f32>,
    /// MLP input layer, 128 -> 480.
    pub fc1: FloatLinear,
    /// MLP output layer, 480 -> 128.
    pub fc2: FloatLinear,
    /// LayerNorm epsilon (both norms), from the nodes' `epsilon` attribute.
    pub ln_eps: f32,
}

/// The float encoder: patch embedding, row embedding and the blocks.
#[derive(Debug, Clone, PartialEq)]
pub struct FloatEncoder {
    /// Patch embedding kernel `(128, 3, 4, 4)` row-major, over the fused (interleaved) image.
    pub patch_weight: Vec<f32>,
    /// Patch embedding bias (128).
    pub patch_bias: Vec<f32>,
    /// Row embedding `(12, 128)`: added to token row r after the patch embedding.
    pub row_embed: Vec<f32>,
    /// The 7 blocks.
    pub blocks: Vec<FloatBlock>,
    /// RoPE frequency base, from the `bino.config` metadata the exporter stamps.
    pub rope_base: f32,
    /// Token rows either side of its own that a query attends to (`attention_rows` in
    /// `bino.config`); `None`: the whole band.
    pub attention_rows: Option<u16>,
}

impl FloatEncoder {
    /// Reads the encoder exported to `path`, checking it has the paper's shape (dim 128,
    /// 7 blocks, 4 heads, MLP 480).
    pub fn from_onnx(path: &Path) -> Result<Self> {
        let params = OnnxParams::load(path)?;
        Self::from_params(&params).with_context(|| format!("reading the float encoder from {}", path.display()))
    }

    /// Reads the encoder from an indexed ONNX graph.
    pub fn from_params(params: &OnnxParams) -> Result<Self> {
        let (rope_base, attention_rows) = check_config(params)?;
        let conv = "/patch_embed/Conv";
        let patch_weight = params.node_tensor(conv, 1, &[DIM, IN_CHANS, PATCH_H, PATCH_W], "patch embedding weight")?;
        let patch_bias = params.node_tensor(conv, 2, &[DIM], "patch embedding bias")?;
        let row_embed = params.tensor("encoder.row_embed", &[BAND_TOKEN_ROWS, DIM], "row embedding")?;
        let depth = (0..).take_while(|b| params.has_node(&norm_node(*b, 1))).count();
        ensure!(
            depth == DEPTH,
            "ONNX model {} has {depth} encoder blocks, expected {DEPTH}",
            params.source()
        );
        let blocks = (0..depth).map(|b| read_block(params, b)).collect::<Result<_>>()?;
        Ok(Self {
            patch_weight,
            patch_bias,
            row_embed,
            blocks,
            rope_base,
            attention_rows,
        })
    }
}

/// LayerNormalization's `epsilon` when a node leaves it out (ONNX operator default).
pub const ONNX_DEFAULT_LN_EPS: f32 = 1e-5;

fn norm_node(block: usize, norm: usize) -> String {
    format!("/blocks.{block}/norm{norm}/LayerNormalization")
}

fn read_block(params: &OnnxParams, b: usize) -> Result<FloatBlock> {
    let (norm1, norm2) = (norm_node(b, 1), norm_node(b, 2));
    let ln_eps = params.float_attribute_or(&norm1, "epsilon", ONNX_DEFAULT_LN_EPS)?;
    let eps2 = params.float_attribute_or(&norm2, "epsilon", ONNX_DEFAULT_LN_EPS)?;
    ensure!(
        eps2 == ln_eps,
        "block {b} of {} has LayerNorm epsilons {ln_eps} and {eps2}; the engine assumes one",
        params.source()
    );
    let linear = |name: &str, inputs, outputs| {
        FloatLinear::from_onnx_scope(params, &format!("/blocks.{b}/{name}"), inputs, outputs)
    };
    let norm = |node: &str, index, what: &str| params.node_tensor(node, index, &[DIM], &format!("block {b} {what}"));
    Ok(FloatBlock {
        norm1_weight: norm(&norm1, 1, "norm1 weight")?,
        norm1_bias: norm(&norm1, 2, "norm1 bias")?,
        qkv: linear("attn/qkv", DIM, 3 * DIM)?,
        proj: linear("attn/proj", DIM, DIM)?,
        norm2_weight: norm(&norm2, 1, "norm2 weight")?,
        norm2_bias: norm(&norm2, 2, "norm2 bias")?,
        fc1: linear("fc1", DIM, MLP_HIDDEN)?,
        fc2: linear("fc2", MLP_HIDDEN, DIM)?,
        ln_eps,
    })
}

// The head count is not visible in the weights' shapes and the RoPE base is folded into
// constants: both come from the `bino.config` metadata `export.py` stamps, as does the
// attention's reach (a mask in the graph). Returns the base and the reach.
fn check_config(params: &OnnxParams) -> Result<(f32, Option<u16>)> {
    let config = params.metadata_numbers("bino.config")?.with_context(|| {
        format!(
            "ONNX model {} has no `bino.config` metadata (written by `python -m bino_train.export`)",
            params.source()
        )
    })?;
    for (field, expected) in [
        ("dim", DIM),
        ("depth", DEPTH),
        ("heads", HEADS),
        ("mlp_hidden", MLP_HIDDEN),
    ] {
        if let Some(&value) = config.get(field) {
            ensure!(
                value == expected as f64,
                "ONNX model {} has {field} {value}, expected {expected}",
                params.source()
            );
        }
    }
    let base = *config
        .get("rope_base")
        .with_context(|| format!("`bino.config` of ONNX model {} has no rope_base", params.source()))?;
    ensure!(base > 1.0, "ONNX model {} has RoPE base {base}", params.source());
    let attention_rows = match config.get("attention_rows") {
        None => None,
        Some(&rows) => {
            ensure!(
                rows == 0.0,
                "ONNX model {} attends {rows} token rows either side; the engine runs 0 or the whole band",
                params.source()
            );
            Some(0)
        }
    };
    Ok((base as f32, attention_rows))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::float::taps::fixture_run::{block0_run, encoder_fixture, HEIGHT, TOKENS, WIDTH};
    use crate::float::taps::BlockTap;

    fn fixture() -> &'static FloatEncoder {
        static ENCODER: std::sync::OnceLock<FloatEncoder> = std::sync::OnceLock::new();
        ENCODER.get_or_init(|| FloatEncoder::from_onnx(&encoder_fixture()).unwrap())
    }

    fn layer_norm(x: &[f32], weight: &[f32], bias: &[f32], eps: f32) -> Vec<f32> {
        let n = x.len() as f64;
        let mean = x.iter().map(|&v| v as f64).sum::<f64>() / n;
        let var = x.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / n;
        let inv = 1.0 / (var + eps as f64).sqrt();
        x.iter()
            .zip(weight.iter().zip(bias))
            .map(|(&v, (&w, &b))| ((v as f64 - mean) * inv * w as f64 + b as f64) as f32)
            .collect()
    }

    fn assert_close(ours: &[f32], tract: &[f32], tolerance: f32, what: &str) {
        assert_eq!(ours.len(), tract.len(), "{what}");
        let worst = ours.iter().zip(tract).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
        assert!(worst < tolerance, "{what}: max |ours - tract| = {worst}");
    }

    // Tokens the layer checks look at: first, last and a few in between.
    const CHECKED_TOKENS: [usize; 4] = [0, 1, 517, TOKENS - 1];

    fn token(values: &[f32], t: usize, width: usize) -> &[f32] {
        &values[t * width..(t + 1) * width]
    }

    #[test]
    fn fixture_has_the_paper_shapes() {
        let e = fixture();
        assert_eq!(e.patch_weight.len(), DIM * IN_CHANS * PATCH_H * PATCH_W);
        assert_eq!(e.patch_bias.len(), DIM);
        assert_eq!(e.row_embed.len(), BAND_TOKEN_ROWS * DIM);
        assert_eq!(e.blocks.len(), DEPTH);
        assert_eq!(e.rope_base, 100.0);
        for block in &e.blocks {
            assert_eq!((block.qkv.out_features, block.qkv.in_features), (3 * DIM, DIM));
            assert_eq!((block.proj.out_features, block.proj.in_features), (DIM, DIM));
            assert_eq!((block.fc1.out_features, block.fc1.in_features), (MLP_HIDDEN, DIM));
            assert_eq!((block.fc2.out_features, block.fc2.in_features), (DIM, MLP_HIDDEN));
            assert_eq!(block.fc2.weight.len(), DIM * MLP_HIDDEN);
            assert_eq!(block.norm2_bias.len(), DIM);
            assert_eq!(block.ln_eps, 1e-5);
        }
    }

    #[test]
    fn fixture_values_match_python() {
        // Read from the fixture with python `onnx.numpy_helper`, printed as float32; they pin
        // the layouts (MatMul initializers are [in, out]: ONNX `onnx::MatMul_1593`[7, 5] is
        // PyTorch blocks.0.attn.qkv.weight[5, 7]).
        let e = fixture();
        let qkv = &e.blocks[0].qkv;
        assert_eq!(qkv.weight[5 * DIM + 7], -0.00715856);
        assert_eq!(qkv.weight[300 * DIM + 100], 0.017069872);
        let fc2 = &e.blocks[6].fc2;
        assert_eq!(fc2.weight[3 * MLP_HIDDEN + 100], -0.011311484);
        assert_eq!(
            e.patch_weight[((17 * IN_CHANS + 2) * PATCH_H + 1) * PATCH_W + 3],
            -0.12561902
        );
        assert_eq!(e.patch_bias[5], -0.12640081);
        assert_eq!(e.row_embed[11 * DIM + 127], 0.012591728);
        assert_eq!(e.row_embed[0], -0.004429852);
    }

    #[test]
    fn block0_layers_reproduce_the_tract_taps() {
        let (e, run) = (fixture(), block0_run());
        let block = &e.blocks[0];
        let tap = |t: BlockTap| run.get(&t.name(0)).1;
        let (_, embed) = run.get("embed");
        let (_, qkv) = run.get("/blocks.0/attn/qkv/Add_output_0");
        for t in CHECKED_TOKENS {
            let ln1 = layer_norm(
                token(embed, t, DIM),
                &block.norm1_weight,
                &block.norm1_bias,
                block.ln_eps,
            );
            assert_close(&ln1, token(tap(BlockTap::Norm1), t, DIM), 1e-4, "norm1");
            // qkv.weight is out x in: this is the transpose check.
            let ours = block.qkv.forward(token(tap(BlockTap::Norm1), t, DIM));
            assert_close(&ours, token(qkv, t, 3 * DIM), 1e-4, "qkv");
            let attn_out: Vec<f32> = token(tap(BlockTap::Middle), t, DIM)
                .iter()
                .zip(token(embed, t, DIM))
                .map(|(m, x)| m - x)
                .collect();
            assert_close(
                &block.proj.forward(token(tap(BlockTap::Attended), t, DIM)),
                &attn_out,
                1e-4,
                "proj",
            );
            let ln2 = layer_norm(
                token(tap(BlockTap::Middle), t, DIM),
                &block.norm2_weight,
                &block.norm2_bias,
                block.ln_eps,
            );
            assert_close(
                &block.fc1.forward(&ln2),
                token(tap(BlockTap::Fc1), t, MLP_HIDDEN),
                1e-4,
                "fc1",
            );
            let mlp_out: Vec<f32> = token(tap(BlockTap::Output), t, DIM)
                .iter()
                .zip(token(tap(BlockTap::Middle), t, DIM))
                .map(|(o, m)| o - m)
                .collect();
            assert_close(
                &block.fc2.forward(token(tap(BlockTap::Gelu), t, MLP_HIDDEN)),
                &mlp_out,
                1e-4,
                "fc2",
            );
        }
    }

    #[test]
    fn patch_and_row_embedding_reproduce_the_embed_output() {
        let (e, run) = (fixture(), block0_run());
        let (_, embed) = run.get("embed");
        let fused_cols = WIDTH / 2;
        // The fused image interleaves the views: fused column 2u is left column u, 2u + 1 right.
        let fused = |ch: usize, y: usize, x: usize| {
            let view = if x.is_multiple_of(2) { &run.left } else { &run.right };
            view[(ch * HEIGHT + y) * WIDTH + x / 2]
        };
        for t in CHECKED_TOKENS {
            let (r, c) = (t / fused_cols, t % fused_cols);
            let ours: Vec<f32> = (0..DIM)
                .map(|n| {
                    let mut acc = e.patch_bias[n] as f64 + e.row_embed[r * DIM + n] as f64;
                    for ch in 0..IN_CHANS {
                        for ky in 0..PATCH_H {
                            for kx in 0..PATCH_W {
                                let w = e.patch_weight[((n * IN_CHANS + ch) * PATCH_H + ky) * PATCH_W + kx];
                                acc += w as f64 * fused(ch, r * PATCH_H + ky, c * PATCH_W + kx) as f64;
                            }
                        }
                    }
                    acc as f32
                })
                .collect();
            assert_close(&ours, token(embed, t, DIM), 1e-4, "embed");
        }
    }

    #[test]
    fn a_wrong_block_count_is_reported() {
        use tract_onnx::prelude::Framework;
        let mut proto = tract_onnx::onnx().proto_model_for_path(encoder_fixture()).unwrap();
        let graph = proto.graph.as_mut().unwrap();
        graph.node.retain(|n| !n.name.starts_with("/blocks.6/"));
        let params = OnnxParams::from_proto(proto, "truncated").unwrap();
        let err = FloatEncoder::from_params(&params).unwrap_err();
        assert!(
            format!("{err:#}").contains("has 6 encoder blocks, expected 7"),
            "{err:#}"
        );
    }
}
