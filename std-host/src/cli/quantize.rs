//! `bino quantize`: the float ONNX models into the int8 weight blob.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Result;
use bino_core::model::ids::HeadKind;
use bino_host::data::profile::Profile;
use bino_host::int8::blob_writer::without_head;
use bino_host::int8::Int8Model;
use bino_host::io::checkout;
use bino_host::quantize::{quantize, QuantizeOptions};
use bino_host::readout::pathway::Pathway;
use clap::Args;

use super::progress::Progress;

/// (developer) Quantise the float ONNX models into the int8 weight blob.
///
/// Weights: symmetric int8 per output channel. Activation formats come from the float
/// encoder's intermediate tensors (tract) on bands of train-split pairs only: per-channel
/// 0.01/99.99 percentiles for the residual stream, MSE-optimal clipping elsewhere
/// (docs/int8-model.md).
#[derive(Args)]
pub struct QuantizeArgs {
    /// Float encoder (`python -m bino_train.export`); the default is the checkout's shipped one.
    ///
    /// With or without `--intermediates`: calibration reads its per-stage tensors by value name.
    #[arg(long, default_value_os_t = checkout::path(checkout::ENCODER_ONNX))]
    onnx: PathBuf,
    /// Float shared head (`python -m bino_train.head`); quantised into the same blob.
    #[arg(long)]
    head: Option<PathBuf>,
    /// Float native-pathway head; quantised into the same blob, beside the shared head.
    ///
    /// `python -m bino_train.head` of a `--pathway native` head with pair features [a, b].
    #[arg(long)]
    native_head: Option<PathBuf>,
    /// Train pairs whose input maps calibrate each head.
    #[arg(long, default_value_t = 16)]
    head_calib_pairs: usize,
    /// Calibrate the heads again with the right view under each of these nuisances too.
    ///
    /// A comma list of gain, gamma, noise, blur, occlude: `bino eval --nuisance`'s images,
    /// seed 0, on the same pairs.
    #[arg(long, value_delimiter = ',', value_enum)]
    head_calib_nuisance: Vec<bino_host::data::nuisance::Nuisance>,
    /// Folder with PAIRS.tsv (only train pairs are read); the default is the one beside the checkout.
    #[arg(long, default_value_os_t = checkout::path(checkout::DATA))]
    calib: PathBuf,
    /// Train pairs to calibrate on (both views, one band each; spread over the split).
    #[arg(long, default_value_t = 64)]
    calib_pairs: usize,
    /// Resolution profile of the calibration bands; the default is the shipped blob's.
    #[arg(long, default_value = "w160")]
    profile: Profile,
    /// Widest band the blob supports, in pixels.
    #[arg(long, default_value_t = 640)]
    max_width: usize,
    /// Output blob; the default is the checkout's shipped one, which is replaced only with --force.
    #[arg(long, default_value_os_t = checkout::path(checkout::BLOB))]
    out: PathBuf,
    /// Replace an existing --out blob (the shipped one included).
    #[arg(long)]
    force: bool,
    /// Copy --from's encoder and only this pathway's head, byte for byte (no calibration).
    ///
    /// The blob of a board that runs one pathway: the native one needs no shared head.
    #[arg(long, value_enum, requires = "from")]
    only: Option<Pathway>,
    /// The blob --only copies from.
    #[arg(long, requires = "only")]
    from: Option<PathBuf>,
}

/// `--only`: `from`'s encoder and `pathway`'s head into `out`.
fn only_pathway(pathway: Pathway, from: &Path, out: &Path) -> Result<()> {
    let model = Int8Model::load(from)?;
    let other = match pathway {
        Pathway::Export => HeadKind::Native,
        Pathway::Native => HeadKind::Export,
    };
    let kept = match pathway {
        Pathway::Export => HeadKind::Export,
        Pathway::Native => HeadKind::Native,
    };
    model.require_head(kept)?;
    let blob = without_head(&model.blob()?, other)?;
    // The blob must load in the engine, with the pathway's head, before it is written.
    Int8Model::from_bytes(blob.clone(), &out.display().to_string())?.require_head(kept)?;
    bino_host::io::files::write_atomic(out, |file| Ok(file.write_all(&blob)?))?;
    println!(
        "{}: {} bytes, the encoder and the {} head of {} ({} bytes)",
        out.display(),
        blob.len(),
        kept.pathway(),
        from.display(),
        model.bytes().len()
    );
    Ok(())
}

/// Runs the verb.
pub fn run(args: QuantizeArgs) -> Result<()> {
    let opts = QuantizeOptions {
        encoder: args.onnx,
        head: args.head,
        native_head: args.native_head,
        head_calib_pairs: args.head_calib_pairs,
        head_calib_nuisances: args.head_calib_nuisance,
        data: args.calib,
        profile: args.profile,
        calib_pairs: args.calib_pairs,
        max_width: args.max_width,
    };
    let out = args.out;
    // Checked before the minutes of calibration: an existing blob (by default the shipped one,
    // which every other verb reads) is replaced only when asked.
    if out.exists() && !args.force {
        super::usage_error(
            "quantize",
            format!(
                "--out {} exists (the shipped blob by default): pass --force to replace it, or --out another file",
                out.display()
            ),
        );
    }
    if let (Some(pathway), Some(from)) = (args.only, args.from) {
        return only_pathway(pathway, &from, &out);
    }
    let started = Instant::now();
    let progress = Progress::new(false);
    progress.status("calibrating: bands");
    let (blob, report) = quantize(&opts, |done, total| {
        progress.tick(done, total, || {
            eprint!("\rcalibrating: band {done}/{total}");
            if done == total {
                eprintln!();
            }
        });
    })?;
    progress.finish();
    for (name, choice) in [
        ("head", &report.head_choice),
        ("native head", &report.native_head_choice),
    ] {
        let Some(choice) = choice else { continue };
        eprintln!("{name} correlation format, mean |int8 - float| disparity on the calibration maps (train split):");
        for (i, (label, error)) in choice.tried.iter().enumerate() {
            let mark = if i == choice.chosen { "  <- chosen" } else { "" };
            eprintln!("  {label:<20} {error:.4} patch columns{mark}");
        }
    }
    // The blob must load in the engine before it is written.
    Int8Model::from_bytes(blob.clone(), &out.display().to_string())?;
    bino_host::io::files::write_atomic(&out, |file| Ok(file.write_all(&blob)?))?;
    println!(
        "{}: {} bytes from {} ({} calibration bands, {:.1} s)",
        out.display(),
        blob.len(),
        opts.encoder.display(),
        report.bands,
        started.elapsed().as_secs_f64()
    );
    Ok(())
}
