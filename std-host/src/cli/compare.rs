//! `bino compare`: the float encoder (tract-onnx) against the int8 engine on eval pairs.

use std::path::PathBuf;

use anyhow::Result;
use bino_host::compare::{compare, CompareOptions};
use bino_host::io::checkout;
use bino_host::readout::pathway::Pathway;
use clap::Args;

use super::args::{Candidates, MeasureProfile, PathwayChoice, NOLINK_CANDIDATES_HELP};
use super::progress::Progress;

/// (developer) Compare the float encoder with the int8 engine on eval pairs.
///
/// The float encoder runs through tract-onnx. Per view and band: the cosine of the residual stream after the embedding and after each
/// block's attention and MLP halves (the float model runs on the engine's own 8-bit pixels
/// / 255, so only the engines differ). Per view: the descriptor maps' cosine (float on the
/// exact view). Per pair: integer WTA disparity agreement and the metrics (epe, bad1tok, bad2)
/// of the no-linkage readout of both, upsampled and refined (nolink+ref; with --head also head
/// and head+ref; with --native-head the native pathway's pair tokens and native head). Prints
/// the means with the targets (descriptor cosine >= 0.99, WTA agreement >= 98 %, int8 epe at
/// most 3 % above float); progress on stderr.
#[derive(Args)]
#[command(mut_arg("max_cols", |a| a.help(NOLINK_CANDIDATES_HELP)))]
pub struct CompareArgs {
    /// Folder with PAIRS.tsv; the default is the data folder beside the checkout.
    #[arg(long, default_value_os_t = checkout::path(checkout::DATA))]
    data: PathBuf,
    /// Split to compare on: only eval (the metrics need ground truth).
    #[arg(long, default_value = "eval")]
    split: String,
    #[command(flatten)]
    profile: MeasureProfile,
    /// Float encoder (`python -m bino_train.export`); the default is the checkout's shipped one.
    #[arg(long, default_value_os_t = checkout::path(checkout::ENCODER_ONNX))]
    onnx: PathBuf,
    /// Int8 weight blob quantised from it (`bino quantize`); the default is the checkout's.
    #[arg(long, default_value_os_t = checkout::path(checkout::BLOB))]
    blob: PathBuf,
    /// Float shared head: also compare the int8 head's logits and disparity with it.
    #[arg(long)]
    head: Option<PathBuf>,
    /// Float native-pathway head: also compare the native pathway.
    ///
    /// The pair tokens of one pass on (L, R), and the blob's int8 native head on them against
    /// this head on the float ones.
    #[arg(long)]
    native_head: Option<PathBuf>,
    /// --pathway native: compare the native pathway too, with --native-head or, by default,
    /// the checkout's weights/bino_native_head.onnx (the encoder's stages and descriptors are
    /// compared on either pathway).
    #[command(flatten)]
    pathway: PathwayChoice,
    /// Also write every number (per pair and mean) and the inputs' provenance as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    #[command(flatten)]
    candidates: Candidates,
    /// Only the first N pairs of the split.
    #[arg(long)]
    limit: Option<usize>,
    /// Degrade every right view first, as `bino eval --nuisance` does (seed 0).
    #[arg(long, value_enum)]
    nuisance: Option<bino_host::data::nuisance::Nuisance>,
}

/// Runs the verb.
pub fn run(args: CompareArgs) -> Result<()> {
    let opts = CompareOptions {
        onnx: args.onnx,
        blob: args.blob,
        head: args.head,
        native_head: match (args.pathway.pathway, args.native_head) {
            (Pathway::Native, None) => Some(checkout::path(checkout::NATIVE_HEAD_ONNX)),
            (_, given) => given,
        },
        data: args.data,
        split: args.split,
        profile: args.profile.profile,
        max_cols: args.candidates.max_cols,
        limit: args.limit,
        nuisance: args.nuisance,
    };
    let progress = Progress::new(args.json.is_some());
    progress.status("comparing pairs");
    let report = compare(&opts, |done, total, pair| {
        let v = &pair.values;
        progress.item(
            done,
            total,
            &format!(
                "[{done}/{total}] {}: descriptor cosine {:.4}, WTA agreement {:.1} %, epe {:.3} float / {:.3} int8 \
                 ({:.1} s)",
                pair.pair_id,
                v.descriptor_cosine,
                v.wta_agreement,
                v.float.epe,
                v.int8.epe,
                pair.elapsed.as_secs_f64()
            ),
        );
    })?;
    progress.finish();
    println!("{}", report.table());
    super::write_json(args.json.as_deref(), || report.to_json())
}
