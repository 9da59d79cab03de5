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

use std::path::PathBuf;

use anyhow::{ensure, Context, Result};
use bino_core::config::CELL_W;

use crate::blob_writer::BlobWriter;
use crate::float_head::FloatHead;
use crate::float_weights::FloatEncoder;
use crate::profile::Profile;

/// What `bino quantize` reads.
#[derive(Debug, Clone)]
pub struct QuantizeOptions {
    /// The float encoder (`python -m bino_train.export`).
    pub encoder: PathBuf,
    /// The float shared head (`python -m bino_train.head`), quantised too when given.
    pub head: Option<PathBuf>,
    /// Train pairs whose float descriptor maps calibrate the head.
    pub head_calib_pairs: usize,
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
    /// How the head's correlation format was chosen (with `--head`).
    pub head_choice: Option<HeadChoice>,
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
    let build = |head: Option<(&FloatHead, &head::HeadFormats)>| -> Result<Vec<u8>> {
        let mut writer = BlobWriter::new();
        encoder::write_encoder(&float, &formats, opts.max_width / CELL_W, &mut writer)?;
        if let Some((float_head, head_formats)) = head {
            head::write_head(float_head, head_formats, formats.descriptor, &mut writer)?;
        }
        Ok(writer.finish())
    };
    let Some(head_onnx) = &opts.head else {
        return Ok((
            build(None)?,
            QuantizeReport {
                bands: stats.bands,
                formats,
                head_choice: None,
            },
        ));
    };
    let float_head = FloatHead::from_onnx(head_onnx)?;
    let maps = head::calibration_maps(&opts.encoder, &opts.data, opts.profile, opts.head_calib_pairs)?;
    let head_stats = head::collect(head_onnx, &maps).context("head calibration")?;
    // Each candidate blob runs the int8 head on the (train-split) calibration maps.
    let mut best: Option<(f64, Vec<u8>)> = None;
    let mut choice = HeadChoice {
        tried: Vec::new(),
        chosen: 0,
    };
    for (label, head_formats) in head::HeadFormats::candidates(&head_stats) {
        let blob = build(Some((&float_head, &head_formats)))?;
        let model = crate::int8::Int8Model::from_bytes(blob, &label)?;
        let error = head::disagreement(&model, &maps, &head_stats.float_disparity, formats.descriptor)
            .with_context(|| format!("head candidate {label}"))?;
        if best.as_ref().is_none_or(|(e, _)| error < *e) {
            choice.chosen = choice.tried.len();
            best = Some((error, model.bytes().to_vec()));
        }
        choice.tried.push((label, error));
    }
    let (_, blob) = best.context("no head format candidates")?;
    Ok((
        blob,
        QuantizeReport {
            bands: stats.bands,
            formats,
            head_choice: Some(choice),
        },
    ))
}
