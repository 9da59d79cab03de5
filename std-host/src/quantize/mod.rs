//! Post-training quantisation: float ONNX models + calibration on train-split pairs -> the
//! int8 weight blob the engine runs (docs/int8-model.md).
//!
//! Weights: symmetric int8 per output channel. Activations: formats chosen from the float
//! model's intermediate tensors computed by tract on calibration bands (see [`formats`] for the
//! range choices: per-channel percentiles for the residual stream, MSE-optimal clipping for
//! the rest).

pub mod calibrate;
pub mod encoder;
pub mod formats;
pub mod head;
pub mod scales;

use crate::data::nuisance::Nuisance;
use std::path::PathBuf;

use anyhow::{ensure, Context, Result};
use bino_core::config::CELL_W;

use bino_core::model::ids::HeadKind;

use crate::data::profile::Profile;
use crate::float::head::FloatHead;
use crate::float::weights::FloatEncoder;
use crate::int8::blob_writer::BlobWriter;

/// What `bino quantize` reads.
#[derive(Debug, Clone)]
pub struct QuantizeOptions {
    /// The float encoder (`python -m bino_train.export`).
    pub encoder: PathBuf,
    /// The float shared head (`python -m bino_train.head`), quantised too when given.
    pub head: Option<PathBuf>,
    /// The float native-pathway head (`python -m bino_train.head` of a `--pathway native`
    /// checkpoint, pair features `[a, b]`), quantised too when given.
    pub native_head: Option<PathBuf>,
    /// Train pairs whose float input maps calibrate each head.
    pub head_calib_pairs: usize,
    /// Also calibrate the heads on each of these pairs with its right view under each of these
    /// nuisances (`bino eval --nuisance`'s images): an int8 head chosen on clean maps alone lost
    /// 10 % more epe than the float head under one-view blur.
    pub head_calib_nuisances: Vec<Nuisance>,
    /// Folder with `PAIRS.tsv`; only its train split is used.
    pub data: PathBuf,
    /// Resolution profile of the calibration bands.
    pub profile: Profile,
    /// Train pairs to calibrate on (both views of each, one band per view).
    pub calib_pairs: usize,
    /// Widest band the blob will support, in pixels (sizes the RoPE column table).
    pub max_width: usize,
}

/// What a quantisation did.
#[derive(Debug, Clone)]
pub struct QuantizeReport {
    /// Calibration bands run through the float model.
    pub bands: usize,
    /// The chosen activation formats.
    pub formats: formats::EncoderFormats,
    /// How the shared head's correlation format was chosen (with `--head`).
    pub head_choice: Option<HeadChoice>,
    /// How the native head's correlation format was chosen (with `--native-head`).
    pub native_head_choice: Option<HeadChoice>,
}

/// The head format candidates and their measured disagreement with the float head on the
/// train-split calibration maps; the lowest wins.
#[derive(Debug, Clone)]
pub struct HeadChoice {
    /// (label, mean |int8 - float| disparity in patch columns), in the order tried.
    pub tried: Vec<(String, f64)>,
    /// Index of the winner in `tried`.
    pub chosen: usize,
}

/// Builds the blob; `progress(done, total)` is called after each calibration band.
pub fn quantize(opts: &QuantizeOptions, progress: impl FnMut(usize, usize)) -> Result<(Vec<u8>, QuantizeReport)> {
    ensure!(
        opts.max_width >= CELL_W && opts.max_width.is_multiple_of(CELL_W),
        "--max-width {} must be a positive multiple of {CELL_W}",
        opts.max_width
    );
    let float = FloatEncoder::from_onnx(&opts.encoder)?;
    let bands = calibrate::calibration_bands(&opts.data, opts.profile, opts.calib_pairs)?;
    let stats = calibrate::collect(&opts.encoder, &bands, progress).context("calibration")?;
    let formats = formats::EncoderFormats::choose(&stats);
    let build = |heads: &[(&FloatHead, &head::HeadFormats)]| -> Result<Vec<u8>> {
        let mut writer = BlobWriter::new();
        encoder::write_encoder(&float, &formats, opts.max_width / CELL_W, &mut writer)?;
        for (float_head, head_formats) in heads {
            head::write_head(float_head, head_formats, formats.descriptor, &mut writer)?;
        }
        Ok(writer.finish())
    };
    // Each head's formats are chosen with the heads before it fixed.
    let mut chosen: Vec<(FloatHead, head::HeadFormats)> = Vec::new();
    let mut choices = [None, None];
    for (slot, (path, kind)) in [(&opts.head, HeadKind::Export), (&opts.native_head, HeadKind::Native)]
        .into_iter()
        .enumerate()
    {
        let Some(path) = path else { continue };
        let float_head = FloatHead::from_onnx(path)?;
        ensure!(
            float_head.kind == kind,
            "{} is the {} pathway's head, given as the {} pathway's",
            path.display(),
            float_head.kind.pathway(),
            kind.pathway()
        );
        let maps = head::calibration_maps(
            &opts.encoder,
            kind,
            &opts.data,
            opts.profile,
            opts.head_calib_pairs,
            &opts.head_calib_nuisances,
        )?;
        let head_stats =
            head::collect(path, kind, &maps).with_context(|| format!("{} head calibration", kind.pathway()))?;
        // Each candidate blob runs the int8 head on the (train-split) calibration maps.
        let mut best: Option<(f64, head::HeadFormats)> = None;
        let mut choice = HeadChoice {
            tried: Vec::new(),
            chosen: 0,
        };
        for (label, head_formats) in head::HeadFormats::candidates(&head_stats) {
            let mut heads: Vec<_> = chosen.iter().map(|(h, f)| (h, f)).collect();
            heads.push((&float_head, &head_formats));
            let model = crate::int8::Int8Model::from_bytes(build(&heads)?, &label)?;
            let error = head::disagreement(&model, kind, &maps, &head_stats.float_disparity, formats.descriptor)
                .with_context(|| format!("{} head candidate {label}", kind.pathway()))?;
            if best.as_ref().is_none_or(|(e, _)| error < *e) {
                choice.chosen = choice.tried.len();
                best = Some((error, head_formats));
            }
            choice.tried.push((label, error));
        }
        let (_, head_formats) = best.context("no head format candidates")?;
        chosen.push((float_head, head_formats));
        choices[slot] = Some(choice);
    }
    let heads: Vec<_> = chosen.iter().map(|(h, f)| (h, f)).collect();
    let [head_choice, native_head_choice] = choices;
    Ok((
        build(&heads)?,
        QuantizeReport {
            bands: stats.bands,
            formats,
            head_choice,
            native_head_choice,
        },
    ))
}
