//! `bino describe`: the int8 engine's maps of a stack of crops, for quantisation-aware head
//! training.

use std::path::PathBuf;

use anyhow::{Context, Result};
use bino_host::int8::crop_maps::crop_maps;
use bino_host::int8::Int8Model;
use bino_host::io::checkout;
use bino_host::io::npy;
use clap::Args;

use super::args::PathwayChoice;

/// (developer) Write the int8 engine's maps of a stack of crops as .npy.
///
/// Reads `--crops` (float32 .npy, shape (N, 2, H, W): each crop's left and right view, gray in
/// [0, 1], H a multiple of 4 and at most one band) and writes `--out` (float32, shape
/// (N, 2, H/4, W/4, 128)): the maps the head of `--pathway` reads, dequantised by the blob's
/// descriptor scale. Export: D(L) and D(R); native: the even and odd phase maps of one pass on
/// (L, R). `python -m bino_train.int8_cache` calls it to train heads on the engine's own
/// descriptors.
#[derive(Args)]
pub struct DescribeArgs {
    /// Crops, float32 .npy of shape (N, 2, H, W).
    #[arg(long)]
    crops: PathBuf,
    /// Int8 weight blob (`bino quantize`); the default is the checkout's.
    #[arg(long, default_value_os_t = checkout::path(checkout::BLOB))]
    blob: PathBuf,
    #[command(flatten)]
    pathway: PathwayChoice,
    /// Worker threads.
    #[arg(long, default_value_t = 1)]
    threads: usize,
    /// Output .npy.
    #[arg(long)]
    out: PathBuf,
}

/// Runs the verb.
pub fn run(args: DescribeArgs) -> Result<()> {
    let model = Int8Model::load(&args.blob)?;
    let bytes = bino_host::io::files::read(&args.crops, "crops")?;
    let crops = npy::decode(&bytes).with_context(|| format!("crops {}", args.crops.display()))?;
    let maps = crop_maps(&model, &crops, args.pathway.pathway, args.threads)
        .with_context(|| format!("crops {}", args.crops.display()))?;
    bino_host::io::files::write_atomic(&args.out, |file| Ok(npy::write(file, &maps)?))?;
    println!("wrote {} ({:?})", args.out.display(), maps.shape);
    Ok(())
}
