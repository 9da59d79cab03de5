//! `bino run`: the int8 pipeline on any rectified pair: disparity as a colour picture, as raw
//! float32 (PFM) and the left-right consistency mask, with timings and arena use.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{ensure, Context, Result};
use bino_core::config::{BAND_ROWS, DIM};
use bino_core::model::{encoder, head};
use bino_core::sgm::Penalties;

use crate::colour::colourise;
use crate::eval::{fill_invalid, upsample_disparity, DisparityMap, PIXELS_PER_PATCH_COLUMN};
use crate::image_io::load_gray;
use crate::int8::{match_rows, sgm_rows, Int8Model};
use crate::profile::Profile;
use crate::readout_eval::Readout;

/// What `bino run` runs on and where it writes.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Left view.
    pub left: PathBuf,
    /// Right view.
    pub right: PathBuf,
    /// Resolution profile (`native` needs sides that are multiples of 4).
    pub profile: Profile,
    /// Int8 weight blob.
    pub blob: PathBuf,
    /// Readout.
    pub readout: Readout,
    /// Disparity candidates of nolink and sgm, in patch columns.
    pub max_cols: usize,
    /// SGM penalties.
    pub penalties: Penalties,
    /// Left-right check tolerance in patch columns.
    pub lr_max_diff: f32,
    /// Output folder.
    pub out: PathBuf,
}

/// What a run measured and wrote.
#[derive(Debug, Clone)]
pub struct RunReport {
    /// Size the pipeline ran at.
    pub width: usize,
    /// Height it ran at.
    pub height: usize,
    /// % of pixels that passed the left-right check.
    pub density: f64,
    /// Wall time of each step.
    pub timings: Vec<(&'static str, Duration)>,
    /// Encoder arena bytes for one band at this width.
    pub encoder_arena_bytes: usize,
    /// Head arena bytes at this width.
    pub head_arena_bytes: usize,
    /// Files written.
    pub files: Vec<PathBuf>,
}

/// Runs the pipeline; `progress` hears about each step before it starts.
pub fn run_pair(opts: &RunOptions, mut progress: impl FnMut(&str)) -> Result<RunReport> {
    let mut timings = Vec::new();
    let mut step = |name: &'static str, timings: &mut Vec<(&'static str, Duration)>| {
        progress(name);
        timings.push((name, Duration::ZERO));
        Instant::now()
    };
    let started = step("loading the pair and the blob", &mut timings);
    let (left_image, right_image) = (load_gray(&opts.left)?, load_gray(&opts.right)?);
    ensure!(
        (left_image.width, left_image.height) == (right_image.width, right_image.height),
        "the views differ in size: {} is {}x{}, {} is {}x{}",
        opts.left.display(),
        left_image.width,
        left_image.height,
        opts.right.display(),
        right_image.width,
        right_image.height
    );
    let left = opts
        .profile
        .apply(&left_image)
        .with_context(|| format!("{}", opts.left.display()))?;
    let right = opts
        .profile
        .apply(&right_image)
        .with_context(|| format!("{}", opts.right.display()))?;
    let model = Int8Model::load(&opts.blob)?;
    finish(&mut timings, started);

    let started = step("int8 encoder, both views", &mut timings);
    let (rows, cols, codes_left) = model.descriptor_codes(&left).context("left view")?;
    let (_, _, codes_right) = model.descriptor_codes(&right).context("right view")?;
    finish(&mut timings, started);

    let started = step("readout and left-right check", &mut timings);
    let tokens = readout(opts, &model, &codes_left, &codes_right, rows, cols)?;
    // The right view's disparity from the same descriptors: with both rows mirrored, right
    // cell q's candidates (left cells q + k) sit k columns to the left, so the mirrored right
    // view matches like a left view.
    let mirrored_right = match_rows(
        &mirror(&codes_right, cols),
        &mirror(&codes_left, cols),
        rows,
        cols,
        opts.max_cols,
    );
    let right_tokens = mirrored_right.map(|m| unmirror(&m))?;
    let token_valid = lr_consistent(&tokens, &right_tokens, opts.lr_max_diff);
    let disparity = upsample_disparity(&tokens);
    let valid = pixel_mask(&token_valid, cols, disparity.width, disparity.height);
    let filled = fill_invalid(&disparity, &valid);
    finish(&mut timings, started);

    let started = step("writing outputs", &mut timings);
    let files = write_outputs(&opts.out, &filled, &valid)?;
    finish(&mut timings, started);
    let density = 100.0 * valid.iter().filter(|&&v| v).count() as f64 / valid.len().max(1) as f64;
    Ok(RunReport {
        width: left.width,
        height: left.height,
        density,
        timings,
        encoder_arena_bytes: encoder::arena_bytes(BAND_ROWS, left.width),
        head_arena_bytes: head::arena_bytes(cols),
        files,
    })
}

