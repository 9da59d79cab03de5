//! `bino eval` and the `EVAL.md` evaluation protocol it follows.
//!
//! The command ([`evaluate`], its options and report): BINO's readouts on every pair of a
//! split that has ground truth, in int8 (the core pipeline) and in float (tract descriptors
//! through the float twins of the same readouts, [`float_twins`]), next to OpenCV StereoSGBM
//! on the same profile images ([`sgbm`]), scored with EVAL.md's metrics per pair and on average.
//!
//! The protocol: ground truth at a resolution profile, the no-linkage descriptor readout,
//! bilinear upsampling of token-grid disparities and the per-pair metrics. Every function
//! mirrors `train/bino_train/probe.py` (and `pairs.py` / `profile.py` for the ground truth), so
//! that the Rust CLI and the Python training code report the same numbers.

mod evaluate;
pub mod float_twins;
pub mod gt;
mod int8_pair;
mod json;
pub mod metrics;
pub mod nearest;
pub mod nolink;
mod options;
mod report;
pub mod set;
pub mod sgbm;
pub mod upsample;

#[cfg(test)]
mod parity_tests;

pub use evaluate::evaluate;
pub use gt::{load_ground_truth, resize_ground_truth, GroundTruthMap};
pub use metrics::{density, fill_invalid, mean_metrics, score, score_sparse, Metrics};
pub use nearest::resize_nearest_exact;
pub use nolink::{no_linkage_disparity, similarity_volume, wta_subtoken, SimilarityVolume, DEFAULT_MAX_COLS};
pub use options::{EvalOptions, Precision};
pub use report::{
    Degradation, EvalReport, NuisanceEval, OcclusionEval, OcclusionSummary, PairEval, ReadoutScore, SetEval,
};
pub use set::{load_eval_item, load_eval_set, EvalItem};
pub use upsample::{resize_bilinear, upsample_disparity, upsample_mask, PIXELS_PER_PATCH_COLUMN};

/// A row-major map of disparities: one value per token (in patch columns) for a token grid,
/// or one per pixel (in pixels) for a view; the producing function says which.
#[derive(Debug, Clone, PartialEq)]
pub struct DisparityMap {
    /// Columns (patch columns or pixels).
    pub width: usize,
    /// Rows (token rows or pixels).
    pub height: usize,
    /// `width * height` disparities, row by row.
    pub values: Vec<f32>,
}
