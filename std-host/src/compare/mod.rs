//! `bino compare`: the float encoder (tract-onnx) against the int8 engine on the eval pairs.
//!
//! For every view of every pair:
//! - **stages**: the residual stream after the embedding and after each block's attention and
//!   MLP halves, band by band (the int8 engine's [`BandPlan`](bino_core::band::BandPlan)), as
//!   the mean per-token cosine. The float model gets the same 8-bit pixels the engine sees
//!   ([`to_u8`](crate::int8::to_u8), divided by 255), so that only the engines differ;
//! - **descriptors**: the float reference on the exact view against the int8 engine, as the
//!   mean per-cell cosine.
//!
//! Per pair, from those descriptor maps: how often the integer winner-take-all disparity
//! (argmax of the cosine similarity volume) agrees, and the `EVAL.md` metrics of the
//! no-linkage readout for each model, upsampled (`nolink`) and refined (`nolink+ref`, the
//! readouts' one refinement, [`crate::readout::refine`]); the same for the head when it runs. Pairs are
//! averaged without weights, like the metrics.

mod comparer;
pub mod head;
pub mod report;
pub mod stages;
mod wta;

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{bail, ensure, Context, Result};

use crate::data::nuisance::{degrade_item, Nuisance};
use crate::data::pairs::{read_index, Split};
use crate::data::profile::Profile;
use crate::eval::{load_eval_item, mean_metrics, Metrics};
use crate::io::files::sha256_hex;
pub use comparer::Comparer;
use stages::{EmbedSource, STAGE_COUNT};
pub use wta::{top2_gap_median, wta_agreement, wta_flip_loss, wta_integer};

/// What to compare, and on which pairs.
#[derive(Debug, Clone)]
pub struct CompareOptions {
    /// Float encoder (ONNX).
    pub onnx: PathBuf,
    /// Int8 weight blob made from it by `bino quantize`.
    pub blob: PathBuf,
    /// Float shared head (ONNX); compared with the blob's int8 head when given.
    pub head: Option<PathBuf>,
    /// Float native-pathway head (ONNX); when given, the native pathway is compared too: the
    /// pair tokens of one pass on (L, R) and the blob's int8 native head on them.
    pub native_head: Option<PathBuf>,
    /// Folder holding `PAIRS.tsv`.
    pub data: PathBuf,
    /// Split to read: only `eval` (the metrics need ground truth).
    pub split: String,
    /// Resolution profile of the views.
    pub profile: Profile,
    /// Disparity candidates of the no-linkage readout, in patch columns.
    pub max_cols: usize,
    /// Only the first this many pairs of the split.
    pub limit: Option<usize>,
    /// Degrade each right view first (`bino eval --nuisance`'s images, seed 0): where under
    /// that nuisance the two engines part.
    pub nuisance: Option<Nuisance>,
}

/// The int8 head against the float head on one pair or on average (`bino compare --head`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadComparison {
    /// Cosine of the int8 and float logits over the valid candidates.
    pub logit_cosine: f64,
    /// Mean |int8 - float| soft-argmin disparity, in patch columns.
    pub disparity_mean_abs: f64,
    /// EVAL.md metrics of the float head's disparity.
    pub float: Metrics,
    /// EVAL.md metrics of the int8 head's disparity.
    pub int8: Metrics,
    /// The float head's disparity refined (`head+ref`).
    pub float_ref: Metrics,
    /// The int8 head's disparity refined (`head+ref`).
    pub int8_ref: Metrics,
}

impl HeadComparison {
    /// Relative epe change of the int8 head over the float head, in %.
    pub fn epe_change_pct(&self) -> f64 {
        (self.int8.epe - self.float.epe) / self.float.epe * 100.0
    }

    /// Unweighted mean over pairs.
    fn mean(heads: &[HeadComparison]) -> Result<HeadComparison> {
        let n = heads.len() as f64;
        let of = |get: fn(&HeadComparison) -> Metrics| mean_metrics(&heads.iter().map(get).collect::<Vec<_>>());
        Ok(HeadComparison {
            logit_cosine: heads.iter().map(|x| x.logit_cosine).sum::<f64>() / n,
            disparity_mean_abs: heads.iter().map(|x| x.disparity_mean_abs).sum::<f64>() / n,
            float: of(|x| x.float)?,
            int8: of(|x| x.int8)?,
            float_ref: of(|x| x.float_ref)?,
            int8_ref: of(|x| x.int8_ref)?,
        })
    }
}

