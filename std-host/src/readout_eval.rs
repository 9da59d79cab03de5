//! `bino eval`: the int8 pipeline's readouts on every pair of a split that has ground truth,
//! scored with EVAL.md's metrics per pair and on average.
//!
//! Each readout turns the same int8 descriptor codes into a token-grid disparity: `nolink`
//! (integer cosine WTA + parabola, `bino_core::matching`), `sgm` (`bino_core::sgm`, 4 streaming
//! paths) and `head` (the int8 shared head). StereoSGBM is not run here: `python -m
//! bino_train.head_eval` reports it in the same EVAL.md setting.

use std::path::PathBuf;
use std::str::FromStr;
use std::time::{Duration, Instant};

use anyhow::{bail, ensure, Context, Result};
use bino_core::sgm::Penalties;

use crate::eval::{load_eval_item, mean_metrics, score, upsample_disparity, DisparityMap, Metrics};
use crate::int8::{match_rows, sgm_rows, Int8Model};
use crate::json::Object;
use crate::pairs::{read_index, Split};
use crate::profile::Profile;

/// A way of reading disparity out of the descriptor maps.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Readout {
    /// Cosine WTA with the parabola step.
    Nolink,
    /// SGM over the cosine costs, then the parabola step.
    Sgm,
    /// The int8 shared head.
    Head,
}

impl Readout {
    /// Its name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Readout::Nolink => "nolink",
            Readout::Sgm => "sgm",
            Readout::Head => "head",
        }
    }
}

impl FromStr for Readout {
    type Err = anyhow::Error;

