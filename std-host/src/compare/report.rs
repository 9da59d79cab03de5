//! The comparison as a readable table with the issue's targets, and as JSON.

use std::fmt::Write;

use super::stages::{stage_label, EmbedSource, STAGE_COUNT};
use serde::Serialize;

use super::{CompareReport, Comparison, HeadComparison, NativeComparison, PairComparison};
use crate::eval::Metrics;
use crate::io::keyed::Keyed;

/// Target: mean per-cell descriptor cosine at least this.
pub const DESCRIPTOR_COSINE_TARGET: f64 = 0.99;
/// Target: integer WTA disparity agreement at least this many %.
pub const WTA_AGREEMENT_TARGET: f64 = 98.0;
/// Target: int8 epe at most this many % above float epe (lower is always fine).
pub const EPE_CHANGE_TARGET_PCT: f64 = 3.0;

/// One of the issue's acceptance targets, evaluated on the mean over pairs.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Check {
    /// Machine name (JSON key).
    pub name: &'static str,
    /// The target, for people.
    pub target: String,
    /// The measured value.
    pub value: f64,
    /// Whether the value meets the target.
    pub pass: bool,
}

/// The targets, evaluated on `mean`.
pub fn checks(mean: &Comparison) -> Vec<Check> {
    let change = mean.epe_change_pct();
    vec![
        Check {
            name: "descriptor_cosine",
            target: format!(">= {DESCRIPTOR_COSINE_TARGET}"),
            value: mean.descriptor_cosine,
            pass: mean.descriptor_cosine >= DESCRIPTOR_COSINE_TARGET,
        },
        Check {
            name: "wta_agreement_pct",
            target: format!(">= {WTA_AGREEMENT_TARGET} %"),
            value: mean.wta_agreement,
            pass: mean.wta_agreement >= WTA_AGREEMENT_TARGET,
        },
        Check {
            name: "epe_change_pct",
            target: format!("<= +{EPE_CHANGE_TARGET_PCT} %"),
            value: change,
            pass: change <= EPE_CHANGE_TARGET_PCT,
        },
    ]
}

/// One metric's row of the table: float, int8, their change and `extra` (a target).
fn metric_row(t: &mut String, name: &str, f: f64, i: f64, extra: &str) {
    let change = (i - f) / f * 100.0;
    let row = format!("  {name:<16} {f:>8.4}  {i:>8.4}  {change:>+7.2} %  {extra}");
    let _ = writeln!(t, "{}", row.trim_end());
}

/// A head's rows of the table: float and int8 metrics, unrefined and refined.
fn head_rows(t: &mut String, title: &str, head: &HeadComparison) {
    let _ = writeln!(
        t,
        "\n{title:<20} float      int8     change   (logit cosine {:.5}, mean |int8 - float| {:.4} patch columns)",
        head.logit_cosine, head.disparity_mean_abs
    );
    metric_row(t, "epe (px)", head.float.epe, head.int8.epe, "");
    metric_row(t, "bad1tok (%)", head.float.bad1tok, head.int8.bad1tok, "");
    metric_row(t, "bad2 (%)", head.float.bad2, head.int8.bad2, "");
    let _ = writeln!(t, "  refined (head+ref)");
    metric_row(t, "epe (px)", head.float_ref.epe, head.int8_ref.epe, "");
    metric_row(t, "bad1tok (%)", head.float_ref.bad1tok, head.int8_ref.bad1tok, "");
    metric_row(t, "bad2 (%)", head.float_ref.bad2, head.int8_ref.bad2, "");
}

fn verdict(pass: bool) -> &'static str {
    if pass {
        "PASS"
    } else {
        "MISS"
    }
}

impl CompareReport {
    /// The targets, evaluated on the mean over pairs.
    pub fn checks(&self) -> Vec<Check> {
        checks(&self.mean)
    }

