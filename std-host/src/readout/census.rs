//! The `census` readout's token grid: the core's census SGM ([`bino_core::census::CensusSgm`])
//! streamed over every token row of the pair's 8-bit views, top to bottom, with its own
//! left-right check. It reads pixels only, so it is the same in every precision.

use anyhow::{ensure, Result};
use bino_core::census::{self, CensusSgm, WINDOW_ROWS};
use bino_core::config::{CELL_W, PATCH_H};
use bino_core::matching::DISPARITY_FRAC_BITS;

use crate::eval::DisparityMap;
use crate::readout::head_candidates;
use crate::readout::refine::GrayViews;

/// The head's share in `fuse-census` (the core's, which the pipeline uses too).
pub use bino_core::census::FUSE_HEAD_WEIGHT;

/// The left-right tolerance of the census check, Q8 patch columns: one column, the CLI's
/// default `--lr-max-diff` (the census map is computed from the views alone, once per pair).
pub const CENSUS_LR_MAX_DIFF_Q8: u16 = 1 << DISPARITY_FRAC_BITS;

/// The census SGM's disparity (patch columns) and its check's mask over the views' token grid,
/// searching as far as the heads at this width ([`head_candidates`]).
pub fn census_grid(views: &GrayViews) -> Result<(DisparityMap, Vec<bool>)> {
    let (width, height) = (views.width, views.height);
    ensure!(
        width.is_multiple_of(CELL_W) && height.is_multiple_of(PATCH_H) && width > 0 && height > 0,
        "census: the views ({width}x{height}) are not whole 4x4 cells"
    );
    let disparities = census::disparities(head_candidates(width));
    let mut s32 = vec![0u32; census::scratch_u32_len(width, disparities)];
    let mut s16 = vec![0u16; census::scratch_u16_len(width, disparities)];
    let mut sgm = CensusSgm::new(
        width,
        disparities,
        census::DEFAULT_PENALTIES,
        CENSUS_LR_MAX_DIFF_Q8,
        &mut s32,
        &mut s16,
    )
    .map_err(anyhow::Error::msg)?;
    let (rows, cols) = (height / PATCH_H, width / CELL_W);
    let (mut q8, mut kept) = (vec![0u16; rows * cols], vec![0u8; rows * cols]);
    // View rows clamp(4 t + j - 2), j = 0..8: the token row's pixel rows and the census reach.
    fn window(view: &[u8], width: usize, height: usize, t: usize) -> Vec<&[u8]> {
        (0..WINDOW_ROWS)
            .map(|j| {
                let y = census::window_row(t, j, height);
                &view[y * width..(y + 1) * width]
            })
            .collect()
    }
    for t in 0..rows {
        let at = t * cols..(t + 1) * cols;
        sgm.push_row(
            &window(&views.left, width, height, t),
            &window(&views.right, width, height, t),
            &mut q8[at.clone()],
            &mut kept[at],
        )
        .map_err(anyhow::Error::msg)?;
    }
    let unit = (1u32 << DISPARITY_FRAC_BITS) as f32;
    let map = DisparityMap {
        width: cols,
        height: rows,
        values: q8.iter().map(|&d| d as f32 / unit).collect(),
    };
    Ok((map, kept.iter().map(|&k| k != 0).collect()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_shifted_texture_reads_its_shift_and_a_ragged_size_is_an_error() {
        let (width, height, shift) = (64, 16, 6);
        let texture = |x: usize, y: usize| ((x * 73 + y * 151 + (x * y) % 17) % 251) as u8;
        let left: Vec<u8> = (0..width * height)
            .map(|i| texture(i % width + 20, i / width))
            .collect();
        let right: Vec<u8> = (0..width * height)
            .map(|i| texture(i % width + 20 + shift, i / width))
            .collect();
        let views = GrayViews {
            width,
            height,
            left,
            right,
        };
        let (map, kept) = census_grid(&views).unwrap();
        assert_eq!((map.width, map.height), (16, 4));
        for (i, (&d, &k)) in map.values.iter().zip(&kept).enumerate() {
            if i % 16 >= 2 {
                assert!((d - 1.5).abs() < 0.1 && k, "cell {i}: {d} kept {k}");
            }
        }
        let ragged = GrayViews { width: 62, ..views };
        assert!(census_grid(&ragged)
            .unwrap_err()
            .to_string()
            .contains("not whole 4x4 cells"));
    }
}
