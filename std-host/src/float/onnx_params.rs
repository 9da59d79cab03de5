//! Float parameters read straight from an ONNX file's protobuf, without building a tract model.
//!
//! The torch exporter names weights unpredictably (`onnx::MatMul_1593`) and deduplicates equal
//! initializers behind `Identity` nodes (a random init's zero biases all share one tensor), so
//! parameters are found through the nodes that consume them, whose names are stable
//! (`/blocks.0/attn/qkv/MatMul`), and every value is resolved through `Identity` chains.

use std::collections::HashMap;
use std::path::Path;

use anyhow::{bail, ensure, Context, Result};
use tract_onnx::pb::attribute_proto::AttributeType;
use tract_onnx::pb::{GraphProto, ModelProto, NodeProto, TensorProto};
use tract_onnx::prelude::*;

/// An ONNX graph indexed for parameter look-ups.
pub struct OnnxParams {
    source: String,
    model_dir: Option<String>,
    graph: GraphProto,
    initializers: HashMap<String, usize>,
    identity_inputs: HashMap<String, String>,
    nodes: HashMap<String, usize>,
    metadata: HashMap<String, String>,
}

impl OnnxParams {
    /// Reads and indexes the ONNX file at `path`.
    pub fn load(path: &Path) -> Result<Self> {
        ensure!(path.is_file(), "ONNX model {} does not exist", path.display());
        let proto = tract_onnx::onnx()
            .proto_model_for_path(path)
            .with_context(|| format!("cannot parse ONNX model {}", path.display()))?;
        let mut params = Self::from_proto(proto, &path.display().to_string())?;
        // External tensor data is looked up next to the model.
        params.model_dir = path.parent().and_then(|p| p.to_str()).map(str::to_string);
        Ok(params)
    }

    /// Indexes an already decoded model; `source` names it in errors.
    pub fn from_proto(proto: ModelProto, source: &str) -> Result<Self> {
        let graph = proto
            .graph
            .with_context(|| format!("ONNX model {source} has no graph"))?;
        let initializers = graph
            .initializer
            .iter()
            .enumerate()
            .map(|(i, t)| (t.name.clone(), i))
            .collect();
        let identity_inputs = graph
            .node
            .iter()
            .filter(|n| n.op_type == "Identity" && n.input.len() == 1 && n.output.len() == 1)
            .map(|n| (n.output[0].clone(), n.input[0].clone()))
            .collect();
        let nodes = graph
            .node
            .iter()
            .enumerate()
            .filter(|(_, n)| !n.name.is_empty())
            .map(|(i, n)| (n.name.clone(), i))
            .collect();
        let metadata = proto
            .metadata_props
            .iter()
            .map(|e| (e.key.clone(), e.value.clone()))
            .collect();
        Ok(Self {
            source: source.to_string(),
            model_dir: None,
            graph,
            initializers,
            identity_inputs,
            nodes,
            metadata,
        })
    }

    /// The file (or description) the model came from.
    pub fn source(&self) -> &str {
        &self.source
    }

    /// The node called `name`.
    pub fn node(&self, name: &str) -> Result<&NodeProto> {
        let index = self
            .nodes
            .get(name)
            .with_context(|| format!("ONNX model {} has no node named `{name}`", self.source))?;
        Ok(&self.graph.node[*index])
    }

    /// Whether a node called `name` exists.
    pub fn has_node(&self, name: &str) -> bool {
        self.nodes.contains_key(name)
    }

    /// The name of input `index` of node `node`.
    pub fn node_input(&self, node: &str, index: usize) -> Result<&str> {
        let proto = self.node(node)?;
        proto
            .input
            .get(index)
            .map(String::as_str)
            .with_context(|| format!("node `{node}` of {} has no input {index}", self.source))
    }

    /// The f32 values of initializer `value` (followed through `Identity` nodes), checked to
    /// have shape `expected`; `what` names the parameter in errors.
    pub fn tensor(&self, value: &str, expected: &[usize], what: &str) -> Result<Vec<f32>> {
        let (shape, data) = self
            .load_values(value)
            .with_context(|| format!("reading {what} from ONNX model {}", self.source))?;
        ensure!(
            shape == expected,
            "{what} (`{value}`) in ONNX model {} has shape {shape:?}, expected {expected:?}",
            self.source
        );
        Ok(data)
    }