    /// The report as a table for people.
    pub fn table(&self) -> String {
        let mut t = String::new();
        let mean = &self.mean;
        let check = |name: &str| {
            self.checks()
                .into_iter()
                .find(|c| c.name == name)
                .map(|c| format!("target {:<9} {}", c.target, verdict(c.pass)))
                .unwrap_or_default()
        };
        let _ = writeln!(
            t,
            "bino {} compare: float {} (tract-onnx) vs int8 {} (sha256 {})",
            self.version,
            self.onnx.display(),
            self.blob.display(),
            &self.blob_sha256[..self.blob_sha256.len().min(16)]
        );
        let _ = writeln!(
            t,
            "{} {} pairs of {} at {}, {} disparity candidates{}; mean over pairs",
            self.pairs.len(),
            self.split,
            self.data.display(),
            self.profile,
            self.max_cols,
            self.nuisance
                .map_or(String::new(), |n| format!(", right views under {}", n.name()))
        );
        let _ = writeln!(
            t,
            "\nstage cosine (per token; float on the engine's u8 pixels; embed from {})",
            match self.embed_source {
                EmbedSource::GraphOutput => "graph output `embed`",
                EmbedSource::InternalValue => "value `/Add_output_0`",
            }
        );
        for (format, cos) in mean.stage_cosine.iter().enumerate() {
            let worst = self
                .pairs
                .iter()
                .map(|p| p.values.stage_cosine[format])
                .fold(f64::INFINITY, f64::min);
            let _ = writeln!(t, "  {:<12} {cos:.5}   (worst pair {worst:.5})", stage_label(format));
        }
        let _ = writeln!(
            t,
            "  {:<12} {:.5}   {}",
            "descriptors",
            mean.descriptor_cosine,
            check("descriptor_cosine")
        );
        let _ = writeln!(
            t,
            "\nWTA agreement  {:.2} %   {}",
            mean.wta_agreement,
            check("wta_agreement_pct")
        );
        let _ = writeln!(
            t,
            "  where they differ, the int8 winner is {:.5} below the float winner in float similarity\n  \
             (median best-to-second gap of the float volume: {:.5})",
            mean.wta_flip_loss, mean.wta_top2_gap
        );
        let _ = writeln!(t, "\nno-linkage readout   float      int8     change");
        metric_row(
            &mut t,
            "epe (px)",
            mean.float.epe,
            mean.int8.epe,
            &check("epe_change_pct"),
        );
        metric_row(&mut t, "bad1tok (%)", mean.float.bad1tok, mean.int8.bad1tok, "");
        metric_row(&mut t, "bad2 (%)", mean.float.bad2, mean.int8.bad2, "");
        let _ = writeln!(t, "  refined (nolink+ref)");
        metric_row(&mut t, "epe (px)", mean.float_ref.epe, mean.int8_ref.epe, "");
        metric_row(&mut t, "bad1tok (%)", mean.float_ref.bad1tok, mean.int8_ref.bad1tok, "");
        metric_row(&mut t, "bad2 (%)", mean.float_ref.bad2, mean.int8_ref.bad2, "");
        if let Some(head) = &mean.head {
            head_rows(&mut t, "shared head", head);
        }
        if let Some(native) = &mean.native {
            let _ = writeln!(
                t,
                "\nnative pathway (one pass on (L, R)): pair token cosine {:.5}",
                native.pair_token_cosine
            );
            head_rows(&mut t, "native head", &native.head);
        }
        let _ = writeln!(
            t,
            "\n{:<24} {:>9} {:>8} {:>10} {:>10} {:>8}",
            "pair", "desc cos", "WTA %", "epe float", "epe int8", "change"
        );
        for p in &self.pairs {
            let v = &p.values;
            let _ = writeln!(
                t,
                "{:<24} {:>9.5} {:>8.2} {:>10.4} {:>10.4} {:>+7.2} %",
                p.pair_id,
                v.descriptor_cosine,
                v.wta_agreement,
                v.float.epe,
                v.int8.epe,
                v.epe_change_pct()
            );
        }
        let checks = self.checks();
        let passed = checks.iter().filter(|c| c.pass).count();
        let _ = write!(t, "\ntargets met: {passed} of {}", checks.len());
        t
    }

    /// The report as JSON: provenance, the mean, the targets and every pair.
    pub fn to_json(&self) -> String {
        let json = CompareJson {
            tool: "bino compare",
            version: &self.version,
            onnx: self.onnx.display().to_string(),
            blob: self.blob.display().to_string(),
            head_onnx: self.head.as_ref().map(|h| h.display().to_string()),
            native_head_onnx: self.native_head.as_ref().map(|h| h.display().to_string()),
            blob_sha256: &self.blob_sha256,
            data: self.data.display().to_string(),
            split: self.split.to_string(),
            profile: self.profile.to_string(),
            max_cols: self.max_cols,
            nuisance: self.nuisance.map(|n| n.name()),
            stage_pixels:
                "float stages run on the int8 engine's u8 pixels / 255; descriptors and metrics on the exact views",
            embed_value: match self.embed_source {
                EmbedSource::GraphOutput => "embed",
                EmbedSource::InternalValue => "/Add_output_0",
            },
            stages: (0..STAGE_COUNT).map(stage_label).collect(),
            mean: MeanJson {
                values: ComparisonJson::new(&self.mean),
                pairs: self.pairs.len(),
            },
            targets: self.checks(),
            pairs: self.pairs.iter().map(PairJson::new).collect(),
        };
        serde_json::to_string_pretty(&json).expect("plain structs serialise")
    }
}

