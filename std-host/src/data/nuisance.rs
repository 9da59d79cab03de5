//! Image nuisances for `bino eval --nuisance`: each degrades the RIGHT view alone, on the
//! profile's 8-bit pixels (after resizing, before encoding), deterministically from a seed and
//! the pair id, so every method (int8, f32 and StereoSGBM) and every run sees the same images.
//!
//! | nuisance  | what it does                                                               |
//! |-----------|----------------------------------------------------------------------------|
//! | `gain`    | exposure: `v * GAIN + OFFSET`, rounded, clamped to 0..=255                 |
//! | `gamma`   | tone curve: `255 * (v / 255) ^ GAMMA`, rounded                             |
//! | `noise`   | sensor noise: gaussian, sigma `NOISE_SIGMA` grey levels, rounded, clamped |
//! | `blur`    | defocus: separable box filter of radius `BLUR_RADIUS` px (edges clamped)   |
//! | `occlude` | rectangles of random size filled with mid-grey until `OCCLUDE_SHARE` of the area is covered (each rectangle at most 1/5 of the width and height, so the share stays below 24 %) |
//!
//! The random numbers come from SplitMix64 (Steele, Lea and Flood 2014, the seeder of
//! `java.util.SplittableRandom`), seeded with the FNV-1a hash of the pair id mixed with the seed
//! and the nuisance; gaussians by Box-Muller.
//!
//! ```
//! use bino_host::data::nuisance::{degrade, Nuisance};
//! let right = vec![100u8; 32 * 16];
//! let a = degrade(Nuisance::Noise, &right, 32, 16, 0, "pair");
//! assert_eq!(a, degrade(Nuisance::Noise, &right, 32, 16, 0, "pair"));
//! assert_eq!(degrade(Nuisance::Gain, &[100], 1, 1, 0, "pair"), [90]);
//! ```

use crate::data::profile::View;
use crate::data::rng::SplitMix64;
use crate::eval::EvalItem;
use crate::int8::to_u8;

/// Exposure gain of `gain`.
pub const GAIN: f32 = 0.7;
/// Exposure offset of `gain`, grey levels.
pub const OFFSET: f32 = 20.0;
/// Exponent of the `gamma` tone curve (on values scaled to 0..=1).
pub const GAMMA: f32 = 0.6;
/// Standard deviation of the `noise` gaussian, grey levels.
pub const NOISE_SIGMA: f32 = 8.0;
/// Radius of the `blur` box filter, pixels (a 5x5 box).
pub const BLUR_RADIUS: usize = 2;
/// Share of the image `occlude` covers at least.
pub const OCCLUDE_SHARE: f64 = 0.20;
/// Grey level of the occluding rectangles.
pub const OCCLUDE_FILL: u8 = 128;

/// One degradation of the right view.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Nuisance {
    /// Exposure gain and offset.
    Gain,
    /// Tone curve.
    Gamma,
    /// Gaussian sensor noise.
    Noise,
    /// Defocus blur.
    Blur,
    /// Random block occlusion.
    Occlude,
}

impl Nuisance {
    /// Its name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Nuisance::Gain => "gain",
            Nuisance::Gamma => "gamma",
            Nuisance::Noise => "noise",
            Nuisance::Blur => "blur",
            Nuisance::Occlude => "occlude",
        }
    }
}

/// `right` (`width * height` grey levels) under `nuisance`, from `seed` and `pair_id`.
pub fn degrade(nuisance: Nuisance, right: &[u8], width: usize, height: usize, seed: u64, pair_id: &str) -> Vec<u8> {
    assert_eq!(
        right.len(),
        width * height,
        "view does not hold {width}x{height} pixels"
    );
    let mut rng = SplitMix64::new(stream_seed(seed, pair_id, nuisance));
    match nuisance {
        Nuisance::Gain => right.iter().map(|&v| level(v as f32 * GAIN + OFFSET)).collect(),
        Nuisance::Gamma => right
            .iter()
            .map(|&v| level(255.0 * (v as f32 / 255.0).powf(GAMMA)))
            .collect(),
        Nuisance::Noise => right
            .iter()
            .map(|&v| level(v as f32 + NOISE_SIGMA * rng.gaussian()))
            .collect(),
        Nuisance::Blur => box_blur(right, width, height, BLUR_RADIUS),
        Nuisance::Occlude => occlude(right, width, height, &mut rng),
    }
}

