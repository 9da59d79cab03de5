//! Token-grid disparity to per-pixel disparity (`probe.upsample_disparity`): patch columns
//! times 4, then a bilinear resize to 4x the grid as OpenCV's `INTER_LINEAR` does it.

use bino_core::config::{CELL_W, PATCH_H};

use super::DisparityMap;

/// Pixels per patch column (and per token row): the unit change from token to pixel disparity.
pub const PIXELS_PER_PATCH_COLUMN: usize = CELL_W;

/// Token-grid disparity in patch columns -> per-pixel disparity in pixels, 4x larger each way.
pub fn upsample_disparity(tokens: &DisparityMap) -> DisparityMap {
    let unit = PIXELS_PER_PATCH_COLUMN as f32;
    let grid: Vec<f32> = tokens.values.iter().map(|&d| d * unit).collect();
    let (width, height) = (tokens.width * CELL_W, tokens.height * PATCH_H);
    DisparityMap {
        width,
        height,
        values: resize_bilinear(&grid, tokens.width, tokens.height, width, height),
    }
}

/// Token-grid validity (`cols` per row) to pixels of a `width` x `height` view: each cell
/// covers its 4x4 block; pixels right of the last cell take the last cell's flag.
pub fn upsample_mask(tokens: &[bool], cols: usize, width: usize, height: usize) -> Vec<bool> {
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

/// Resizes a row-major `sw` x `sh` image to `dw` x `dh` like `cv2.resize(..., INTER_LINEAR)` on
/// float32 input: pixel-centre alignment, edge pixels clamped, rows interpolated first.
pub fn resize_bilinear(src: &[f32], sw: usize, sh: usize, dw: usize, dh: usize) -> Vec<f32> {
    assert_eq!(src.len(), sw * sh, "{sw}x{sh} image needs {} values", sw * sh);
    let horizontal = linear_taps(sw, dw);
    let vertical = linear_taps(sh, dh);
    let rows: Vec<f32> = (0..sh)
        .flat_map(|y| {
            let line = &src[y * sw..(y + 1) * sw];
            horizontal
                .iter()
                .map(move |t| line[t.first] * t.weights[0] + line[t.second] * t.weights[1])
        })
        .collect();
    let mut out = Vec::with_capacity(dw * dh);
    for t in &vertical {
        let (a, b) = (&rows[t.first * dw..][..dw], &rows[t.second * dw..][..dw]);
        out.extend(a.iter().zip(b).map(|(&x, &y)| x * t.weights[0] + y * t.weights[1]));
    }
    out
}

// Two source indices and their weights for one destination index.
struct Taps {
    first: usize,
    second: usize,
    weights: [f32; 2],
}

// OpenCV's rule: x = (d + 0.5) * scale - 0.5 (as f32) with scale = 1 / (dst / src) in f64;
// outside [0, src - 1] the edge pixel is taken with full weight.
fn linear_taps(src: usize, dst: usize) -> Vec<Taps> {
    let scale = 1.0 / (dst as f64 / src as f64);
    (0..dst)
        .map(|d| {
            let x = ((d as f64 + 0.5) * scale - 0.5) as f32;
            let floor = x.floor();
            let (first, frac) = if floor < 0.0 {
                (0, 0.0)
            } else if floor as usize >= src - 1 {
                (src - 1, 0.0)
            } else {
                (floor as usize, x - floor)
            };
            Taps {
                first,
                second: (first + 1).min(src - 1),
                weights: [1.0 - frac, frac],
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cell_flag_covers_its_four_by_four_block() {
        // 2 x 2 cells over an 10 x 8 view: columns 8 and 9 take the last cell's flag.
        let mask = upsample_mask(&[true, false, false, true], 2, 10, 8);
        let at = |x: usize, y: usize| mask[y * 10 + x];
        assert!(at(0, 0) && at(3, 3) && !at(4, 0) && !at(9, 3));
        assert!(!at(0, 4) && !at(3, 7) && at(4, 4) && at(9, 7));
        assert_eq!(mask.iter().filter(|&&m| m).count(), 4 * 4 + 6 * 4);
    }

    #[test]
    fn constant_grid_stays_constant_in_pixels() {
        let tokens = DisparityMap {
            width: 3,
            height: 2,
            values: vec![2.5; 6],
        };
        let px = upsample_disparity(&tokens);
        assert_eq!((px.width, px.height), (12, 8));
        assert!(px.values.iter().all(|&v| v == 10.0));
    }

    #[test]
    fn ramp_is_interpolated_between_centres_and_clamped_at_edges() {
        // One row [0, 4]: pixel centres of the 4x grid sit at -0.375, -0.125, 0.125, ... source px.
        let out = resize_bilinear(&[0.0, 4.0], 2, 1, 8, 1);
        assert_eq!(out, vec![0.0, 0.0, 0.5, 1.5, 2.5, 3.5, 4.0, 4.0]);
        // A single source pixel fills everything.
        assert_eq!(resize_bilinear(&[7.0], 1, 1, 4, 4), vec![7.0; 16]);
    }
}