// The report's JSON, in the file's field order; paths as `Path::display` shows them.
#[derive(Serialize)]
struct CompareJson<'a> {
    tool: &'static str,
    version: &'a str,
    onnx: String,
    blob: String,
    head_onnx: Option<String>,
    native_head_onnx: Option<String>,
    blob_sha256: &'a str,
    data: String,
    split: String,
    profile: String,
    max_cols: usize,
    #[serde(skip_serializing_if = "Option::is_none")]
    nuisance: Option<&'static str>,
    stage_pixels: &'static str,
    embed_value: &'static str,
    stages: Vec<String>,
    mean: MeanJson,
    targets: Vec<Check>,
    pairs: Vec<PairJson<'a>>,
}

#[derive(Serialize)]
struct MeanJson {
    #[serde(flatten)]
    values: ComparisonJson,
    pairs: usize,
}

#[derive(Serialize)]
struct PairJson<'a> {
    pair_id: &'a str,
    width: usize,
    height: usize,
    bands_per_view: usize,
    seconds: f64,
    #[serde(flatten)]
    values: ComparisonJson,
}

impl<'a> PairJson<'a> {
    fn new(p: &'a PairComparison) -> Self {
        Self {
            pair_id: &p.pair_id,
            width: p.width,
            height: p.height,
            bands_per_view: p.bands,
            seconds: p.elapsed.as_secs_f64(),
            values: ComparisonJson::new(&p.values),
        }
    }
}

// A comparison with its derived numbers, stage cosines keyed by stage label.
#[derive(Serialize)]
struct ComparisonJson {
    stage_cosine: Keyed<f64>,
    descriptor_cosine: f64,
    wta_agreement_pct: f64,
    wta_flip_loss: f64,
    wta_top2_gap: f64,
    float: Metrics,
    int8: Metrics,
    epe_change_pct: f64,
    /// `nolink+ref`.
    float_ref: Metrics,
    int8_ref: Metrics,
    head: Option<HeadJson>,
    native: Option<NativeJson>,
}

impl ComparisonJson {
    fn new(c: &Comparison) -> Self {
        Self {
            stage_cosine: Keyed((0..STAGE_COUNT).map(|s| (stage_label(s), c.stage_cosine[s])).collect()),
            descriptor_cosine: c.descriptor_cosine,
            wta_agreement_pct: c.wta_agreement,
            wta_flip_loss: c.wta_flip_loss,
            wta_top2_gap: c.wta_top2_gap,
            float: c.float,
            int8: c.int8,
            epe_change_pct: c.epe_change_pct(),
            float_ref: c.float_ref,
            int8_ref: c.int8_ref,
            head: c.head.as_ref().map(HeadJson::new),
            native: c.native.as_ref().map(NativeJson::new),
        }
    }
}

#[derive(Serialize)]
struct NativeJson {
    pair_token_cosine: f64,
    /// The native head, as `head`.
    head: HeadJson,
}

impl NativeJson {
    fn new(n: &NativeComparison) -> Self {
        Self {
            pair_token_cosine: n.pair_token_cosine,
            head: HeadJson::new(&n.head),
        }
    }
}

#[derive(Serialize)]
struct HeadJson {
    logit_cosine: f64,
    disparity_mean_abs: f64,
    float: Metrics,
    int8: Metrics,
    epe_change_pct: f64,
    /// `head+ref`.
    float_ref: Metrics,
    int8_ref: Metrics,
}

impl HeadJson {
    fn new(h: &HeadComparison) -> Self {
        Self {
            logit_cosine: h.logit_cosine,
            disparity_mean_abs: h.disparity_mean_abs,
            float: h.float,
            int8: h.int8,
            epe_change_pct: h.epe_change_pct(),
            float_ref: h.float_ref,
            int8_ref: h.int8_ref,
        }
    }
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;
    use std::time::Duration;

    use super::*;
    use crate::data::pairs::Split;
    use crate::data::profile::Profile;

    fn comparison(desc: f64, wta: f64, epe_float: f64, epe_int8: f64) -> Comparison {
        let m = |epe| Metrics {
            epe,
            bad1tok: 30.0,
            bad2: 50.0,
            density: 100.0,
        };
        Comparison {
            stage_cosine: (0..STAGE_COUNT).map(|s| 1.0 - s as f64 * 1e-3).collect(),
            descriptor_cosine: desc,
            wta_agreement: wta,
            wta_flip_loss: 0.001,
            wta_top2_gap: 0.02,
            float: m(epe_float),
            int8: m(epe_int8),
            float_ref: m(0.6 * epe_float),
            int8_ref: m(0.6 * epe_int8),
            head: None,
            native: None,
        }
    }

