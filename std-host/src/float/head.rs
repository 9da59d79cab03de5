//! The float stereo heads' parameters, read from their ONNX exports
//! (`python -m bino_train.head --checkpoint ... --out ...`; `train/bino_train/head.py`): the
//! export pathway's shared head and the native pathway's head with pair features `u = [a, b]`
//! (`NATIVE_HEAD`; the `[a, b, |a-b|, a*b]` variant has no int8 twin and is refused).
//!
//! Layouts follow PyTorch: the projection is `out x in` row-major, Conv3d kernels are
//! `(out, in, 3, 3, 3)` over (disparity, row, column).

use std::path::Path;

use anyhow::{ensure, Context, Result};
use bino_core::config::{HEAD_GROUPS, HEAD_HIDDEN, HEAD_MAX_DISP, HEAD_MIDDLE_LAYERS};
use bino_core::model::ids::HeadKind;

use crate::float::onnx_params::OnnxParams;
use crate::float::weights::{FloatLinear, ONNX_DEFAULT_LN_EPS};

/// Kernel extent of every head convolution along disparity, row and column.
pub const HEAD_KERNEL: usize = 3;

/// A 3x3x3 `nn.Conv3d` (stride 1, padding 1).
#[derive(Debug, Clone, PartialEq)]
pub struct FloatConv3d {
    /// Output channels.
    pub out_channels: usize,
    /// Input channels.
    pub in_channels: usize,
    /// `(out, in, 3, 3, 3)` row-major.
    pub weight: Vec<f32>,
    /// `out_channels` biases.
    pub bias: Vec<f32>,
}

impl FloatConv3d {
    /// Reads Conv node `node` (weight input 1, bias input 2), checking its channel counts.
    pub fn from_onnx_node(params: &OnnxParams, node: &str, in_channels: usize, out_channels: usize) -> Result<Self> {
        let k = HEAD_KERNEL;
        let weight = params.node_tensor(
            node,
            1,
            &[out_channels, in_channels, k, k, k],
            &format!("{node} weight"),
        )?;
        let bias = params.node_tensor(node, 2, &[out_channels], &format!("{node} bias"))?;
        Ok(Self {
            out_channels,
            in_channels,
            weight,
            bias,
        })
    }
}

/// A stereo head: LayerNorm + projection on both views (export) or LayerNorm of the pair
/// feature and two projections (native), groupwise correlation over `max_disp` candidates, then
/// stem, residual middle layers and output Conv3d.
#[derive(Debug, Clone, PartialEq)]
pub struct FloatHead {
    /// Which head: export (shared) or native.
    pub kind: HeadKind,
    /// LayerNorm scale (`kind.input_dim()`: 128, or 256 for the native `[a, b]`).
    pub norm_weight: Vec<f32>,
    /// LayerNorm shift.
    pub norm_bias: Vec<f32>,
    /// LayerNorm epsilon.
    pub ln_eps: f32,
    /// The left projection: the export head's shared one (128 -> 96, both views), or the
    /// native head's `P_L` (256 -> 64).
    pub proj: FloatLinear,
    /// The native head's `P_R` (256 -> 64); `None` for the export head (its `proj` serves both).
    pub proj_right: Option<FloatLinear>,
    /// Correlation groups (96 channels / 16 groups = 6 channels averaged per group).
    pub groups: usize,
    /// Disparity candidates 0 .. max_disp - 1, in patch columns.
    pub max_disp: usize,
    /// First Conv3d, groups -> hidden, followed by ReLU.
    pub stem: FloatConv3d,
    /// Residual layers `x + relu(conv(x))`, hidden -> hidden.
    pub middle: Vec<FloatConv3d>,
    /// Last Conv3d, hidden -> 1: the logits.
    pub out: FloatConv3d,
}

impl FloatHead {
    /// Reads the head exported to `path`, checking it has the paper's shape (proj 96, or 64 for
    /// the native head, 16 groups, hidden 24, 4 middle layers, 12 candidates).
    pub fn from_onnx(path: &Path) -> Result<Self> {
        let params = OnnxParams::load(path)?;
        Self::from_params(&params).with_context(|| format!("reading the float head from {}", path.display()))
    }

