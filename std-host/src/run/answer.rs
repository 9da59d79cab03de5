//! `bino run`'s answer at the input's size: the readout's pixel disparities, computed at the
//! profile's size, resampled to the images the user gave and expressed in their pixels, with a
//! validity mask: pixels whose cell the readout's own check keeps and whose view holds texture
//! there. A flat or textureless region, an occlusion the check rejects, are invalid; the
//! disparity stays dense (every pixel finite) unless asked to mark them (`--invalid inf`).

use anyhow::{ensure, Result};
use bino_core::config::{BAND_ROWS, CELL_W, PATCH_H};

use crate::data::profile::{Profile, ProfileSize};
use crate::eval::DisparityMap;

/// The smallest step between horizontally neighbouring grey levels (0-255) that makes a 4x4
/// cell textured: below it no matcher has anything to match, whatever its check says.
pub const TEXTURE_MIN_STEP: u8 = 3;

/// Upscaling beyond which the answer is mostly invented: the warning's threshold.
pub const MAX_UPSCALE: f32 = 2.0;

/// What `--invalid` writes in `disparity.pfm` for invalid pixels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum InvalidPixels {
    /// The readout's value (dense; the validity mask says which pixels to trust).
    #[default]
    Keep,
    /// +infinity, Middlebury's convention for unknown disparity.
    Inf,
}

/// Which 4x4 cells of `left` (`width x height` grey pixels, whole cells) hold texture: some pair
/// of horizontal neighbours inside the cell, or across its left edge, differs by at least
/// [`TEXTURE_MIN_STEP`].
pub fn textured_cells(left: &[u8], width: usize, height: usize) -> Result<Vec<bool>> {
    ensure!(
        width > 0 && width.is_multiple_of(CELL_W) && height.is_multiple_of(PATCH_H) && left.len() == width * height,
        "texture: a {width}x{height} view of {} pixels is not whole 4x4 cells",
        left.len()
    );
    let cols = width / CELL_W;
    let mut textured = vec![false; cols * (height / PATCH_H)];
    for (y, row) in left.chunks_exact(width).enumerate() {
        for (x, pair) in row.windows(2).enumerate() {
            if pair[0].abs_diff(pair[1]) >= TEXTURE_MIN_STEP {
                // The step lies between pixels x and x + 1: it textures both their cells.
                let at = (y / PATCH_H) * cols;
                textured[at + x / CELL_W] = true;
                textured[at + (x + 1) / CELL_W] = true;
            }
        }
    }
    Ok(textured)
}

/// The answer resampled from the profile's size to the input's `input` (width, height):
/// bilinear for the disparity, scaled into input pixels, nearest for the mask. The profile
/// resized the input by the same factor both ways (its height rounded) and dropped the bottom
/// rows to a multiple of 4; rows below the computed ones take the last computed row.
pub fn to_input_size(
    disparity: &DisparityMap,
    valid: &[bool],
    profile: Profile,
    input: (usize, usize),
) -> Result<(DisparityMap, Vec<bool>)> {
    let (w, h) = input;
    let ProfileSize { resized, kept_rows } = profile.size(w, h)?;
    ensure!(
        (disparity.width, disparity.height) == (resized.0, kept_rows) && valid.len() == disparity.values.len(),
        "the answer is {}x{} with {} mask cells, the profile computes {}x{kept_rows}",
        disparity.width,
        disparity.height,
        valid.len(),
        resized.0
    );
    if (w, h) == (disparity.width, disparity.height) {
        return Ok((disparity.clone(), valid.to_vec()));
    }
    let (sx, sy) = (resized.0 as f32 / w as f32, resized.1 as f32 / h as f32);
    // Input pixel centre -> computed pixel coordinate, clamped to the computed rows.
    let source = |i: usize, scale: f32, last: usize| ((i as f32 + 0.5) * scale - 0.5).clamp(0.0, last as f32);
    let (cw, ch) = (disparity.width, disparity.height);
    let at = |x: usize, y: usize| disparity.values[y * cw + x];
    let unit = w as f32 / resized.0 as f32;
    let mut values = Vec::with_capacity(w * h);
    let mut mask = Vec::with_capacity(w * h);
    for y in 0..h {
        let fy = source(y, sy, ch - 1);
        let (y0, ty) = (fy.floor() as usize, fy.fract());
        let y1 = (y0 + 1).min(ch - 1);
        for x in 0..w {
            let fx = source(x, sx, cw - 1);
            let (x0, tx) = (fx.floor() as usize, fx.fract());
            let x1 = (x0 + 1).min(cw - 1);
            let top = at(x0, y0) * (1.0 - tx) + at(x1, y0) * tx;
            let bottom = at(x0, y1) * (1.0 - tx) + at(x1, y1) * tx;
            values.push((top * (1.0 - ty) + bottom * ty) * unit);
            let (nx, ny) = (fx.round() as usize, fy.round() as usize);
            mask.push(valid[ny.min(ch - 1) * cw + nx.min(cw - 1)]);
        }
    }
    Ok((
        DisparityMap {
            width: w,
            height: h,
            values,
        },
        mask,
    ))
}