    /// The f32 values of input `index` of node `node`, checked to have shape `expected`.
    pub fn node_tensor(&self, node: &str, index: usize, expected: &[usize], what: &str) -> Result<Vec<f32>> {
        let value = self.node_input(node, index)?;
        self.tensor(value, expected, what)
    }

    /// Float attribute `attr` of node `node` (e.g. a LayerNormalization's `epsilon`), or
    /// `default` (the ONNX operator's default) when the node does not set it.
    pub fn float_attribute_or(&self, node: &str, attr: &str, default: f32) -> Result<f32> {
        let Some(found) = self.node(node)?.attribute.iter().find(|a| a.name == attr) else {
            return Ok(default);
        };
        ensure!(
            found.r#type == AttributeType::Float as i32,
            "attribute `{attr}` of node `{node}` in {} is not a float",
            self.source
        );
        Ok(found.f)
    }

    /// The metadata entry `key` (the exporters stamp `bino.*` keys).
    pub fn metadata(&self, key: &str) -> Option<&str> {
        self.metadata.get(key).map(String::as_str)
    }

    /// The numeric fields of metadata entry `key`, written by the exporters as a Python dict
    /// `repr` (`{'dim': 128, 'rope_base': 100.0}`); `None` when the entry is absent.
    pub fn metadata_numbers(&self, key: &str) -> Result<Option<HashMap<String, f64>>> {
        self.metadata(key)
            .map(|text| {
                python_dict_numbers(text)
                    .with_context(|| format!("metadata `{key}` of ONNX model {} is not a dict", self.source))
            })
            .transpose()
    }

    // The initializer behind `value`, following Identity chains.
    fn resolve(&self, value: &str) -> Result<&TensorProto> {
        let mut name = value;
        // The chain length bound guards against a malformed cyclic graph.
        for _ in 0..=self.identity_inputs.len() {
            if let Some(&index) = self.initializers.get(name) {
                return Ok(&self.graph.initializer[index]);
            }
            match self.identity_inputs.get(name) {
                Some(input) => name = input,
                None => break,
            }
        }
        bail!("`{value}` is not an initializer of ONNX model {}", self.source)
    }

    fn load_values(&self, value: &str) -> Result<(Vec<usize>, Vec<f32>)> {
        let proto = self.resolve(value)?;
        let framework = tract_onnx::onnx();
        let tensor = tract_onnx::tensor::load_tensor(&*framework.provider, proto, self.model_dir.as_deref())
            .with_context(|| format!("cannot decode tensor `{}`", proto.name))?;
        let floats = tensor.cast_to::<f32>()?;
        let data = floats.to_plain_array_view::<f32>()?.iter().copied().collect();
        Ok((tensor.shape().to_vec(), data))
    }
}

/// The numeric values of a Python dict `repr` with string keys; other values are skipped.
pub fn python_dict_numbers(text: &str) -> Result<HashMap<String, f64>> {
    let inner = text
        .trim()
        .strip_prefix('{')
        .and_then(|t| t.strip_suffix('}'))
        .context("expected `{...}`")?;
    let mut numbers = HashMap::new();
    for entry in inner.split(',').map(str::trim).filter(|e| !e.is_empty()) {
        let (key, value) = entry
            .split_once(':')
            .with_context(|| format!("entry `{entry}` has no `:`"))?;
        let key = key.trim().trim_matches(|c| c == '\'' || c == '"');
        if let Ok(number) = value.trim().parse::<f64>() {
            numbers.insert(key.to_string(), number);
        }
    }
    Ok(numbers)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn python_dict_repr_numbers_are_read() {
        let text = "{'dim': 128, 'rope_base': 100.0, 'ln_eps': 1e-05, 'name': 'x'}";
        let numbers = python_dict_numbers(text).unwrap();
        assert_eq!(numbers["dim"], 128.0);
        assert_eq!(numbers["rope_base"], 100.0);
        assert_eq!(numbers["ln_eps"], 1e-5);
        assert!(!numbers.contains_key("name"));
        assert!(python_dict_numbers("dim: 1").is_err());
    }
}
