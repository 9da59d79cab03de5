//! `bino eval --json`: the report's every number, in the file's field order.

use serde::Serialize;

use super::{EvalReport, Metrics, OcclusionSummary, PairEval, ReadoutScore};
use crate::io::keyed::Keyed;
use crate::readout::head_candidates;

impl EvalReport {
    /// Every number as JSON.
    pub fn to_json<'a>(&'a self) -> String {
        let o = &self.options;
        let rows = o.rows();
        let readouts = |scores: &[ReadoutScore], sgbm: Option<Metrics>, sgbm_large: Option<Metrics>| ReadoutsJson {
            rows: Keyed(
                (rows.iter().zip(scores))
                    .map(|((p, r), s)| (format!("{}_{}", p.name(), r.name()), *s))
                    .collect(),
            ),
            sgbm,
            sgbm_large,
        };
        let per_pair = |pairs: &'a [PairEval]| -> Vec<PairJson<'a>> {
            (pairs.iter())
                .map(|p| PairJson {
                    pair_id: &p.pair_id,
                    readouts: readouts(&p.scores, p.sgbm, p.sgbm_large),
                    seconds: p.elapsed.as_secs_f64(),
                })
                .collect()
        };
        let json = EvalJson {
            tool: "bino eval",
            version: env!("CARGO_PKG_VERSION"),
            blob: o.blob.display().to_string(),
            onnx: o.onnx.display().to_string(),
            head_onnx: o.head_onnx.display().to_string(),
            pathway: o.pathway.name(),
            native_head_onnx: o.native_head_onnx.display().to_string(),
            data: o.data.display().to_string(),
            split: &o.split,
            profile: o.profile.to_string(),
            max_cols: o.max_cols,
            head_candidates: o.profile.width().map(head_candidates),
            sgm_p1: o.penalties.p1,
            sgm_p2: o.penalties.p2,
            sgm_edge: o.penalties.edge,
            lr_max_diff: o.lr_max_diff as f64,
            pairs: self.pairs.len(),
            seed: o.seed,
            nuisance_params: NuisanceParams {
                gain: crate::data::nuisance::GAIN,
                offset: crate::data::nuisance::OFFSET,
                gamma: crate::data::nuisance::GAMMA,
                noise_sigma: crate::data::nuisance::NOISE_SIGMA,
                blur_radius: crate::data::nuisance::BLUR_RADIUS,
                occlude_share: crate::data::nuisance::OCCLUDE_SHARE,
                occlude_fill: crate::data::nuisance::OCCLUDE_FILL,
            },
            mean: readouts(&self.mean, self.sgbm_mean, self.sgbm_large_mean),
            per_pair: per_pair(&self.pairs),
            nuisances: Keyed(
                (self.nuisances.iter())
                    .map(|n| {
                        let sgbm_rise = self.sgbm_rise(n);
                        let rise: Vec<(String, f64)> = (rows.iter().zip(&n.set.mean).zip(&self.mean))
                            .map(|(((p, r), s), clean)| {
                                (format!("{}_{}", p.name(), r.name()), s.metrics.epe - clean.metrics.epe)
                            })
                            .collect();
                        let below =
                            sgbm_rise.map(|sgbm| Keyed(rise.iter().map(|(k, v)| (k.clone(), *v < sgbm)).collect()));
                        let json = NuisanceJson {
                            mean: readouts(&n.set.mean, n.set.sgbm_mean, n.set.sgbm_large_mean),
                            epe_rise: RiseJson {
                                rows: Keyed(rise),
                                sgbm: sgbm_rise,
                            },
                            rise_below_sgbm: below,
                            per_pair: per_pair(&n.set.pairs),
                        };
                        (n.nuisance.name().to_string(), json)
                    })
                    .collect(),
            ),
            occlusion: self.occlusion_summary().map(|summary| OcclusionJson {
                fill: crate::data::nuisance::OCCLUDE_FILL,
                severities: self.occlusions.iter().map(|o| o.percent).collect(),
                summary: Keyed(summary.into_iter().map(|s| (s.name.replace(' ', "_"), s)).collect()),
                per_severity: Keyed(
                    (self.occlusions.iter())
                        .map(|o| {
                            let json = SeverityJson {
                                mean: readouts(&o.set.mean, o.set.sgbm_mean, o.set.sgbm_large_mean),
                                per_pair: per_pair(&o.set.pairs),
                            };
                            (o.percent.to_string(), json)
                        })
                        .collect(),
                ),
            }),
        };
        serde_json::to_string_pretty(&json).expect("plain structs serialise")
    }
}