    /// Reads the head from an indexed ONNX graph.
    pub fn from_params(params: &OnnxParams) -> Result<Self> {
        let kind = if params.has_node("/head/proj_left/MatMul") {
            HeadKind::Native
        } else {
            HeadKind::Export
        };
        let (groups, max_disp) = head_config(params, kind)?;
        let (input, proj) = (kind.input_dim(), kind.proj_dim());
        let norm = "/head/norm/LayerNormalization";
        let middle_layers = (0..).take_while(|i| params.has_node(&middle_node(*i))).count();
        ensure!(
            middle_layers == HEAD_MIDDLE_LAYERS,
            "ONNX head {} has {middle_layers} middle layers, expected {HEAD_MIDDLE_LAYERS}",
            params.source()
        );
        let middle = (0..middle_layers)
            .map(|i| FloatConv3d::from_onnx_node(params, &middle_node(i), HEAD_HIDDEN, HEAD_HIDDEN))
            .collect::<Result<_>>()?;
        let (proj_left, proj_right) = match kind {
            HeadKind::Export => (FloatLinear::from_onnx_scope(params, "/head/proj", input, proj)?, None),
            HeadKind::Native => (
                FloatLinear::from_onnx_scope(params, "/head/proj_left", input, proj)?,
                Some(FloatLinear::from_onnx_scope(params, "/head/proj_right", input, proj)?),
            ),
        };
        Ok(Self {
            kind,
            norm_weight: params.node_tensor(norm, 1, &[input], "head LayerNorm weight")?,
            norm_bias: params.node_tensor(norm, 2, &[input], "head LayerNorm bias")?,
            ln_eps: params.float_attribute_or(norm, "epsilon", ONNX_DEFAULT_LN_EPS)?,
            proj: proj_left,
            proj_right,
            groups,
            max_disp,
            stem: FloatConv3d::from_onnx_node(params, "/head/stem/Conv", groups, HEAD_HIDDEN)?,
            middle,
            out: FloatConv3d::from_onnx_node(params, "/head/out/Conv", HEAD_HIDDEN, 1)?,
        })
    }
}

fn middle_node(i: usize) -> String {
    format!("/head/middle.{i}/Conv")
}

// The MatMul averaging candidate k's products into groups.
fn group_pool_node(k: usize) -> String {
    if k == 0 {
        "/head/MatMul".to_string()
    } else {
        format!("/head/MatMul_{k}")
    }
}

// Groups and candidates from the `bino.head_config` metadata `head.py` stamps; without it, one
// group-pooling MatMul per candidate (`/head/MatMul`, `/head/MatMul_1`, ...) gives the count
// and the groups are the paper's (the stem's input channels are checked against them).
fn head_config(params: &OnnxParams, kind: HeadKind) -> Result<(usize, usize)> {
    if kind == HeadKind::Native {
        let text = params.metadata("bino.head_config").unwrap_or_default();
        ensure!(
            !text.contains("'full'"),
            "ONNX head {} is a native head with pair features [a, b, |a-b|, a*b] ('full'); the int8 \
             engine runs the [a, b] head ('concat', NATIVE_HEAD)",
            params.source()
        );
    }
    let config = params.metadata_numbers("bino.head_config")?.unwrap_or_default();
    let desc_dim = bino_core::config::DIM;
    for (field, expected) in [
        ("desc_dim", desc_dim),
        ("proj_dim", kind.proj_dim()),
        ("hidden", HEAD_HIDDEN),
    ] {
        if let Some(&value) = config.get(field) {
            ensure!(
                value == expected as f64,
                "ONNX head {} has {field} {value}, expected {expected}",
                params.source()
            );
        }
    }
    let groups = config.get("groups").map_or(HEAD_GROUPS, |&g| g as usize);
    let max_disp = match config.get("max_disp") {
        Some(&d) => d as usize,
        None => (0..).take_while(|k| params.has_node(&group_pool_node(*k))).count(),
    };
    ensure!(
        groups == HEAD_GROUPS,
        "ONNX head {} has {groups} correlation groups, expected {HEAD_GROUPS}",
        params.source()
    );
    ensure!(
        max_disp == HEAD_MAX_DISP,
        "ONNX head {} has {max_disp} disparity candidates, expected {HEAD_MAX_DISP}",
        params.source()
    );
    Ok((groups, max_disp))
}

