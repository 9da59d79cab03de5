//! What `bino eval` runs: the precisions, readouts, data and degradations ([`EvalOptions`]).

use std::path::PathBuf;
use std::str::FromStr;

use anyhow::{bail, Result};
use bino_core::sgm::Penalties;

use crate::data::nuisance::Nuisance;
use crate::data::profile::Profile;
use crate::readout::pathway::Pathway;
use crate::readout::Readout;

/// The arithmetic a readout runs in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Precision {
    /// The int8 engine and the core's integer readouts.
    Int8,
    /// tract on the float ONNX models and the float twins of the readouts.
    F32,
}

impl Precision {
    /// Its name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Precision::Int8 => "int8",
            Precision::F32 => "f32",
        }
    }
}

impl FromStr for Precision {
    type Err = anyhow::Error;

    fn from_str(s: &str) -> Result<Self> {
        match s {
            "int8" => Ok(Precision::Int8),
            "f32" => Ok(Precision::F32),
            other => bail!("unknown precision {other:?} (expected int8 or f32)"),
        }
    }
}

/// What `bino eval` runs.
#[derive(Debug, Clone)]
pub struct EvalOptions {
    /// Folder with PAIRS.tsv.
    pub data: PathBuf,
    /// Split name (pairs need ground truth).
    pub split: String,
    /// EVAL.md resolution profile.
    pub profile: Profile,
    /// Int8 weight blob.
    pub blob: PathBuf,
    /// Float encoder (ONNX), for `f32`.
    pub onnx: PathBuf,
    /// Float head (ONNX), for `f32` with the `head` readout.
    pub head_onnx: PathBuf,
    /// Precisions to run, in order.
    pub precisions: Vec<Precision>,
    /// Readouts to score, in order (each one of the pathway's).
    pub readouts: Vec<Readout>,
    /// Export (two encoder passes, every readout) or native (one pass on (L, R), its head).
    pub pathway: Pathway,
    /// Float native-pathway head (ONNX), for `f32` on the native pathway.
    pub native_head_onnx: PathBuf,
    /// Disparity candidates of `nolink` and `sgm`, in patch columns.
    pub max_cols: usize,
    /// SGM penalties.
    pub penalties: Penalties,
    /// Left-right check tolerance, patch columns.
    pub lr_max_diff: f32,
    /// Run StereoSGBM (Python, OpenCV) on the same pairs.
    pub sgbm: bool,
    /// Only the first this many pairs.
    pub limit: Option<usize>,
    /// Nuisances of the right view, each scored over the whole set after the clean run.
    pub nuisances: Vec<Nuisance>,
    /// Seed of the nuisances and occlusions (with each pair's id).
    pub seed: u64,
    /// One-view occlusion severities, % of the right view's area, rising; each scored over the
    /// whole set after the clean run ([`crate::data::occlusion`]).
    pub occlusions: Vec<u32>,
}

impl EvalOptions {
    /// The table's rows: every precision with every readout.
    pub fn rows(&self) -> Vec<(Precision, Readout)> {
        self.precisions
            .iter()
            .flat_map(|&p| self.readouts.iter().map(move |&r| (p, r)))
            .collect()
    }
}