// The report's JSON, in the file's field order.
#[derive(Serialize)]
struct EvalJson<'a> {
    tool: &'static str,
    version: &'static str,
    blob: String,
    onnx: String,
    head_onnx: String,
    pathway: &'static str,
    native_head_onnx: String,
    data: String,
    split: &'a str,
    profile: String,
    max_cols: usize,
    // The heads' candidates at the profile's width (head_candidates); absent for the native
    // profile, whose width varies by pair.
    #[serde(skip_serializing_if = "Option::is_none")]
    head_candidates: Option<usize>,
    sgm_p1: u16,
    sgm_p2: u16,
    sgm_edge: u8,
    lr_max_diff: f64,
    pairs: usize,
    seed: u64,
    nuisance_params: NuisanceParams,
    // Clean: the right view as loaded.
    mean: ReadoutsJson,
    per_pair: Vec<PairJson<'a>>,
    // Keyed by nuisance name, in --nuisance order; empty without --nuisance.
    nuisances: Keyed<NuisanceJson<'a>>,
    // The one-view occlusion benchmark; absent without --occlude.
    #[serde(skip_serializing_if = "Option::is_none")]
    occlusion: Option<OcclusionJson<'a>>,
}

#[derive(Serialize)]
struct OcclusionJson<'a> {
    fill: u8,
    severities: Vec<u32>,
    // Keyed `<precision>_<readout>` and `StereoSGBM`.
    summary: Keyed<OcclusionSummary>,
    // Keyed by severity in %.
    per_severity: Keyed<SeverityJson<'a>>,
}

#[derive(Serialize)]
struct SeverityJson<'a> {
    mean: ReadoutsJson,
    per_pair: Vec<PairJson<'a>>,
}

// The constants of crate::data::nuisance.
#[derive(Serialize)]
struct NuisanceParams {
    gain: f32,
    offset: f32,
    gamma: f32,
    noise_sigma: f32,
    blur_radius: usize,
    occlude_share: f64,
    occlude_fill: u8,
}

#[derive(Serialize)]
struct NuisanceJson<'a> {
    mean: ReadoutsJson,
    // Mean epe under the nuisance minus the clean mean epe, per row and SGBM.
    epe_rise: RiseJson,
    // Per row: its epe rise is below SGBM's (absent when SGBM did not run).
    #[serde(skip_serializing_if = "Option::is_none")]
    rise_below_sgbm: Option<Keyed<bool>>,
    per_pair: Vec<PairJson<'a>>,
}

#[derive(Serialize)]
struct RiseJson {
    #[serde(flatten)]
    rows: Keyed<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    sgbm: Option<f64>,
}

#[derive(Serialize)]
struct PairJson<'a> {
    pair_id: &'a str,
    readouts: ReadoutsJson,
    seconds: f64,
}

// Scores keyed `<precision>_<readout>` in row order, then SGBM's when it ran.
#[derive(Serialize)]
struct ReadoutsJson {
    #[serde(flatten)]
    rows: Keyed<ReadoutScore>,
    #[serde(skip_serializing_if = "Option::is_none")]
    sgbm: Option<Metrics>,
    #[serde(skip_serializing_if = "Option::is_none")]
    sgbm_large: Option<Metrics>,
}
