//! The pixel refinement of a readout (issue 14) on the host: a token-grid disparity (patch
//! columns, `f32`) to Q8 patch columns, then [`bino_core::refine::refine_map`] on the pair's
//! 8-bit gray views, then pixels. Every readout's `+ref` variant comes from here
//! ([`crate::readout::MethodMaps::pixels`]), for the int8 and the float precision alike: one
//! integer refinement, one definition.
//!
//! The views are the profile's views as the pipeline encodes them ([`crate::int8::to_u8`] of
//! the [`View`]'s `[0, 1]` values), whichever precision made the token grid.

use anyhow::{ensure, Result};
use bino_core::config::{CELL_W, PATCH_H};
use bino_core::matching::DISPARITY_FRAC_BITS;
use bino_core::refine::{refine_map, scratch_len, RefineParams};

use crate::eval::DisparityMap;
use crate::int8::to_u8;
use crate::profile::View;

/// The two views of a pair as the pipeline reads them: 8-bit gray, row-major, one size.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct GrayViews {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Left view, `width * height` pixels.
    pub left: Vec<u8>,
    /// Right view, the same size.
    pub right: Vec<u8>,
}

impl GrayViews {
    /// The 8-bit views of two profile views (the pipeline's input); they must be one size.
    pub fn from_views(left: &View, right: &View) -> Result<Self> {
        ensure!(
            (left.width, left.height) == (right.width, right.height),
            "the views differ in size: {}x{} and {}x{}",
            left.width,
            left.height,
            right.width,
            right.height
        );
        Ok(Self {
            width: left.width,
            height: left.height,
            left: to_u8(&left.pixels),
            right: to_u8(&right.pixels),
        })
    }
}

/// A token-grid disparity in patch columns as the core's Q8 patch columns: `256 d` rounded
/// half away from zero, negative values and NaN to 0, values above `u16::MAX` to `u16::MAX`.
/// The int8 readouts' maps are Q8 values / 256, so they come back exactly.
pub fn tokens_q8(map: &DisparityMap) -> Vec<u16> {
    let unit = (1u32 << DISPARITY_FRAC_BITS) as f32;
    // `as` saturates at the type's bounds and maps NaN to 0.
    map.values.iter().map(|&d| (d * unit).round() as u16).collect()
}

/// The refined pixel disparity (px) of a token grid on `views`, with
/// [`RefineParams::DEFAULT`]. The grid must be the views' (`H / 4` x `W / 4` cells); the result
/// has the views' size, as the bilinear upsampling of the unrefined readout.
pub fn refine_pixels(tokens: &DisparityMap, views: &GrayViews) -> Result<DisparityMap> {
    refine_pixels_with(tokens, views, &RefineParams::DEFAULT)
}

/// [`refine_pixels`] with explicit parameters.
pub fn refine_pixels_with(tokens: &DisparityMap, views: &GrayViews, params: &RefineParams) -> Result<DisparityMap> {
    let (width, height) = (views.width, views.height);
    ensure!(
        tokens.width * CELL_W == width && tokens.height * PATCH_H == height,
        "a {}x{} token grid does not cover {width}x{height} views",
        tokens.width,
        tokens.height
    );
    let mut scratch = vec![0u32; scratch_len(width, params)];
    let mut out = vec![0u16; width * height];
    refine_map(
        &views.left,
        &views.right,
        width,
        &tokens_q8(tokens),
        params,
        &mut scratch,
        &mut out,
    )
    .map_err(anyhow::Error::msg)?;
    let unit = (1u32 << DISPARITY_FRAC_BITS) as f32;
    Ok(DisparityMap {
        width,
        height,
        values: out.iter().map(|&d| d as f32 / unit).collect(),
    })
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
    fn q8_rounding_is_defined_for_every_float() {
        let got = tokens_q8(&map(
            8,
            vec![
                0.5 / 256.0,
                1.49 / 256.0,
                -0.3,
                f32::NAN,
                1e9,
                2.0,
                f32::INFINITY,
                3.0 / 512.0,
            ],
        ));
        assert_eq!(got, vec![1, 1, 0, 0, u16::MAX, 512, u16::MAX, 2]);
        // Q8 maps (what the int8 pipeline emits) come back exactly.
        let q8: Vec<u16> = (0..=u16::MAX).step_by(7).collect();
        let values = q8.iter().map(|&d| d as f32 / 256.0).collect();
        assert_eq!(tokens_q8(&map(q8.len(), values)), q8);
    }

    #[test]
    fn the_refinement_is_the_cores_refine_map() {
        let (w, h) = (24, 12);
        let left: Vec<u8> = (0..w * h).map(|i| ((i * 97 + i / w * 31) % 251) as u8).collect();
        let right: Vec<u8> = (0..w * h).map(|i| left[(i / w) * w + (i % w + 3).min(w - 1)]).collect();
        let views = GrayViews {
            width: w,
            height: h,
            left,
            right,
        };
        let q8: Vec<u16> = (0..18).map(|i| (150 + i * 23 % 90) as u16).collect();
        let grid = map(6, q8.iter().map(|&d| d as f32 / 256.0).collect());
        let host = refine_pixels(&grid, &views).unwrap();

        let params = RefineParams::DEFAULT;
        let mut scratch = vec![0u32; scratch_len(w, &params)];
        let mut core = vec![0u16; w * h];
        refine_map(&views.left, &views.right, w, &q8, &params, &mut scratch, &mut core).unwrap();
        assert_eq!((host.width, host.height), (w, h));
        let core: Vec<f32> = core.iter().map(|&d| d as f32 / 256.0).collect();
        assert_eq!(host.values, core);
        assert!(
            host.values.iter().filter(|&&d| (d - 3.0).abs() < 0.25).count() > w * h / 2,
            "finds the 3 px shift"
        );

        let wrong = map(5, vec![1.0; 15]);
        assert!(refine_pixels(&wrong, &views).is_err(), "grid of another size");
    }
}