    fn report(mean: Comparison) -> CompareReport {
        CompareReport {
            version: "0.0.0".into(),
            onnx: PathBuf::from("enc \"x\".onnx"),
            blob: PathBuf::from("q.bin"),
            head: Some(PathBuf::from("head.onnx")),
            native_head: None,
            blob_sha256: "ab".repeat(32),
            data: PathBuf::from("data"),
            split: Split::Eval,
            profile: Profile::W160,
            max_cols: 10,
            nuisance: None,
            embed_source: EmbedSource::GraphOutput,
            pairs: vec![PairComparison {
                pair_id: "p1".into(),
                width: 160,
                height: 120,
                bands: 3,
                values: mean.clone(),
                elapsed: Duration::from_millis(1500),
            }],
            mean,
        }
    }

    #[test]
    fn targets_pass_and_miss_at_the_issue_thresholds() {
        let good = checks(&comparison(0.99, 98.0, 2.0, 2.05));
        assert!(good.iter().all(|c| c.pass), "{good:?}");
        // Better int8 epe is fine; just below each threshold is not.
        assert!(checks(&comparison(0.995, 99.0, 2.0, 1.5)).iter().all(|c| c.pass));
        let bad = checks(&comparison(0.9899, 97.9, 2.0, 2.07));
        assert!(bad.iter().all(|c| !c.pass), "{bad:?}");
    }

    #[test]
    fn table_marks_each_target() {
        let table = report(comparison(0.995, 97.0, 2.0, 2.02)).table();
        assert!(
            table.contains("descriptors  0.99500   target >= 0.99   PASS"),
            "{table}"
        );
        assert!(
            table.contains("WTA agreement  97.00 %   target >= 98 %   MISS"),
            "{table}"
        );
        assert!(table.contains("block6"), "{table}");
        assert!(table.contains("targets met: 2 of 3"), "{table}");
        assert!(table.contains("refined (nolink+ref)"), "{table}");
    }

    #[test]
    fn json_parses_and_holds_every_number() {
        let mut mean = comparison(0.995, 99.0, 2.0, 2.02);
        mean.head = Some(HeadComparison {
            logit_cosine: 0.98,
            disparity_mean_abs: 0.1,
            float: Metrics { epe: 1.5, ..mean.float },
            int8: Metrics { epe: 1.6, ..mean.float },
            float_ref: Metrics { epe: 0.9, ..mean.float },
            int8_ref: Metrics { epe: 1.0, ..mean.float },
        });
        let head = mean.head.unwrap();
        mean.native = Some(NativeComparison {
            pair_token_cosine: 0.997,
            head: HeadComparison {
                logit_cosine: 0.97,
                ..head
            },
        });
        let text = report(mean.clone()).to_json();
        let table = report(mean).table();
        assert!(table.contains("pair token cosine 0.99700"), "{table}");
        assert!(table.contains("native head"), "{table}");
        let v: serde_json::Value = serde_json::from_str(&text).unwrap();
        assert_eq!(v["mean"]["native"]["pair_token_cosine"], 0.997);
        assert_eq!(v["mean"]["native"]["head"]["logit_cosine"], 0.97);
        assert_eq!(v["native_head_onnx"], serde_json::Value::Null);
        assert_eq!(v["onnx"], "enc \"x\".onnx");
        assert_eq!(v["head_onnx"], "head.onnx");
        assert_eq!(v["stages"].as_array().unwrap().len(), STAGE_COUNT);
        assert_eq!(v["mean"]["pairs"], 1);
        assert_eq!(v["mean"]["stage_cosine"]["embed"], 1.0);
        assert_eq!(v["mean"]["head"]["logit_cosine"], 0.98);
        assert_eq!(v["mean"]["head"]["int8"]["epe"], 1.6);
        assert_eq!(v["mean"]["head"]["int8_ref"]["epe"], 1.0);
        assert_eq!(v["mean"]["float_ref"]["epe"], 1.2);
        assert_eq!(v["pairs"][0]["bands_per_view"], 3);
        assert_eq!(v["pairs"][0]["int8"]["epe"], 2.02);
        assert_eq!(v["targets"].as_array().unwrap().len(), 3);
        assert!((v["mean"]["epe_change_pct"].as_f64().unwrap() - 1.0).abs() < 1e-9);
    }
}
