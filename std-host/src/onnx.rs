//! An ONNX model run by tract with one optimised plan per input shape: exported BINO graphs
//! have dynamic sizes, and tract optimises best for concrete ones.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{ensure, Context, Result};
use tract_onnx::prelude::*;

/// A loaded ONNX graph computing one named output.
pub struct OnnxModel {
    path: PathBuf,
    model: InferenceModel,
    plans: HashMap<Vec<Vec<usize>>, Arc<TypedRunnableModel>>,
}

impl OnnxModel {
    /// Loads `path`, keeping only output `output`; fails unless it takes `inputs` inputs.
    pub fn load(path: &Path, output: &str, inputs: usize) -> Result<Self> {
        ensure!(path.is_file(), "ONNX model {} does not exist", path.display());
        let mut model = tract_onnx::onnx()
            .model_for_path(path)
            .with_context(|| format!("cannot load ONNX model {}", path.display()))?;
        let outlet = model
            .find_outlet_label(output)
            .with_context(|| format!("ONNX model {} has no output named `{output}`", path.display()))?;
        model.select_output_outlets(&[outlet])?;
        ensure!(
            model.inputs.len() == inputs,
            "ONNX model {} takes {} inputs, expected {inputs}",
            path.display(),
            model.inputs.len()
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

    /// Runs the model on `inputs` (f32 tensors); returns the output's shape and values.
    pub fn run(&mut self, inputs: Vec<Tensor>) -> Result<(Vec<usize>, Vec<f32>)> {
        let shapes: Vec<Vec<usize>> = inputs.iter().map(|t| t.shape().to_vec()).collect();
        let plan = match self.plans.get(&shapes) {
            Some(plan) => plan,
            None => {
                let plan = self.optimise(&shapes)?;
                self.plans.entry(shapes.clone()).or_insert(plan)
            }
        };
        let outputs = plan
            .run(inputs.into_iter().map(TValue::from).collect())
            .with_context(|| format!("running {} on inputs {shapes:?}", self.path.display()))?;
        let view = outputs[0].to_plain_array_view::<f32>()?;
        Ok((view.shape().to_vec(), view.iter().copied().collect()))
    }

    fn optimise(&self, shapes: &[Vec<usize>]) -> Result<Arc<TypedRunnableModel>> {
        let mut model = self.model.clone();
        for (i, shape) in shapes.iter().enumerate() {
            model = model.with_input_fact(i, f32::fact(shape).into())?;
        }
        model
            .into_optimized()
            .and_then(|m| m.into_runnable())
            .with_context(|| format!("cannot plan {} for inputs {shapes:?}", self.path.display()))
    }
}