#[cfg(test)]
mod tests {
    use super::*;
    use bino_core::config::{DIM, HEAD_PROJ_DIM};
    use tract_onnx::pb::attribute_proto::AttributeType;
    use tract_onnx::pb::{AttributeProto, GraphProto, ModelProto, NodeProto, StringStringEntryProto, TensorProto};

    // A distinct, position-revealing value for element `i` of tensor number `id`.
    fn pattern(id: usize, len: usize) -> Vec<f32> {
        (0..len).map(|i| id as f32 + i as f32 * 1e-4).collect()
    }

    fn initializer(name: &str, dims: &[usize], id: usize) -> TensorProto {
        TensorProto {
            name: name.to_string(),
            dims: dims.iter().map(|&d| d as i64).collect(),
            data_type: 1, // FLOAT
            float_data: pattern(id, dims.iter().product()),
            ..Default::default()
        }
    }

    fn node(name: &str, op: &str, inputs: &[&str]) -> NodeProto {
        NodeProto {
            name: name.to_string(),
            op_type: op.to_string(),
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: vec![format!("{name}_output_0")],
            ..Default::default()
        }
    }

    // The parameter-carrying part of a `head.py` export: same node and initializer names,
    // the projection weight behind an Identity, the bias first in the Add.
    fn head_proto(middle_layers: usize, metadata: bool) -> ModelProto {
        let k = HEAD_KERNEL;
        let mut inits = vec![
            initializer("head.norm.weight", &[DIM], 1),
            initializer("head.norm.bias", &[DIM], 2),
            initializer("onnx::MatMul_395", &[DIM, HEAD_PROJ_DIM], 3),
            initializer("head.proj.bias", &[HEAD_PROJ_DIM], 4),
            initializer("head.stem.weight", &[HEAD_HIDDEN, HEAD_GROUPS, k, k, k], 5),
            initializer("head.stem.bias", &[HEAD_HIDDEN], 6),
            initializer("head.out.weight", &[1, HEAD_HIDDEN, k, k, k], 7),
            initializer("head.out.bias", &[1], 8),
        ];
        let mut ln = node(
            "/head/norm/LayerNormalization",
            "LayerNormalization",
            &["desc_left", "head.norm.weight", "head.norm.bias"],
        );
        ln.attribute.push(AttributeProto {
            name: "epsilon".into(),
            r#type: AttributeType::Float as i32,
            f: 2e-5,
            ..Default::default()
        });
        let mut nodes = vec![
            node("Identity_141", "Identity", &["onnx::MatMul_395"]),
            ln,
            node(
                "/head/proj/MatMul",
                "MatMul",
                &["/head/norm/LayerNormalization_output_0", "Identity_141_output_0"],
            ),
            node(
                "/head/proj/Add",
                "Add",
                &["head.proj.bias", "/head/proj/MatMul_output_0"],
            ),
            node(
                "/head/stem/Conv",
                "Conv",
                &["volume", "head.stem.weight", "head.stem.bias"],
            ),
            node("/head/out/Conv", "Conv", &["x", "head.out.weight", "head.out.bias"]),
        ];
        for i in 0..middle_layers {
            let (w, b) = (format!("head.middle.{i}.weight"), format!("head.middle.{i}.bias"));
            inits.push(initializer(&w, &[HEAD_HIDDEN, HEAD_HIDDEN, k, k, k], 10 + i));
            inits.push(initializer(&b, &[HEAD_HIDDEN], 20 + i));
            nodes.push(node(&middle_node(i), "Conv", &["x", &w, &b]));
        }
        for d in 0..HEAD_MAX_DISP {
            nodes.push(node(&group_pool_node(d), "MatMul", &["product", "pool"]));
        }
        let metadata_props = if metadata {
            vec![StringStringEntryProto {
                key: "bino.head_config".into(),
                value: "{'desc_dim': 128, 'proj_dim': 96, 'groups': 16, 'hidden': 24, 'middle_layers': 4, \
                        'max_disp': 12, 'ln_eps': 1e-05}"
                    .into(),
            }]
        } else {
            Vec::new()
        };
        ModelProto {
            graph: Some(GraphProto {
                node: nodes,
                initializer: inits,
                ..Default::default()
            }),
            metadata_props,
            ..Default::default()
        }
    }

