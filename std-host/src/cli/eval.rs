//! `bino eval`: the readouts scored on the eval split, int8 and f32, StereoSGBM beside them.

use std::path::PathBuf;

use anyhow::Result;
use bino_host::eval::EvalOptions;
use bino_host::io::checkout;
use clap::Args;

use super::args::{Candidates, LeftRightCheck, MeasureProfile, PathwayChoice, SgmPenalties};
use super::progress::Progress;

/// Score the readouts, int8 and f32, on a data folder's eval pairs beside StereoSGBM.
///
/// The readouts nolink, sgm, head, fuse, census, fuse-census, fuse-all, each also +lr, each of those also +ref; int8 (the core
/// pipeline) and f32; epe, bad1tok and bad2 per pair and mean, StereoSGBM in the same run; with
/// --nuisance also with the right view degraded, with --occlude with it partly covered.
#[derive(Args)]
pub struct EvalArgs {
    /// Folder with PAIRS.tsv; the default is the data folder beside the checkout.
    #[arg(long, default_value_os_t = checkout::path(checkout::DATA))]
    data: PathBuf,
    /// Split: eval (the metrics need ground truth), or val (held-out train pairs).
    ///
    /// val: held-out train pairs scored against confident StereoSGBM, written by
    /// `python -m bino_train.val_folder`.
    #[arg(long, default_value = "eval")]
    split: String,
    #[command(flatten)]
    profile: MeasureProfile,
    /// Int8 weight blob; the default is the checkout's shipped one.
    #[arg(long, default_value_os_t = checkout::path(checkout::BLOB))]
    blob: PathBuf,
    /// Float encoder (ONNX), for --precision f32; the default is the checkout's shipped one.
    #[arg(long, default_value_os_t = checkout::path(checkout::ENCODER_ONNX))]
    onnx: PathBuf,
    /// Float shared head (ONNX), for --precision f32 with the head readout.
    #[arg(long, default_value_os_t = checkout::path(checkout::HEAD_ONNX))]
    head_onnx: PathBuf,
    /// Float native-pathway head (ONNX), for --precision f32 on --pathway native.
    #[arg(long, default_value_os_t = checkout::path(checkout::NATIVE_HEAD_ONNX))]
    native_head_onnx: PathBuf,
    #[command(flatten)]
    pathway: PathwayChoice,
    /// Precisions (repeat or comma-separate): int8 (the core pipeline), f32 (tract).
    ///
    /// f32: the float encoder and heads through tract-onnx, and the float twins of the readouts.
    #[arg(long, value_delimiter = ',', default_value = "int8,f32")]
    precision: Vec<bino_host::eval::Precision>,
    /// Readouts to score (repeat or comma-separate); the default is every readout of the pathway.
    ///
    /// nolink, sgm, head, fuse, census, fuse-census or fuse-all, each optionally with +lr (cells the
    /// method's own left-right check rejects filled from their lower kept neighbour), then optionally +ref (pixels
    /// by the integer refinement instead of bilinear upsampling). Default: every readout of the
    /// pathway, each unrefined then refined (all 28 on export; the head's, census's and
    /// fuse-census's twelve on native).
    #[arg(long, value_delimiter = ',')]
    readout: Vec<bino_host::readout::Readout>,
    #[command(flatten)]
    lr: LeftRightCheck,
    /// Skip StereoSGBM (it runs in the project's Python environment, OpenCV).
    #[arg(long)]
    no_sgbm: bool,
    #[command(flatten)]
    candidates: Candidates,
    #[command(flatten)]
    sgm: SgmPenalties,
    /// Also write every number as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Only the first N pairs of the split.
    #[arg(long)]
    limit: Option<usize>,
    /// Also score everything with the right view degraded: gain, gamma, noise, blur, occlude.
    ///
    /// Repeat or comma-separate; the clean run is always reported too. Applied to the profile's
    /// 8-bit right view after resizing, the same images for every method: gain (v * 0.7 +
    /// 20, clamped), gamma (255 (v/255)^0.6), noise (gaussian, sigma 8 grey levels), blur
    /// (5x5 box, radius 2 px), occlude (mid-grey rectangles, each at most 1/5 of the width
    /// and height, until at least 20 % of the area is covered). The whole set runs once
    /// more per nuisance: five nuisances take six times as long.
    #[arg(long, value_delimiter = ',')]
    nuisance: Vec<bino_host::data::nuisance::Nuisance>,
    /// Seed of the nuisances' noise and occlusions (mixed with each pair's id).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Also the one-view occlusion benchmark: the right view covered over these % of its area.
    ///
    /// Token-aligned mid-grey blocks over these % of the right view's area (comma-separated,
    /// rising, nested: each severity's blocks contain the milder ones'), every readout and
    /// StereoSGBM scored at each; reports clean, each severity, OccAUC and the rise at the
    /// largest. The whole set runs once more per severity.
    #[arg(long, value_delimiter = ',')]
    occlude: Vec<u32>,
}

/// Runs the verb.
pub fn run(args: EvalArgs) -> Result<()> {
    let opts = EvalOptions {
        data: args.data,
        split: args.split,
        profile: args.profile.profile,
        blob: args.blob,
        onnx: args.onnx,
        head_onnx: args.head_onnx,
        pathway: args.pathway.pathway,
        native_head_onnx: args.native_head_onnx,
        precisions: args.precision,
        readouts: if args.readout.is_empty() {
            args.pathway.pathway.readouts()
        } else {
            args.readout
        },
        max_cols: args.candidates.max_cols,
        penalties: args.sgm.penalties(),
        lr_max_diff: args.lr.lr_max_diff,
        sgbm: !args.no_sgbm,
        limit: args.limit,
        nuisances: args.nuisance,
        seed: args.seed,
        occlusions: args.occlude,
    };
    let progress = Progress::new(args.json.is_some());
    progress.status("scoring pairs");
    let report = bino_host::eval::evaluate(&opts, |done, total, pair| {
        let mut epe: Vec<String> = opts
            .rows()
            .iter()
            .zip(&pair.scores)
            .map(|((p, r), s)| format!("{} {} {:.3}", p.name(), r.name(), s.metrics.epe))
            .collect();
        if let Some(m) = pair.sgbm {
            epe.push(format!("SGBM {:.3}", m.epe));
        }
        let under = pair.nuisance.map_or(String::new(), |n| format!(" under {}", n.name()));
        progress.item(
            done,
            total,
            &format!(
                "[{done}/{total}] {}{under}: epe {} ({:.1} s)",
                pair.pair_id,
                epe.join(", "),
                pair.elapsed.as_secs_f64()
            ),
        );
    })?;
    progress.finish();
    println!("{}", report.table());
    super::write_json(args.json.as_deref(), || report.to_json())
}