/// `disparity` with the pixels `valid` rejects set to +infinity.
pub fn mark_invalid(disparity: &DisparityMap, valid: &[bool]) -> DisparityMap {
    let values = disparity
        .values
        .iter()
        .zip(valid)
        .map(|(&d, &v)| if v { d } else { f32::INFINITY })
        .collect();
    DisparityMap { values, ..*disparity }
}

/// What a user should know before trusting the answer: an input smaller than one band of the
/// encoder, or upscaled by more than [`MAX_UPSCALE`] to the computed size.
pub fn warnings(input: (usize, usize), computed: (usize, usize)) -> Vec<String> {
    let mut out = Vec::new();
    let upscale = computed.0 as f32 / input.0.max(1) as f32;
    if upscale > MAX_UPSCALE {
        out.push(format!(
            "the {}x{} input is upscaled {upscale:.1}x to {}x{}: most of the answer is interpolated \
             (--profile native keeps the input's size)",
            input.0, input.1, computed.0, computed.1
        ));
    }
    if input.1 < BAND_ROWS {
        out.push(format!(
            "the {}x{} input is shorter than one {BAND_ROWS}-row band: the encoder sees less context \
             than it was trained with",
            input.0, input.1
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flat_view_has_no_texture_and_one_step_textures_both_cells() {
        let (w, h) = (16, 8);
        assert!(textured_cells(&[128; 128], w, h).unwrap().iter().all(|&t| !t));
        let mut view = vec![128u8; w * h];
        view[2 * w + 7] = 128 + TEXTURE_MIN_STEP; // the step 6 -> 7 (cell 1) and 7 -> 8 (cells 1, 2)
        let textured = textured_cells(&view, w, h).unwrap();
        assert_eq!(textured, [false, true, true, false, false, false, false, false]);
        view[2 * w + 7] = 128 + TEXTURE_MIN_STEP - 1;
        assert!(textured_cells(&view, w, h).unwrap().iter().all(|&t| !t));
        assert!(textured_cells(&view, 14, 8).is_err());
    }

    #[test]
    fn the_answer_comes_at_the_inputs_size_in_its_pixels() {
        // 640x192 at w320: computed 320x96, every disparity doubles.
        let computed = DisparityMap {
            width: 320,
            height: 96,
            values: (0..320 * 96).map(|i| (i % 320) as f32 / 32.0).collect(),
        };
        let valid: Vec<bool> = (0..320 * 96).map(|i| i % 320 < 160).collect();
        let (d, v) = to_input_size(&computed, &valid, Profile::W320, (640, 192)).unwrap();
        assert_eq!((d.width, d.height, v.len()), (640, 192, 640 * 192));
        // Input column 101 sits on computed column 50.25: disparity 50.25 / 32 * 2.
        let got = d.values[5 * 640 + 101];
        assert!((got - 50.25 / 16.0).abs() < 1e-4, "{got}");
        assert!(v[10 * 640 + 300] && !v[10 * 640 + 340]);
        // A profile that keeps the size changes nothing.
        let (same, _) = to_input_size(&computed, &valid, Profile::Native, (320, 96)).unwrap();
        assert_eq!(same, computed);
        // Rows the profile dropped (1242x375 -> 320x97, 96 kept) take the last computed row.
        let (d, _) = to_input_size(&computed, &valid, Profile::W320, (1242, 375)).unwrap();
        assert_eq!((d.width, d.height), (1242, 375));
        assert_eq!(d.values[374 * 1242 + 600], d.values[372 * 1242 + 600]);
        assert!(to_input_size(&computed, &valid, Profile::W320, (1242, 500)).is_err());
    }

    #[test]
    fn invalid_pixels_become_infinite_and_odd_inputs_are_named() {
        let map = DisparityMap {
            width: 2,
            height: 1,
            values: vec![1.0, 2.0],
        };
        assert_eq!(mark_invalid(&map, &[true, false]).values, [1.0, f32::INFINITY]);
        assert!(warnings((4, 4), (320, 320))[0].contains("upscaled 80.0x"));
        assert!(warnings((4, 4), (320, 320))[1].contains("shorter than one 48-row band"));
        assert!(warnings((640, 480), (320, 240)).is_empty());
    }
}