    #[test]
    fn head_parameters_are_read_in_pytorch_layout() {
        for metadata in [true, false] {
            let params = OnnxParams::from_proto(head_proto(HEAD_MIDDLE_LAYERS, metadata), "synthetic head").unwrap();
            let head = FloatHead::from_params(&params).unwrap();
            assert_eq!(
                (head.groups, head.max_disp, head.ln_eps),
                (HEAD_GROUPS, HEAD_MAX_DISP, 2e-5)
            );
            assert_eq!(head.norm_weight, pattern(1, DIM));
            assert_eq!(head.norm_bias, pattern(2, DIM));
            // ONNX proj weight is [in, out]: element (i, o) sits at i * 96 + o.
            let onnx_weight = pattern(3, DIM * HEAD_PROJ_DIM);
            assert_eq!((head.proj.out_features, head.proj.in_features), (HEAD_PROJ_DIM, DIM));
            assert_eq!(head.proj.weight[5 * DIM + 7], onnx_weight[7 * HEAD_PROJ_DIM + 5]);
            assert_eq!(head.proj.weight[95 * DIM + 127], onnx_weight[127 * HEAD_PROJ_DIM + 95]);
            assert_eq!(head.proj.bias, pattern(4, HEAD_PROJ_DIM));
            assert_eq!(
                (head.stem.in_channels, head.stem.out_channels),
                (HEAD_GROUPS, HEAD_HIDDEN)
            );
            assert_eq!(head.stem.weight, pattern(5, HEAD_HIDDEN * HEAD_GROUPS * 27));
            assert_eq!(head.middle.len(), HEAD_MIDDLE_LAYERS);
            assert_eq!(head.middle[3].weight, pattern(13, HEAD_HIDDEN * HEAD_HIDDEN * 27));
            assert_eq!(head.middle[3].bias, pattern(23, HEAD_HIDDEN));
            assert_eq!((head.out.out_channels, head.out.bias.len()), (1, 1));
        }
    }

    #[test]
    fn a_head_of_another_shape_is_refused() {
        let params = OnnxParams::from_proto(head_proto(3, true), "short head").unwrap();
        let err = FloatHead::from_params(&params).unwrap_err();
        assert!(
            format!("{err:#}").contains("has 3 middle layers, expected 4"),
            "{err:#}"
        );
    }

    /// Checks a real export against tract: `BINO_HEAD_ONNX=/tmp/head.onnx cargo test -p
    /// bino-host --lib float::head -- --ignored` (a head export is ~450 KB, too big for
    /// `tests/fixtures`; `export_head_onnx(StereoHead(), ...)` in python writes one).
    #[test]
    #[ignore = "needs BINO_HEAD_ONNX pointing at a head export"]
    fn head_export_projection_matches_tract() {
        use crate::float::taps::fixture_run::random_pixels;
        use crate::float::taps::TappedModel;
        use tract_onnx::prelude::*;

        let path = std::path::PathBuf::from(std::env::var("BINO_HEAD_ONNX").expect("set BINO_HEAD_ONNX"));
        let head = FloatHead::from_onnx(&path).unwrap();
        let taps = ["/head/norm/LayerNormalization_output_0", "/head/proj/Add_output_0"].map(String::from);
        let mut model = TappedModel::load(&path, &taps, 2).unwrap();
        let (rows, cols) = (3, 20);
        let desc = |seed| -> Tensor {
            let values = random_pixels(seed, rows * cols * DIM)
                .iter()
                .map(|v| 4.0 * v - 2.0)
                .collect();
            tract_ndarray::Array4::from_shape_vec((1, rows, cols, DIM), values)
                .unwrap()
                .into()
        };
        let outputs = model.run(vec![desc(1), desc(2)]).unwrap();
        let (normed, projected) = (&outputs[0].1, &outputs[1].1);
        for t in 0..rows * cols {
            let ours = head.proj.forward(&normed[t * DIM..(t + 1) * DIM]);
            let tract = &projected[t * HEAD_PROJ_DIM..(t + 1) * HEAD_PROJ_DIM];
            let worst = ours.iter().zip(tract).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max);
            assert!(worst < 1e-4, "token {t}: {worst}");
        }
    }
}
