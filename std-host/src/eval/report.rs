//! `bino eval`'s results: scores per readout, pair and set ([`EvalReport`]), as the readable
//! table and the one-view occlusion summary (the JSON is in `json`).

use std::time::Duration;

use serde::Serialize;

use super::{EvalOptions, Metrics};
use crate::data::nuisance::Nuisance;
use crate::readout::head_candidates;

/// One readout's scores on one pair (or their mean).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ReadoutScore {
    /// EVAL.md metrics over every ground-truth pixel (the readout is dense).
    pub metrics: Metrics,
    /// % of ground-truth pixels whose cell passes the left-right check (`nolink`, `sgm`).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lr_keep: Option<f64>,
    /// epe over the ground-truth pixels that pass the left-right check.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gt_lr_epe: Option<f64>,
    /// The same metrics on the large-disparity subset
    /// ([`crate::eval::GroundTruthMap::large_disparity_subset`]).
    pub large: Metrics,
    /// An int8 readout the core's streaming pipeline does not stream (the unchecked fusions,
    /// `fuse-census` on the export pathway): host-only analysis, fused and refined on whole
    /// maps. The other int8 rows are the core's (`bino run`'s numbers); f32 rows are the float
    /// reference.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub host_only: bool,
}

/// How the right view was degraded for a run over the set.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Degradation {
    /// One of `--nuisance`.
    Nuisance(Nuisance),
    /// One-view occlusion of this % of the area (`--occlude`).
    Occlusion(u32),
}

impl Degradation {
    /// Its name in reports: the nuisance's, or `occlusion N%`.
    pub fn name(self) -> String {
        match self {
            Degradation::Nuisance(n) => n.name().to_string(),
            Degradation::Occlusion(p) => format!("occlusion {p}%"),
        }
    }
}

/// One pair's scores, a row each (in [`EvalOptions::rows`] order), and SGBM's.
#[derive(Debug, Clone)]
pub struct PairEval {
    /// The pair's id.
    pub pair_id: String,
    /// Scores per row.
    pub scores: Vec<ReadoutScore>,
    /// StereoSGBM on the same images (its invalid pixels filled as EVAL.md says).
    pub sgbm: Option<Metrics>,
    /// StereoSGBM on the large-disparity subset.
    pub sgbm_large: Option<Metrics>,
    /// Wall time for the pair (every precision and readout).
    pub elapsed: Duration,
    /// How the right view was degraded (None: clean).
    pub nuisance: Option<Degradation>,
}

/// The whole set's scores under one condition of the right view.
#[derive(Debug, Clone)]
pub struct SetEval {
    /// Per pair.
    pub pairs: Vec<PairEval>,
    /// Mean per row.
    pub mean: Vec<ReadoutScore>,
    /// SGBM's mean.
    pub sgbm_mean: Option<Metrics>,
    /// SGBM's mean on the large-disparity subsets.
    pub sgbm_large_mean: Option<Metrics>,
}

/// The whole set under one nuisance.
#[derive(Debug, Clone)]
pub struct NuisanceEval {
    /// The nuisance.
    pub nuisance: Nuisance,
    /// Its scores.
    pub set: SetEval,
}

/// The whole set with the right view occluded at one severity.
#[derive(Debug, Clone)]
pub struct OcclusionEval {
    /// % of the right view's area covered.
    pub percent: u32,
    /// Its scores.
    pub set: SetEval,
}

/// Every pair and the unweighted mean.
#[derive(Debug, Clone)]
pub struct EvalReport {
    /// The options it ran with.
    pub options: EvalOptions,
    /// Per pair.
    pub pairs: Vec<PairEval>,
    /// Mean per row.
    pub mean: Vec<ReadoutScore>,
    /// SGBM's mean.
    pub sgbm_mean: Option<Metrics>,
    /// SGBM's mean on the large-disparity subsets.
    pub sgbm_large_mean: Option<Metrics>,
    /// The same under each nuisance, in [`EvalOptions::nuisances`] order.
    pub nuisances: Vec<NuisanceEval>,
    /// The same under each occlusion severity, in [`EvalOptions::occlusions`] order.
    pub occlusions: Vec<OcclusionEval>,
}