fn finish(timings: &mut [(&'static str, Duration)], started: Instant) {
    if let Some(last) = timings.last_mut() {
        last.1 = started.elapsed();
    }
}

fn readout(opts: &RunOptions, model: &Int8Model, l: &[i8], r: &[i8], rows: usize, cols: usize) -> Result<DisparityMap> {
    match opts.readout {
        Readout::Nolink => match_rows(l, r, rows, cols, opts.max_cols),
        Readout::Sgm => sgm_rows(l, r, rows, cols, opts.max_cols, opts.penalties),
        Readout::Head => Ok(DisparityMap {
            width: cols,
            height: rows,
            values: model.head(l, r, rows, cols)?.disparity,
        }),
    }
}

/// Descriptor rows with their cells in reverse order.
fn mirror(codes: &[i8], cols: usize) -> Vec<i8> {
    let mut out = Vec::with_capacity(codes.len());
    for row in codes.chunks_exact(cols * DIM) {
        for cell in row.chunks_exact(DIM).rev() {
            out.extend_from_slice(cell);
        }
    }
    out
}

fn unmirror(map: &DisparityMap) -> DisparityMap {
    let mut values = Vec::with_capacity(map.values.len());
    for row in map.values.chunks_exact(map.width.max(1)) {
        values.extend(row.iter().rev());
    }
    DisparityMap { values, ..map.clone() }
}

/// Left cell p with disparity d is consistent when the right cell p - round(d) points back
/// within `max_diff` columns.
pub fn lr_consistent(left: &DisparityMap, right: &DisparityMap, max_diff: f32) -> Vec<bool> {
    let cols = left.width;
    left.values
        .iter()
        .enumerate()
        .map(|(i, &d)| {
            let (row, p) = (i / cols.max(1), i % cols.max(1));
            let q = p as i64 - d.round() as i64;
            q >= 0
                && right
                    .values
                    .get(row * cols + q as usize)
                    .is_some_and(|&dr| (dr - d).abs() <= max_diff)
        })
        .collect()
}

/// Token-grid validity to pixels (each cell covers a 4x4 block).
fn pixel_mask(tokens: &[bool], cols: usize, width: usize, height: usize) -> Vec<bool> {
    let cell = PIXELS_PER_PATCH_COLUMN;
    (0..width * height)
        .map(|i| {
            let (y, x) = (i / width, i % width);
            tokens
                .get((y / cell) * cols + (x / cell).min(cols.saturating_sub(1)))
                .copied()
                .unwrap_or(false)
        })
        .collect()
}

fn write_outputs(out: &Path, disparity: &DisparityMap, valid: &[bool]) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let (w, h) = (disparity.width, disparity.height);
    let max = disparity.values.iter().cloned().fold(1.0f32, f32::max);
    let colour = image::RgbImage::from_raw(w as u32, h as u32, colourise(&disparity.values, max))
        .context("disparity picture size")?;
    let png = out.join("disparity.png");
    colour
        .save(&png)
        .with_context(|| format!("cannot write {}", png.display()))?;
    let mask = image::GrayImage::from_raw(
        w as u32,
        h as u32,
        valid.iter().map(|&v| if v { 255 } else { 0 }).collect(),
    )
    .context("mask size")?;
    let mask_path = out.join("lr_mask.png");
    mask.save(&mask_path)
        .with_context(|| format!("cannot write {}", mask_path.display()))?;
    let pfm = out.join("disparity.pfm");
    std::fs::write(&pfm, pfm_bytes(disparity)).with_context(|| format!("cannot write {}", pfm.display()))?;
    Ok(vec![png, pfm, mask_path])
}

/// Grayscale PFM: header, then float32 little-endian rows from the bottom up.
pub fn pfm_bytes(map: &DisparityMap) -> Vec<u8> {
    let mut bytes = Vec::with_capacity(32 + map.values.len() * 4);
    let _ = write!(bytes, "Pf\n{} {}\n-1.0\n", map.width, map.height);
    for row in map.values.chunks_exact(map.width.max(1)).rev() {
        for v in row {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    bytes
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(width: usize, values: Vec<f32>) -> DisparityMap {
        DisparityMap {
            width,
            height: values.len() / width,
            values,
        }
    }

    #[test]
    fn lr_check_keeps_mutual_matches_only() {
        // Left cell 0 and right cell 0 agree at 0. Left cell 1 (d 0) lands on right cell 1,
        // which says 1: rejected. Left cells 2 and 3 (d 1) land on right cells 1 and 2, which
        // say 1 and 3: only cell 2 is kept.
        let left = map(4, vec![0.0, 0.0, 1.0, 1.2]);
        let right = map(4, vec![0.0, 1.0, 3.0, 0.0]);
        assert_eq!(lr_consistent(&left, &right, 0.5), [true, false, true, false]);
        // A disparity pointing outside the view is inconsistent.
        let left = map(2, vec![3.0, 0.0]);
        assert_eq!(lr_consistent(&left, &map(2, vec![0.0, 0.0]), 1.0), [false, true]);
    }

    #[test]
    fn mirroring_twice_is_the_identity() {
        let codes: Vec<i8> = (0..2 * 3 * DIM).map(|i| (i % 251) as i8).collect();
        assert_eq!(mirror(&mirror(&codes, 3), 3), codes);
        let m = map(3, vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0]);
        assert_eq!(unmirror(&unmirror(&m)), m);
        assert_eq!(unmirror(&m).values, [3.0, 2.0, 1.0, 6.0, 5.0, 4.0]);
    }

    #[test]
    fn pfm_has_the_header_and_bottom_up_rows() {
        let bytes = pfm_bytes(&map(2, vec![1.0, 2.0, 3.0, 4.0]));
        let header = b"Pf\n2 2\n-1.0\n";
        assert_eq!(&bytes[..header.len()], header);
        let first = f32::from_le_bytes(bytes[header.len()..header.len() + 4].try_into().unwrap());
        assert_eq!(first, 3.0, "the bottom row comes first");
        assert_eq!(bytes.len(), header.len() + 16);
    }
}