    fn from_str(s: &str) -> Result<Self> {
        match s {
            "nolink" => Ok(Readout::Nolink),
            "sgm" => Ok(Readout::Sgm),
            "head" => Ok(Readout::Head),
            other => bail!("unknown readout {other:?} (expected nolink, sgm or head)"),
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
    /// Readouts to score, in order.
    pub readouts: Vec<Readout>,
    /// Disparity candidates of `nolink` and `sgm`, in patch columns.
    pub max_cols: usize,
    /// SGM penalties.
    pub penalties: Penalties,
    /// Only the first this many pairs.
    pub limit: Option<usize>,
}

/// One pair's metrics, a readout each (in the options' order).
#[derive(Debug, Clone)]
pub struct PairEval {
    /// The pair's id.
    pub pair_id: String,
    /// Metrics per readout.
    pub metrics: Vec<Metrics>,
    /// Wall time for the pair (encoder on both views and every readout).
    pub elapsed: Duration,
}

/// Every pair and the unweighted mean.
#[derive(Debug, Clone)]
pub struct EvalReport {
    /// The options it ran with.
    pub options: EvalOptions,
    /// Per pair.
    pub pairs: Vec<PairEval>,
    /// Mean per readout.
    pub mean: Vec<Metrics>,
}

/// Runs the readouts over the split; `progress(done, total, pair)` after each pair.
pub fn evaluate(opts: &EvalOptions, mut progress: impl FnMut(usize, usize, &PairEval)) -> Result<EvalReport> {
    ensure!(!opts.readouts.is_empty(), "no readout to evaluate");
    ensure!(opts.limit != Some(0), "--limit must be at least 1");
    let split = match opts.split.as_str() {
        "eval" => Split::Eval,
        other => bail!("split {other:?}: only eval pairs carry ground truth here (use --split eval)"),
    };
    let model = Int8Model::load(&opts.blob)?;
    ensure!(
        !opts.readouts.contains(&Readout::Head) || model.has_head(),
        "blob {} holds no shared head: drop --readout head or quantise with --head",
        opts.blob.display()
    );
    let records: Vec<_> = read_index(&opts.data)?
        .into_iter()
        .filter(|r| r.split == split)
        .take(opts.limit.unwrap_or(usize::MAX))
        .collect();
    ensure!(!records.is_empty(), "no {split} pairs in {}", opts.data.display());
    let mut pairs = Vec::with_capacity(records.len());
    for (i, record) in records.iter().enumerate() {
        let started = Instant::now();
        let item = load_eval_item(record, opts.profile)?;
        let (rows, cols, left) = model.descriptor_codes(&item.left).context("left view")?;
        let (_, _, right) = model.descriptor_codes(&item.right).context("right view")?;
        let mut metrics = Vec::with_capacity(opts.readouts.len());
        for &readout in &opts.readouts {
            let tokens = match readout {
                Readout::Nolink => match_rows(&left, &right, rows, cols, opts.max_cols)?,
                Readout::Sgm => sgm_rows(&left, &right, rows, cols, opts.max_cols, opts.penalties)?,
                Readout::Head => {
                    let maps = model.head(&left, &right, rows, cols)?;
                    DisparityMap {
                        width: cols,
                        height: rows,
                        values: maps.disparity,
                    }
                }
            };
            metrics.push(
                score(&upsample_disparity(&tokens), &item.gt)
                    .with_context(|| format!("pair {}: {} readout", record.pair_id, readout.name()))?,
            );
        }
        let pair = PairEval {
            pair_id: record.pair_id.clone(),
            metrics,
            elapsed: started.elapsed(),
        };
        progress(i + 1, records.len(), &pair);
        pairs.push(pair);
    }
    let mean = (0..opts.readouts.len())
        .map(|r| mean_metrics(&pairs.iter().map(|p| p.metrics[r]).collect::<Vec<_>>()))
        .collect::<Result<Vec<_>>>()?;
    Ok(EvalReport {
        options: opts.clone(),
        pairs,
        mean,
    })
}

impl EvalReport {
    /// The human-readable table: one row per readout (mean), then per pair epe.
    pub fn table(&self) -> String {
        use std::fmt::Write;
        let o = &self.options;
        let mut t = String::new();
        let _ = writeln!(
            t,
            "bino {} eval: int8 blob {}, {} {} pairs of {} at {}, {} candidates, SGM p1 {} p2 {}",
            env!("CARGO_PKG_VERSION"),
            o.blob.display(),
            self.pairs.len(),
            o.split,
            o.data.display(),
            o.profile,
            o.max_cols,
            o.penalties.p1,
            o.penalties.p2
        );
        let _ = writeln!(
            t,
            "\n{:<8} {:>8} {:>10} {:>8} {:>9}",
            "readout", "epe px", "bad1tok %", "bad2 %", "density"
        );
        for (r, m) in o.readouts.iter().zip(&self.mean) {
            let _ = writeln!(
                t,
                "{:<8} {:>8.3} {:>10.2} {:>8.2} {:>9.1}",
                r.name(),
                m.epe,
                m.bad1tok,
                m.bad2,
                m.density
            );
        }
        let _ = write!(t, "\n{:<24}", "pair (epe px)");
        for r in &o.readouts {
            let _ = write!(t, " {:>8}", r.name());
        }
        for p in &self.pairs {
            let _ = write!(t, "\n{:<24}", p.pair_id);
            for m in &p.metrics {
                let _ = write!(t, " {:>8.3}", m.epe);
            }
        }
        t
    }

    /// Every number as JSON.
    pub fn to_json(&self) -> String {
        let o = &self.options;
        let readouts = |metrics: &[Metrics]| {
            o.readouts
                .iter()
                .zip(metrics)
                .fold(Object::new(), |obj, (r, m)| obj.raw(r.name(), m.to_json()))
                .render()
        };
        let pairs: Vec<String> = self
            .pairs
            .iter()
            .map(|p| {
                Object::new()
                    .str("pair_id", &p.pair_id)
                    .raw("readouts", readouts(&p.metrics))
                    .num("seconds", p.elapsed.as_secs_f64())
                    .render()
            })
            .collect();
        Object::new()
            .str("tool", "bino eval")
            .str("version", env!("CARGO_PKG_VERSION"))
            .str("blob", &o.blob.display().to_string())
            .str("data", &o.data.display().to_string())
            .str("split", &o.split)
            .str("profile", &o.profile.to_string())
            .int("max_cols", o.max_cols as u64)
            .int("sgm_p1", o.penalties.p1 as u64)
            .int("sgm_p2", o.penalties.p2 as u64)
            .int("pairs", self.pairs.len() as u64)
            .raw("mean", readouts(&self.mean))
            .raw("per_pair", format!("[{}]", pairs.join(",")))
            .render()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn readouts_parse_by_name() {
        for r in [Readout::Nolink, Readout::Sgm, Readout::Head] {
            assert_eq!(r.name().parse::<Readout>().unwrap(), r);
        }
        assert!("sgbm"
            .parse::<Readout>()
            .unwrap_err()
            .to_string()
            .contains("nolink, sgm or head"));
    }

    #[test]
    fn bad_options_are_errors() {
        let opts = EvalOptions {
            data: PathBuf::from("/nonexistent"),
            split: "train".into(),
            profile: Profile::W160,
            blob: PathBuf::from("/nonexistent/blob.bin"),
            readouts: vec![Readout::Nolink],
            max_cols: 10,
            penalties: Penalties { p1: 8, p2: 32 },
            limit: None,
        };
        let err = evaluate(&opts, |_, _, _| {}).unwrap_err().to_string();
        assert!(err.contains("only eval pairs"), "{err}");
        let none = EvalOptions {
            readouts: vec![],
            ..opts.clone()
        };
        assert!(evaluate(&none, |_, _, _| {}).is_err());
        let missing = EvalOptions {
            split: "eval".into(),
            ..opts
        };
        let err = format!("{:#}", evaluate(&missing, |_, _, _| {}).unwrap_err());
        assert!(err.contains("/nonexistent/blob.bin"), "{err}");
    }
}