/// `item` with its right view under `nuisance` (the left view and the ground truth untouched).
/// The degraded view holds 8-bit levels (`k / 255`), as the pipeline's input does.
pub fn degrade_item(item: &EvalItem, nuisance: Nuisance, seed: u64) -> EvalItem {
    EvalItem {
        right: degrade_view(&item.right, nuisance, seed, &item.pair_id),
        ..item.clone()
    }
}

/// `view` under `nuisance` as [`degrade_item`] degrades a right view (8-bit levels out).
pub fn degrade_view(view: &View, nuisance: Nuisance, seed: u64, pair_id: &str) -> View {
    let pixels = degrade(nuisance, &to_u8(&view.pixels), view.width, view.height, seed, pair_id);
    View {
        width: view.width,
        height: view.height,
        pixels: pixels.iter().map(|&v| v as f32 / 255.0).collect(),
    }
}

fn level(v: f32) -> u8 {
    v.round().clamp(0.0, 255.0) as u8
}

fn box_blur(src: &[u8], width: usize, height: usize, radius: usize) -> Vec<u8> {
    let taps = (2 * radius + 1) as u32;
    let clampi = |i: isize, n: usize| i.clamp(0, n as isize - 1) as usize;
    let mut rows = vec![0u32; src.len()];
    for y in 0..height {
        for x in 0..width {
            rows[y * width + x] = (-(radius as isize)..=radius as isize)
                .map(|d| src[y * width + clampi(x as isize + d, width)] as u32)
                .sum();
        }
    }
    let mut out = vec![0u8; src.len()];
    for y in 0..height {
        for x in 0..width {
            let sum: u32 = (-(radius as isize)..=radius as isize)
                .map(|d| rows[clampi(y as isize + d, height) * width + x])
                .sum();
            let n = taps * taps;
            out[y * width + x] = ((sum + n / 2) / n) as u8;
        }
    }
    out
}

fn occlude(src: &[u8], width: usize, height: usize, rng: &mut SplitMix64) -> Vec<u8> {
    let mut out = src.to_vec();
    let mut covered = vec![false; src.len()];
    let mut count = 0usize;
    let target = (OCCLUDE_SHARE * src.len() as f64).ceil() as usize;
    let (max_w, max_h) = ((width / 5).max(1), (height / 5).max(1));
    let (min_w, min_h) = ((width / 20).max(1), (height / 20).max(1));
    while count < target {
        let w = min_w + rng.below(max_w - min_w + 1);
        let h = min_h + rng.below(max_h - min_h + 1);
        let (x0, y0) = (rng.below(width - w + 1), rng.below(height - h + 1));
        for y in y0..y0 + h {
            for x in x0..x0 + w {
                let i = y * width + x;
                out[i] = OCCLUDE_FILL;
                if !covered[i] {
                    covered[i] = true;
                    count += 1;
                }
            }
        }
    }
    out
}

