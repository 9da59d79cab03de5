//! An ONNX model run by tract with one optimised plan per input shape: exported BINO graphs
//! have dynamic sizes, and tract optimises best for concrete ones.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use anyhow::{ensure, Context, Result};
use tract_onnx::prelude::*;

/// A loaded ONNX graph computing one or more named outputs.
pub struct OnnxModel {
    path: PathBuf,
    model: InferenceModel,
    plans: HashMap<Vec<Vec<usize>>, Arc<TypedRunnableModel>>,
}

impl OnnxModel {
    /// Loads `path`, keeping only output `output`; fails unless it takes `inputs` inputs.
    pub fn load(path: &Path, output: &str, inputs: usize) -> Result<Self> {
        Self::load_outputs(path, &[output.to_string()], inputs)
    }

    /// Loads `path` computing `outputs`, in that order: graph outputs or any internal value
    /// named in the file (selected before optimisation, so tract keeps them); fails unless it
    /// takes `inputs` inputs.
    pub fn load_outputs(path: &Path, outputs: &[String], inputs: usize) -> Result<Self> {
        crate::io::files::input(path, "ONNX model")?;
        ensure!(
            !outputs.is_empty(),
            "no outputs requested from ONNX model {}",
            path.display()
        );
        let mut model = tract_onnx::onnx()
            .model_for_path(path)
            .with_context(|| format!("cannot load ONNX model {}", path.display()))?;
        let mut outlets = Vec::with_capacity(outputs.len());
        for (i, name) in outputs.iter().enumerate() {
            ensure!(
                !outputs[..i].contains(name),
                "output `{name}` of ONNX model {} is requested twice",
                path.display()
            );
            let outlet = model
                .find_outlet_label(name)
                .with_context(|| format!("ONNX model {} has no output or value named `{name}`", path.display()))?;
            outlets.push(outlet);
        }
        model.select_output_outlets(&outlets)?;
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

    /// Runs the model on `inputs` (f32 tensors); returns the (first) output's shape and values.
    pub fn run(&mut self, inputs: Vec<Tensor>) -> Result<(Vec<usize>, Vec<f32>)> {
        let mut outputs = self.run_outputs(inputs)?;
        Ok(outputs.swap_remove(0))
    }

    /// Runs the model on `inputs` (f32 tensors); returns every selected output's shape and
    /// values, in the order they were requested.
    pub fn run_outputs(&mut self, inputs: Vec<Tensor>) -> Result<Vec<(Vec<usize>, Vec<f32>)>> {
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
        outputs
            .iter()
            .enumerate()
            .map(|(i, output)| {
                let view = output
                    .to_plain_array_view::<f32>()
                    .with_context(|| format!("output {i} of {} is not f32", self.path.display()))?;
                Ok((view.shape().to_vec(), view.iter().copied().collect()))
            })
            .collect()
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