impl EvalReport {
    /// The human-readable table: one row per precision and readout (mean), SGBM, then per
    /// pair epe.
    pub fn table(&self) -> String {
        use std::fmt::Write;
        let o = &self.options;
        let mut t = String::new();
        let _ = writeln!(
            t,
            "bino {} eval: {} {} pairs of {} at {}, {} pathway, {} candidates (head {}), SGM p1 {} p2 {}{}, LR tolerance {} col",
            env!("CARGO_PKG_VERSION"),
            self.pairs.len(),
            o.split,
            o.data.display(),
            o.profile,
            o.pathway,
            o.max_cols,
            o.profile
                .width()
                .map_or("by width".to_string(), |w| head_candidates(w).to_string()),
            o.penalties.p1,
            o.penalties.p2,
            match o.penalties.edge {
                0 => String::new(),
                e => format!(" edge {e}"),
            },
            o.lr_max_diff
        );
        let _ = writeln!(
            t,
            "\n{:<18} {:>8} {:>10} {:>8} {:>8} {:>8} {:>10} {:>10} {:>11}",
            "readout", "epe px", "bad1tok %", "bad2 %", "density", "LRkeep", "GT+LR epe", "large epe", "large b1t %"
        );
        let opt = |v: Option<f64>, prec: usize| v.map_or("-".to_string(), |v| format!("{v:.prec$}"));
        for ((p, r), s) in o.rows().iter().zip(&self.mean) {
            let m = s.metrics;
            let host = if s.host_only { " (host)" } else { "" };
            let _ = writeln!(
                t,
                "{:<18} {:>8.3} {:>10.2} {:>8.2} {:>8.1} {:>8} {:>10} {:>10.3} {:>11.2}",
                format!("{} {}{host}", p.name(), r.name()),
                m.epe,
                m.bad1tok,
                m.bad2,
                m.density,
                opt(s.lr_keep, 1),
                opt(s.gt_lr_epe, 3),
                s.large.epe,
                s.large.bad1tok
            );
        }
        if let (Some(m), Some(l)) = (self.sgbm_mean, self.sgbm_large_mean) {
            let _ = writeln!(
                t,
                "{:<18} {:>8.3} {:>10.2} {:>8.2} {:>8.1} {:>8} {:>10} {:>10.3} {:>11.2}",
                "StereoSGBM", m.epe, m.bad1tok, m.bad2, m.density, "-", "-", l.epe, l.bad1tok
            );
        }
        if self.mean.iter().any(|s| s.host_only) {
            let _ = writeln!(
                t,
                "(host): host-only analysis, an int8 readout the core's streaming pipeline does not stream, fused \
                 and refined on whole maps; the other int8 rows are the core's, as bino run writes them"
            );
        }
        if !self.nuisances.is_empty() {
            let _ = writeln!(
                t,
                "\nrobust accuracy: right view degraded (seed {}), epe px / bad1tok %, epe rise over clean; \
                 * = rise below StereoSGBM's",
                o.seed
            );
            let _ = write!(t, "{:<18} {:>14}", "readout", "clean");
            for n in &self.nuisances {
                let _ = write!(t, " {:>22}", n.nuisance.name());
            }
            let cell = |m: &Metrics| format!("{:.3}/{:.2}", m.epe, m.bad1tok);
            for (r, ((p, readout), clean)) in o.rows().iter().zip(&self.mean).enumerate() {
                let _ = write!(
                    t,
                    "\n{:<18} {:>14}",
                    format!("{} {}", p.name(), readout.name()),
                    cell(&clean.metrics)
                );
                for n in &self.nuisances {
                    let m = n.set.mean[r].metrics;
                    let rise = m.epe - clean.metrics.epe;
                    let below = match self.sgbm_rise(n) {
                        Some(sgbm) if rise < sgbm => "*",
                        Some(_) => " ",
                        None => "",
                    };
                    let _ = write!(t, " {:>22}", format!("{} {rise:+.3}{below}", cell(&m)));
                }
            }
            if let Some(clean) = self.sgbm_mean {
                let _ = write!(t, "\n{:<18} {:>14}", "StereoSGBM", cell(&clean));
                for n in &self.nuisances {
                    if let Some(m) = n.set.sgbm_mean {
                        let _ = write!(t, " {:>22}", format!("{} {:+.3} ", cell(&m), m.epe - clean.epe));
                    }
                }
            }
            t.push('\n');
        }
        self.occlusion_table(&mut t);
        let _ = write!(t, "\n{:<24}", "pair (epe px)");
        for (p, r) in o.rows() {
            let _ = write!(t, " {:>18}", format!("{} {}", p.name(), r.name()));
        }
        if self.sgbm_mean.is_some() {
            let _ = write!(t, " {:>18}", "SGBM");
        }
        for pair in &self.pairs {
            let _ = write!(t, "\n{:<24}", pair.pair_id);
            for s in &pair.scores {
                let _ = write!(t, " {:>18.3}", s.metrics.epe);
            }
            if let Some(m) = pair.sgbm {
                let _ = write!(t, " {:>18.3}", m.epe);
            }
        }
        t
    }