/// The native pathway, int8 against float (`bino compare --native-head`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NativeComparison {
    /// Mean per-token cosine of the de-positioned fused token grids of one pass on (L, R)
    /// (the native head's input).
    pub pair_token_cosine: f64,
    /// The int8 native head on the int8 pair tokens against the float one on the float tokens.
    pub head: HeadComparison,
}

/// The numbers of one pair, or their unweighted mean over pairs.
#[derive(Debug, Clone, PartialEq)]
pub struct Comparison {
    /// Mean per-token cosine of each stage, indexed by residual format
    /// ([`stages::stage_label`] names them).
    pub stage_cosine: Vec<f64>,
    /// Mean per-cell cosine of the descriptor maps.
    pub descriptor_cosine: f64,
    /// % of left-view cells whose integer WTA disparity is the same for both models.
    pub wta_agreement: f64,
    /// Where the winners differ: mean float similarity the int8 winner gives up against the
    /// float winner (0 without flips). Small against `wta_top2_gap` means flips are near-ties.
    pub wta_flip_loss: f64,
    /// Median over cells of the float volume's gap between its best and second-best candidate.
    pub wta_top2_gap: f64,
    /// Metrics of the no-linkage readout of the float descriptors.
    pub float: Metrics,
    /// Metrics of the no-linkage readout of the int8 descriptors.
    pub int8: Metrics,
    /// The float no-linkage readout refined (`nolink+ref`).
    pub float_ref: Metrics,
    /// The int8 no-linkage readout refined (`nolink+ref`).
    pub int8_ref: Metrics,
    /// The head comparison, once there is one.
    pub head: Option<HeadComparison>,
    /// The native pathway's comparison, with `--native-head`.
    pub native: Option<NativeComparison>,
}

impl Comparison {
    /// Relative epe change of int8 over float, in %: `(int8 - float) / float * 100`.
    pub fn epe_change_pct(&self) -> f64 {
        (self.int8.epe - self.float.epe) / self.float.epe * 100.0
    }

    /// Unweighted mean over pairs; the head only when every pair has one.
    pub fn mean<'a>(items: impl IntoIterator<Item = &'a Comparison>) -> Result<Comparison> {
        let items: Vec<&Comparison> = items.into_iter().collect();
        ensure!(!items.is_empty(), "no pairs to average");
        let n = items.len() as f64;
        let mean = |get: &dyn Fn(&Comparison) -> f64| items.iter().map(|c| get(c)).sum::<f64>() / n;
        let heads: Option<Vec<HeadComparison>> = items.iter().map(|c| c.head).collect();
        let natives: Option<Vec<NativeComparison>> = items.iter().map(|c| c.native).collect();
        let all = |get: fn(&Comparison) -> Metrics| mean_metrics(&items.iter().map(|c| get(c)).collect::<Vec<_>>());
        Ok(Comparison {
            stage_cosine: (0..STAGE_COUNT).map(|s| mean(&|c| c.stage_cosine[s])).collect(),
            descriptor_cosine: mean(&|c| c.descriptor_cosine),
            wta_agreement: mean(&|c| c.wta_agreement),
            wta_flip_loss: mean(&|c| c.wta_flip_loss),
            wta_top2_gap: mean(&|c| c.wta_top2_gap),
            float: all(|c| c.float)?,
            int8: all(|c| c.int8)?,
            float_ref: all(|c| c.float_ref)?,
            int8_ref: all(|c| c.int8_ref)?,
            head: heads.map(|h| HeadComparison::mean(&h)).transpose()?,
            native: match natives {
                Some(v) => Some(NativeComparison {
                    pair_token_cosine: v.iter().map(|x| x.pair_token_cosine).sum::<f64>() / n,
                    head: HeadComparison::mean(&v.iter().map(|x| x.head).collect::<Vec<_>>())?,
                }),
                None => None,
            },
        })
    }
}

