//! The eval split of a data folder at a resolution profile (`probe.load_probe_set`).

use std::path::Path;

use anyhow::{ensure, Context, Result};

use super::gt::{load_ground_truth, resize_ground_truth, GroundTruthMap};
use crate::data::pairs::{read_index, PairRecord, Split};
use crate::data::profile::{Profile, View};
use crate::io::image_io::load_gray;

/// One eval pair ready for scoring: both views and the ground truth at the same profile.
#[derive(Debug, Clone, PartialEq)]
pub struct EvalItem {
    /// The pair's `pair_id`.
    pub pair_id: String,
    /// Left view at the profile.
    pub left: View,
    /// Right view at the profile.
    pub right: View,
    /// Ground truth of the left view at the profile.
    pub gt: GroundTruthMap,
}

/// Loads one labeled pair at a profile; fails if the views and the ground truth disagree in size.
pub fn load_eval_item(record: &PairRecord, profile: Profile) -> Result<EvalItem> {
    let id = &record.pair_id;
    let gt = record
        .gt
        .as_ref()
        .with_context(|| format!("pair {id} has no ground truth"))?;
    let view = |path: &Path| -> Result<(View, (usize, usize))> {
        let image = load_gray(path)?;
        let view = profile
            .apply(&image)
            .with_context(|| format!("pair {id}: image {}", path.display()))?;
        Ok((view, (image.width, image.height)))
    };
    let ((left, stored_size), (right, _)) = (view(&record.left)?, view(&record.right)?);
    let stored = load_ground_truth(gt).with_context(|| format!("pair {id}"))?;
    // At the stored resolution: a map of another size may still resize to the profile's.
    ensure!(
        (stored.width, stored.height) == stored_size,
        "pair {id}: ground truth {} is {}x{}, its left image {} is {}x{}",
        gt.path.display(),
        stored.width,
        stored.height,
        record.left.display(),
        stored_size.0,
        stored_size.1
    );
    let gt_map = resize_ground_truth(&stored, profile)
        .with_context(|| format!("pair {id}: ground truth {}", gt.path.display()))?;
    ensure!(
        (gt_map.width, gt_map.height) == (left.width, left.height),
        "pair {id}: ground truth {} is {}x{} at profile {profile}, left image {} is {}x{}",
        gt.path.display(),
        gt_map.width,
        gt_map.height,
        record.left.display(),
        left.width,
        left.height
    );
    ensure!(
        (right.width, right.height) == (left.width, left.height),
        "pair {id}: right image {} is {}x{} at profile {profile}, left image is {}x{}",
        record.right.display(),
        right.width,
        right.height,
        left.width,
        left.height
    );
    Ok(EvalItem {
        pair_id: id.clone(),
        left,
        right,
        gt: gt_map,
    })
}

/// The `split = eval` pairs of `data_dir/PAIRS.tsv` (or of the index file itself) at a
/// profile, in file order. Fails when the index has no eval pairs.
pub fn load_eval_set(data_dir: &Path, profile: Profile) -> Result<Vec<EvalItem>> {
    let records = read_index(data_dir)?;
    let items = records
        .iter()
        .filter(|r| r.split == Split::Eval)
        .map(|r| load_eval_item(r, profile))
        .collect::<Result<Vec<_>>>()?;
    ensure!(!items.is_empty(), "no eval pairs in {}", data_dir.display());
    Ok(items)
}
