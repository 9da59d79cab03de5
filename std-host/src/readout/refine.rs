//! The pixel refinement of a readout (issue 14) on the host: a token-grid disparity (patch
//! columns, `f32`) to Q8 patch columns, then the core's whole-map refinement on the pair's
//! 8-bit gray views ([`bino_core::refine::sharpness::refine_map_equalised`], the shipped one, or
//! [`bino_core::refine::refine_map`] without equalisation), then pixels. Every readout's `+ref` variant comes from here
//! ([`crate::readout::MethodMaps::pixels`]), for the int8 and the float precision alike: one
//! integer refinement, one definition.
//!
//! The views are the profile's views as the pipeline encodes them ([`crate::int8::to_u8`] of
//! the [`View`]'s `[0, 1]` values), whichever precision made the token grid.

use anyhow::{ensure, Result};
use bino_core::config::{CELL_W, PATCH_H};
use bino_core::matching::DISPARITY_FRAC_BITS;
use bino_core::pipeline::Refine;
use bino_core::refine::sharpness::refine_map_equalised;
use bino_core::refine::{keep_rejected_map, refine_map, scratch_len, RefineParams};

use crate::data::profile::View;
use crate::eval::DisparityMap;
use crate::int8::to_u8;

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

/// The refined pixel disparity (px) of a token grid on `views` by the shipped refinement
/// ([`RefineParams::for_width`] of the views' width, equalised as [`Refine::EQUALISE`] says: the
/// pipeline's with [`Refine::for_width`], and the firmware's at 160 px). The grid must be the views' (`H / 4` x `W / 4` cells); the result has the
/// views' size, as the bilinear upsampling of the unrefined readout. With `kept` (a `+lr`
/// readout's left-right mask of the grid, its rejected cells already filled) the pixels of
/// rejected cells keep the bilinear step ([`bino_core::refine::keep_rejected_map`]).
pub fn refine_pixels(tokens: &DisparityMap, views: &GrayViews, kept: Option<&[bool]>) -> Result<DisparityMap> {
    refine_pixels_with(
        tokens,
        views,
        &RefineParams::for_width(views.width),
        Refine::EQUALISE,
        kept,
    )
}

/// [`refine_pixels`] with explicit parameters, with or without the sharpness equalisation.
pub fn refine_pixels_with(
    tokens: &DisparityMap,
    views: &GrayViews,
    params: &RefineParams,
    equalise: bool,
    kept: Option<&[bool]>,
) -> Result<DisparityMap> {
    let (width, height) = (views.width, views.height);
    ensure!(
        tokens.width * CELL_W == width && tokens.height * PATCH_H == height,
        "a {}x{} token grid does not cover {width}x{height} views",
        tokens.width,
        tokens.height
    );
    let mut scratch = vec![0u32; scratch_len(width, params)];
    let mut out = vec![0u16; width * height];
    let whole_map = if equalise { refine_map_equalised } else { refine_map };
    let grid = tokens_q8(tokens);
    whole_map(&views.left, &views.right, width, &grid, params, &mut scratch, &mut out).map_err(anyhow::Error::msg)?;
    if let Some(kept) = kept {
        let kept: Vec<u8> = kept.iter().map(|&k| u8::from(k)).collect();
        keep_rejected_map(width, &grid, &kept, &mut out).map_err(anyhow::Error::msg)?;
    }
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

    /// The core's whole-map refinement of `q8` on `views`, as pixels.
    fn core_pixels(views: &GrayViews, q8: &[u16], equalise: bool) -> Vec<f32> {
        let params = RefineParams::DEFAULT;
        let mut scratch = vec![0u32; scratch_len(views.width, &params)];
        let mut out = vec![0u16; views.width * views.height];
        let whole_map = if equalise { refine_map_equalised } else { refine_map };
        whole_map(
            &views.left,
            &views.right,
            views.width,
            q8,
            &params,
            &mut scratch,
            &mut out,
        )
        .unwrap();
        out.iter().map(|&d| d as f32 / 256.0).collect()
    }

    #[test]
    fn the_refinement_is_the_cores_equalised_whole_map() {
        let (w, h) = (24, 12);
        let left: Vec<u8> = (0..w * h).map(|i| ((i * 97 + i / w * 31) % 251) as u8).collect();
        let shifted: Vec<u8> = (0..w * h).map(|i| left[(i / w) * w + (i % w + 3).min(w - 1)]).collect();
        // The right view defocused (3-tap horizontal mean), so the equalisation engages.
        let right: Vec<u8> = (0..w * h)
            .map(|i| {
                let (y, x) = (i / w, i % w);
                let tap = |dx: isize| shifted[y * w + (x as isize + dx).clamp(0, w as isize - 1) as usize] as u32;
                ((tap(-1) + tap(0) + tap(1) + 1) / 3) as u8
            })
            .collect();
        let views = GrayViews {
            width: w,
            height: h,
            left,
            right,
        };
        let q8: Vec<u16> = (0..18).map(|i| (150 + i * 23 % 90) as u16).collect();
        let grid = map(6, q8.iter().map(|&d| d as f32 / 256.0).collect());

        let shipped = refine_pixels(&grid, &views, None).unwrap();
        assert_eq!((shipped.width, shipped.height), (w, h));
        assert_eq!(shipped.values, core_pixels(&views, &q8, Refine::EQUALISE));
        let plain = refine_pixels_with(&grid, &views, &RefineParams::DEFAULT, false, None).unwrap();
        assert_eq!(plain.values, core_pixels(&views, &q8, false));
        assert_ne!(plain.values, shipped.values, "the equalisation changes pixels here");
        assert!(
            shipped.values.iter().filter(|&&d| (d - 3.0).abs() < 0.25).count() > w * h / 2,
            "finds the 3 px shift"
        );

        let wrong = map(5, vec![1.0; 15]);
        assert!(refine_pixels(&wrong, &views, None).is_err(), "grid of another size");
    }
}