/// One pair's comparison.
#[derive(Debug, Clone, PartialEq)]
pub struct PairComparison {
    /// The pair's `pair_id`.
    pub pair_id: String,
    /// View width at the profile.
    pub width: usize,
    /// View height at the profile.
    pub height: usize,
    /// Bands per view.
    pub bands: usize,
    /// Its numbers.
    pub values: Comparison,
    /// Wall time spent on the pair.
    pub elapsed: Duration,
}

/// Everything `bino compare` measured, with what it measured it on.
#[derive(Debug, Clone)]
pub struct CompareReport {
    /// `bino` version.
    pub version: String,
    /// Float encoder file.
    pub onnx: PathBuf,
    /// Int8 blob file.
    pub blob: PathBuf,
    /// The float head compared, if any.
    pub head: Option<PathBuf>,
    /// The float native head compared, if any.
    pub native_head: Option<PathBuf>,
    /// SHA-256 of the blob's bytes.
    pub blob_sha256: String,
    /// Data folder.
    pub data: PathBuf,
    /// Split compared.
    pub split: Split,
    /// Resolution profile.
    pub profile: Profile,
    /// Disparity candidates of the readout.
    pub max_cols: usize,
    /// The nuisance on every right view, if any (seed [`NUISANCE_SEED`]).
    pub nuisance: Option<Nuisance>,
    /// Where the float embedding stage came from.
    pub embed_source: EmbedSource,
    /// Per pair, in index order.
    pub pairs: Vec<PairComparison>,
    /// Unweighted mean over the pairs.
    pub mean: Comparison,
}

/// Seed of `CompareOptions::nuisance`: `bino eval --nuisance`'s default, so both see the same images.
pub const NUISANCE_SEED: u64 = 0;

/// Runs the comparison over the split's pairs; `progress(done, total, pair)` after each pair.
pub fn compare(
    opts: &CompareOptions,
    mut progress: impl FnMut(usize, usize, &PairComparison),
) -> Result<CompareReport> {
    let split = match opts.split.as_str() {
        "eval" => Split::Eval,
        "train" => {
            bail!("compare scores both models against ground truth, which only eval pairs have: use --split eval")
        }
        other => bail!("unknown split {other:?} (expected eval)"),
    };
    ensure!(opts.limit != Some(0), "--limit must be at least 1");
    let records: Vec<_> = read_index(&opts.data)?
        .into_iter()
        .filter(|r| r.split == split)
        .take(opts.limit.unwrap_or(usize::MAX))
        .collect();
    ensure!(!records.is_empty(), "no {split} pairs in {}", opts.data.display());
    let heads = [opts.head.as_deref(), opts.native_head.as_deref()];
    let mut comparer = Comparer::load(&opts.onnx, &opts.blob, heads, opts.max_cols)?;
    let mut pairs = Vec::with_capacity(records.len());
    for (i, record) in records.iter().enumerate() {
        let mut item = load_eval_item(record, opts.profile)?;
        if let Some(nuisance) = opts.nuisance {
            item = degrade_item(&item, nuisance, NUISANCE_SEED);
        }
        let pair = comparer
            .compare_pair(&item)
            .with_context(|| format!("pair {}", record.pair_id))?;
        progress(i + 1, records.len(), &pair);
        pairs.push(pair);
    }
    let mean = Comparison::mean(pairs.iter().map(|p| &p.values))?;
    Ok(CompareReport {
        version: env!("CARGO_PKG_VERSION").to_string(),
        onnx: opts.onnx.clone(),
        blob: opts.blob.clone(),
        head: opts.head.clone(),
        native_head: opts.native_head.clone(),
        blob_sha256: sha256_hex(comparer.int8().bytes()),
        data: opts.data.clone(),
        split,
        profile: opts.profile,
        max_cols: opts.max_cols,
        nuisance: opts.nuisance,
        embed_source: comparer.embed_source(),
        pairs,
        mean,
    })
}

#[cfg(test)]
mod tests;
