//! A procedurally textured stereo scene with known disparity: the built-in input that needs
//! no data files, and a ground truth for tests.
//!
//! The scene is a stack of fronto-parallel textured planes (a background and rectangles in
//! front of it). Left pixel `x` sees the nearest plane covering it; the same point appears in
//! the right view at `x - d` (the convention of `DATA.md`: `left(x, y) = right(x - d, y)`).

use crate::io::image_io::GrayImage;

/// A rectangle of constant disparity, in left-view pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// Left-view columns `x0..x1` and rows `y0..y1` it covers.
    pub x0: usize,
    /// End column (exclusive).
    pub x1: usize,
    /// First row.
    pub y0: usize,
    /// End row (exclusive).
    pub y1: usize,
    /// Disparity in pixels (integer, so both views sample the texture on its grid).
    pub disparity: usize,
}

/// A rendered pair and the left view's true disparity.
#[derive(Debug, Clone, PartialEq)]
pub struct SyntheticPair {
    /// Left view.
    pub left: GrayImage,
    /// Right view.
    pub right: GrayImage,
    /// Disparity of every left pixel, row-major.
    pub disparity: Vec<f32>,
}

/// The default scene: a `width` x `height` background at disparity 4 with two nearer boxes.
pub fn default_scene(width: usize, height: usize) -> SyntheticPair {
    let background = Plane {
        x0: 0,
        x1: width,
        y0: 0,
        y1: height,
        disparity: 4,
    };
    let near = Plane {
        x0: width / 8,
        x1: width * 3 / 8,
        y0: height / 6,
        y1: height * 5 / 6,
        disparity: 16,
    };
    let mid = Plane {
        x0: width / 2,
        x1: width * 7 / 8,
        y0: height / 4,
        y1: height * 3 / 4,
        disparity: 10,
    };
    render(width, height, &[background, mid, near], 7)
}

/// Renders `planes` (later ones in front) with a texture seeded by `seed`.
pub fn render(width: usize, height: usize, planes: &[Plane], seed: u32) -> SyntheticPair {
    let mut left = vec![0u8; width * height];
    let mut right = vec![0u8; width * height];
    let mut disparity = vec![0f32; width * height];
    for y in 0..height {
        for x in 0..width {
            // Nearest plane covering left pixel x.
            if let Some((i, p)) = front(planes, x as isize, y) {
                left[y * width + x] = texture(seed + i as u32, x as isize, y);
                disparity[y * width + x] = p.disparity as f32;
            }
            // Right pixel x shows the nearest plane whose left-view footprint covers x + d.
            let seen = planes
                .iter()
                .enumerate()
                .rev()
                .find(|(_, p)| covers(p, x as isize + p.disparity as isize, y));
            if let Some((i, p)) = seen {
                right[y * width + x] = texture(seed + i as u32, x as isize + p.disparity as isize, y);
            }
        }
    }
    let gray = |pixels| GrayImage { width, height, pixels };
    SyntheticPair {
        left: gray(left),
        right: gray(right),
        disparity,
    }
}

fn covers(p: &Plane, x: isize, y: usize) -> bool {
    x >= p.x0 as isize && x < p.x1 as isize && y >= p.y0 && y < p.y1
}

fn front(planes: &[Plane], x: isize, y: usize) -> Option<(usize, &Plane)> {
    planes.iter().enumerate().rev().find(|(_, p)| covers(p, x, y))
}

// Multi-scale value noise: structure at 16, 6 and 2 px so matching has something at every scale.
fn texture(seed: u32, x: isize, y: usize) -> u8 {
    let mut value = 0.0f32;
    for (cell, weight) in [(16, 0.45f32), (6, 0.3), (2, 0.25)] {
        value += weight * value_noise(seed.wrapping_mul(31).wrapping_add(cell as u32), x, y as isize, cell);
    }
    (value * 255.0).round().clamp(0.0, 255.0) as u8
}

fn value_noise(seed: u32, x: isize, y: isize, cell: isize) -> f32 {
    let (gx, gy) = (x.div_euclid(cell), y.div_euclid(cell));
    let (fx, fy) = (
        x.rem_euclid(cell) as f32 / cell as f32,
        y.rem_euclid(cell) as f32 / cell as f32,
    );
    let h = |i: isize, j: isize| hash(seed, i, j);
    let top = h(gx, gy) * (1.0 - fx) + h(gx + 1, gy) * fx;
    let bottom = h(gx, gy + 1) * (1.0 - fx) + h(gx + 1, gy + 1) * fx;
    top * (1.0 - fy) + bottom * fy
}

// A value in [0, 1) from integer lattice coordinates (a small integer hash, no RNG state).
fn hash(seed: u32, i: isize, j: isize) -> f32 {
    let mut h = seed ^ (i as u32).wrapping_mul(0x9e37_79b1) ^ (j as u32).wrapping_mul(0x85eb_ca77);
    h ^= h >> 15;
    h = h.wrapping_mul(0x2c1b_3c6d);
    h ^= h >> 12;
    h = h.wrapping_mul(0x297a_2d39);
    h ^= h >> 15;
    (h >> 8) as f32 / (1u32 << 24) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn left_pixels_reappear_shifted_by_their_disparity() {
        let pair = default_scene(160, 96);
        let (w, h) = (160, 96);
        let mut checked = 0;
        for y in 0..h {
            for x in 0..w {
                let d = pair.disparity[y * w + x] as usize;
                if x < d {
                    continue;
                }
                // Visible in both views unless a nearer plane covers it on the right.
                let occluded = pair.disparity[y * w..(y + 1) * w]
                    .iter()
                    .enumerate()
                    .any(|(xl, &dl)| dl as usize > d && xl as isize - dl as isize == (x - d) as isize);
                if !occluded {
                    assert_eq!(
                        pair.left.pixels[y * w + x],
                        pair.right.pixels[y * w + x - d],
                        "({x},{y}) d={d}"
                    );
                    checked += 1;
                }
            }
        }
        assert!(
            checked > w * h * 3 / 4,
            "most pixels are visible in both views: {checked}"
        );
    }

    #[test]
    fn texture_has_contrast_and_is_deterministic() {
        let a = default_scene(64, 48);
        assert_eq!(a, default_scene(64, 48));
        let (lo, hi) = a
            .left
            .pixels
            .iter()
            .fold((255, 0), |(lo, hi), &p| (lo.min(p), hi.max(p)));
        assert!(hi - lo > 100, "range {lo}..{hi}");
    }
}
