//! `bino reference`: the float ONNX reference on a pair, tokens and descriptor maps as .npz.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{bail, ensure, Context, Result};
use bino_host::data::profile::{Profile, View};
use bino_host::data::synthetic;
use bino_host::float::reference::{FeatureMap, ReferenceEncoder};
use bino_host::float::reference_head::ReferenceHead;
use bino_host::io::checkout;
use bino_host::io::image_io::{load_gray, GrayImage};
use bino_host::io::npy::Array;
use bino_host::io::npz;
use clap::Args;

use super::args::MeasureProfile;
use super::progress::Progress;

/// (developer) Write the float model's tokens and descriptors for a pair as .npz.
///
/// Arrays in the archive (float32, C order; open with numpy.load):
/// `left`, `right` (H, W) the views after the profile, gray in [0, 1];
/// `tokens` (H/4, W/2, 128) the de-positioned fused token grid of (left, right);
/// `desc_left`, `desc_right` (H/4, W/4, 128) the descriptor maps (encoder on (I, I),
/// phase-averaged); with --head also `disparity` (H/4, W/4) in patch columns. Without
/// --left/--right a built-in procedural scene (160x96) is used.
#[derive(Args)]
pub struct ReferenceArgs {
    /// Left image (PNG, PPM/PGM or JPEG; gray or colour).
    #[arg(long, requires = "right")]
    left: Option<PathBuf>,
    /// Right image, the same size as the left.
    #[arg(long, requires = "left")]
    right: Option<PathBuf>,
    #[command(flatten)]
    profile: MeasureProfile,
    /// Encoder exported by `python -m bino_train.export`; the default is the checkout's shipped one.
    #[arg(long, default_value_os_t = checkout::path(checkout::ENCODER_ONNX))]
    onnx: PathBuf,
    /// Shared head exported by `python -m bino_train.head`; adds `disparity` to the archive.
    ///
    /// `disparity` is (H/4, W/4), in patch columns.
    #[arg(long)]
    head: Option<PathBuf>,
    /// Output archive (.npz).
    #[arg(long)]
    out: PathBuf,
}

/// Runs the verb.
pub fn run(args: ReferenceArgs) -> Result<()> {
    let ReferenceArgs {
        left,
        right,
        profile,
        onnx,
        head,
        out,
    } = args;
    reference(left.zip(right), profile.profile, &onnx, head.as_deref(), &out)
}

fn reference(
    files: Option<(PathBuf, PathBuf)>,
    profile: Profile,
    onnx: &Path,
    head: Option<&Path>,
    out: &Path,
) -> Result<()> {
    ensure!(
        out.extension().is_some_and(|e| e == "npz"),
        "output {} must end in .npz (the reference writes a NumPy archive)",
        out.display()
    );
    let progress = Progress::new(false);
    progress.status("reading the pair");
    let (left, right, source) = match files {
        Some((l, r)) => {
            let (left, right) = (load_gray(&l)?, load_gray(&r)?);
            let source = format!("{} + {}", l.display(), r.display());
            (left, right, source)
        }
        None => {
            let scene = synthetic::default_scene(160, 96);
            (scene.left, scene.right, "built-in procedural scene".to_string())
        }
    };
    let (left, right) = apply_profile(&left, &right, profile, &source)?;
    progress.status("loading the float models (tract-onnx)");
    let mut encoder = ReferenceEncoder::load(onnx)?;
    let mut head = head.map(ReferenceHead::load).transpose()?;
    let started = Instant::now();
    progress.status("encoder on (left, right)");
    let tokens = encoder.tokens(&left, &right)?;
    progress.status("encoder on (left, left)");
    let desc_left = encoder.descriptors(&left)?;
    progress.status("encoder on (right, right)");
    let desc_right = encoder.descriptors(&right)?;
    let elapsed = started.elapsed();
    progress.status("shared head");
    let disparity = head
        .as_mut()
        .map(|h| h.disparity(&desc_left, &desc_right))
        .transpose()?;

    let view = |v: &View| Array::new(vec![v.height, v.width], v.pixels.clone());
    let map = |m: &FeatureMap| Array::new(vec![m.rows, m.cols, m.dim], m.data.clone());
    let mut arrays = vec![
        ("left", view(&left)?),
        ("right", view(&right)?),
        ("tokens", map(&tokens)?),
        ("desc_left", map(&desc_left)?),
        ("desc_right", map(&desc_right)?),
    ];
    if let Some(d) = &disparity {
        arrays.push(("disparity", Array::new(vec![d.rows, d.cols], d.data.clone())?));
    }
    let named: Vec<(&str, &Array)> = arrays.iter().map(|(n, a)| (*n, a)).collect();
    progress.status("writing the archive");
    bino_host::io::files::write_atomic(out, |file| npz::write(file, &named))?;
    progress.finish();
    println!(
        "{source}: {}x{} at profile {profile}; tokens {}x{}x{}, descriptors {}x{}x{}; \
         3 encoder passes in {:.2} s (tract-onnx, {})",
        left.width,
        left.height,
        tokens.rows,
        tokens.cols,
        tokens.dim,
        desc_left.rows,
        desc_left.cols,
        desc_left.dim,
        elapsed.as_secs_f64(),
        encoder.path().display()
    );
    println!("wrote {}", out.display());
    Ok(())
}

fn apply_profile(left: &GrayImage, right: &GrayImage, profile: Profile, source: &str) -> Result<(View, View)> {
    if (left.width, left.height) != (right.width, right.height) {
        bail!(
            "{source}: left is {}x{} but right is {}x{}; a rectified pair has views of one size",
            left.width,
            left.height,
            right.width,
            right.height
        );
    }
    let apply = |v: &GrayImage| profile.apply(v).with_context(|| source.to_string());
    Ok((apply(left)?, apply(right)?))
}
