//! The `EVAL.md` evaluation protocol: ground truth at a resolution profile, the no-linkage
//! descriptor readout, bilinear upsampling of token-grid disparities and the per-pair metrics.
//!
//! Every function mirrors `train/bino_train/probe.py` (and `pairs.py` / `profile.py` for the
//! ground truth), so that the Rust CLI and the Python training code report the same numbers.

pub mod float_twins;
pub mod gt;
pub mod metrics;
pub mod nearest;
pub mod nolink;
pub mod set;
pub mod upsample;

#[cfg(test)]
mod parity_tests;

pub use gt::{load_ground_truth, resize_ground_truth, GroundTruthMap};
pub use metrics::{density, fill_invalid, mean_metrics, score, score_sparse, Metrics};
pub use nearest::resize_nearest_exact;
pub use nolink::{no_linkage_disparity, similarity_volume, wta_subtoken, SimilarityVolume, DEFAULT_MAX_COLS};
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