/// FNV-1a of the pair id, mixed with the seed and the nuisance.
fn stream_seed(seed: u64, pair_id: &str, nuisance: Nuisance) -> u64 {
    crate::data::rng::fnv1a(pair_id.as_bytes())
        ^ seed.wrapping_mul(0x9e37_79b9_7f4a_7c15)
        ^ (nuisance as u64 + 1).wrapping_mul(0xbf58_476d_1ce4_e5b9)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::GroundTruthMap;

    const ALL: [Nuisance; 5] = [
        Nuisance::Gain,
        Nuisance::Gamma,
        Nuisance::Noise,
        Nuisance::Blur,
        Nuisance::Occlude,
    ];

    fn texture(w: usize, h: usize) -> Vec<u8> {
        (0..w * h).map(|i| ((i % w) * 7 + (i / w) * 13) as u8).collect()
    }

    #[test]
    fn same_seed_same_image_and_pairs_differ() {
        let (w, h) = (80, 48);
        let img = texture(w, h);
        for n in ALL {
            let a = degrade(n, &img, w, h, 0, "a");
            assert_eq!(a, degrade(n, &img, w, h, 0, "a"), "{n:?}");
            assert_ne!(a, img, "{n:?} changes the view");
        }
        for n in [Nuisance::Noise, Nuisance::Occlude] {
            let a = degrade(n, &img, w, h, 0, "a");
            assert_ne!(a, degrade(n, &img, w, h, 0, "b"), "{n:?}: pair ids differ");
            assert_ne!(a, degrade(n, &img, w, h, 1, "a"), "{n:?}: seeds differ");
        }
    }

    #[test]
    fn occlusion_covers_between_20_and_25_percent() {
        for (w, h) in [(160, 96), (320, 192), (37, 23)] {
            // A view without the fill level, so every fill pixel is an occluded one.
            let img = vec![7u8; w * h];
            for id in ["a", "b", "c", "d"] {
                let out = degrade(Nuisance::Occlude, &img, w, h, 3, id);
                let share = out.iter().filter(|&&v| v == OCCLUDE_FILL).count() as f64 / (w * h) as f64;
                assert!((0.20..=0.25).contains(&share), "{w}x{h} {id}: {share}");
            }
        }
    }

    #[test]
    fn gain_and_gamma_are_exact() {
        let px = [0u8, 100, 250, 64];
        // 0.7 v + 20: 20, 90, 195, 64.8 -> 65.
        assert_eq!(degrade(Nuisance::Gain, &px, 4, 1, 0, "p"), [20, 90, 195, 65]);
        // 255 (v/255)^0.6.
        let expect: Vec<u8> = px
            .iter()
            .map(|&v| (255.0 * (v as f64 / 255.0).powf(0.6)).round() as u8)
            .collect();
        assert_eq!(degrade(Nuisance::Gamma, &px, 4, 1, 0, "p"), expect);
        assert_eq!(expect[0], 0);
        assert_eq!(expect[1], 145);
    }

    #[test]
    fn noise_has_the_documented_sigma_and_blur_keeps_flat_areas() {
        let (w, h) = (200, 200);
        let img = vec![128u8; w * h];
        let out = degrade(Nuisance::Noise, &img, w, h, 0, "p");
        let d: Vec<f64> = out.iter().map(|&v| v as f64 - 128.0).collect();
        let mean = d.iter().sum::<f64>() / d.len() as f64;
        let sd = (d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / d.len() as f64).sqrt();
        assert!(mean.abs() < 0.2 && (sd - 8.0).abs() < 0.3, "mean {mean} sd {sd}");
        assert_eq!(degrade(Nuisance::Blur, &img, w, h, 0, "p"), img);
        // A single bright pixel spreads over the 5x5 box: 25 / 25 = 1 each.
        let mut dot = vec![0u8; 100];
        dot[55] = 25;
        let blurred = degrade(Nuisance::Blur, &dot, 10, 10, 0, "p");
        assert_eq!(blurred.iter().filter(|&&v| v == 1).count(), 25);
    }

    #[test]
    fn the_left_view_and_ground_truth_are_never_touched() {
        let (w, h) = (40, 24);
        let view = |px: &[u8]| View {
            width: w,
            height: h,
            pixels: px.iter().map(|&v| v as f32 / 255.0).collect(),
        };
        let item = EvalItem {
            pair_id: "p".into(),
            left: view(&texture(w, h)),
            right: view(&texture(w, h)),
            gt: GroundTruthMap {
                width: w,
                height: h,
                disparity: vec![3.0; w * h],
                valid: vec![true; w * h],
            },
        };
        for n in ALL {
            let out = degrade_item(&item, n, 0);
            assert_eq!(out.left.pixels, item.left.pixels, "{n:?}");
            assert_eq!(out.gt.disparity, item.gt.disparity, "{n:?}");
            assert_ne!(out.right.pixels, item.right.pixels, "{n:?}");
            assert_eq!(to_u8(&out.right.pixels), degrade(n, &texture(w, h), w, h, 0, "p"));
        }
    }
}