    /// The one-view occlusion section of [`EvalReport::table`] (nothing without `--occlude`):
    /// epe / bad1tok clean and at each severity, then OccAUC and Δ at the largest.
    fn occlusion_table(&self, t: &mut String) {
        use std::fmt::Write;
        let Some(summary) = self.occlusion_summary() else {
            return;
        };
        let top = self.occlusions.last().map_or(0, |o| o.percent);
        let _ = writeln!(
            t,
            "\none-view occlusion: right view, token-aligned mid-grey blocks (seed {}), epe px / bad1tok %",
            self.options.seed
        );
        let _ = write!(t, "{:<18} {:>14}", "readout", "clean");
        for o in &self.occlusions {
            let _ = write!(t, " {:>14}", format!("occ{}", o.percent));
        }
        let _ = write!(t, " {:>14} {:>16}", "OccAUC", format!("delta{top}"));
        let cell = |epe: f64, bad: f64| format!("{epe:.3}/{bad:.2}");
        for row in &summary {
            let _ = write!(t, "\n{:<18} {:>14}", row.name, cell(row.clean.epe, row.clean.bad1tok));
            for m in &row.severities {
                let _ = write!(t, " {:>14}", cell(m.epe, m.bad1tok));
            }
            let _ = write!(
                t,
                " {:>14} {:>16}",
                cell(row.auc_epe, row.auc_bad1tok),
                format!("{:+.3}/{:+.2}", row.delta_epe, row.delta_bad1tok)
            );
        }
        t.push('\n');
    }

    /// Per row (and SGBM last, when it ran) the occlusion curve and its summary; `None`
    /// without `--occlude`.
    pub fn occlusion_summary(&self) -> Option<Vec<OcclusionSummary>> {
        if self.occlusions.is_empty() {
            return None;
        }
        let rows = self.options.rows();
        let mut summary: Vec<OcclusionSummary> = (rows.iter().enumerate())
            .map(|(r, (p, readout))| {
                OcclusionSummary::new(
                    format!("{} {}", p.name(), readout.name()),
                    self.mean[r].metrics,
                    self.occlusions.iter().map(|o| o.set.mean[r].metrics).collect(),
                )
            })
            .collect();
        let sgbm: Option<Vec<Metrics>> = self.occlusions.iter().map(|o| o.set.sgbm_mean).collect();
        if let (Some(clean), Some(curve)) = (self.sgbm_mean, sgbm) {
            summary.push(OcclusionSummary::new("StereoSGBM".to_string(), clean, curve));
        }
        Some(summary)
    }

    /// StereoSGBM's mean epe rise under `n` over its clean epe, when SGBM ran.
    pub fn sgbm_rise(&self, n: &NuisanceEval) -> Option<f64> {
        Some(n.set.sgbm_mean?.epe - self.sgbm_mean?.epe)
    }
}

/// One row's one-view occlusion curve (means over the set) and its summary, the paper's
/// columns: `Occ` at the largest severity, `OccAUC` the mean over the non-zero severities,
/// `Δ` the largest severity minus clean.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct OcclusionSummary {
    /// `<precision> <readout>` or `StereoSGBM`.
    #[serde(skip)]
    pub name: String,
    /// Clean.
    pub clean: Metrics,
    /// At each severity, in order.
    pub severities: Vec<Metrics>,
    /// Mean epe over the severities.
    pub auc_epe: f64,
    /// Mean bad1tok over the severities.
    pub auc_bad1tok: f64,
    /// epe at the largest severity minus clean.
    pub delta_epe: f64,
    /// bad1tok at the largest severity minus clean.
    pub delta_bad1tok: f64,
}

impl OcclusionSummary {
    fn new(name: String, clean: Metrics, severities: Vec<Metrics>) -> Self {
        let n = severities.len().max(1) as f64;
        let last = severities.last().copied().unwrap_or(clean);
        Self {
            name,
            auc_epe: severities.iter().map(|m| m.epe).sum::<f64>() / n,
            auc_bad1tok: severities.iter().map(|m| m.bad1tok).sum::<f64>() / n,
            delta_epe: last.epe - clean.epe,
            delta_bad1tok: last.bad1tok - clean.bad1tok,
            clean,
            severities,
        }
    }
}
