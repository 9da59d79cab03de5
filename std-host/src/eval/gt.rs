//! Ground-truth disparity of a labeled pair, at its stored resolution and at a profile.
//!
//! Mirrors `pairs.load_gt` and `profile.resize_gt`: stored value / `gt_scale` is the disparity
//! in every `gt_format`, the stored value `gt_invalid` marks a pixel without ground truth (and,
//! in a PFM, so does any non-finite value), and the profile resize is OpenCV's
//! `INTER_NEAREST_EXACT` for disparity and mask alike, disparity times `P / W`.

use anyhow::{bail, ensure, Result};
use image::DynamicImage;

use super::nearest::resize_nearest_exact;
use crate::data::pairs::{GroundTruth, GtFormat};
use crate::data::profile::Profile;

/// Left-image disparity in pixels with its validity mask, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct GroundTruthMap {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `width * height` disparities in pixels (0 where invalid).
    pub disparity: Vec<f32>,
    /// `width * height` flags: true where the pixel has ground truth.
    pub valid: Vec<bool>,
}

impl GroundTruthMap {
    /// Number of pixels with ground truth.
    pub fn valid_count(&self) -> usize {
        self.valid.iter().filter(|&&v| v).count()
    }

    /// The large-disparity subset (the paper's stress test, section 3.6): the pixels whose
    /// ground truth is in the pair's top quartile: at or above the smallest of its `ceil(n / 4)`
    /// largest valid disparities (ties at that threshold are kept, so it may hold a little more
    /// than a quarter). Token disparities are pixel disparities / 4: the same pixels.
    pub fn large_disparity_subset(&self) -> GroundTruthMap {
        let mut values: Vec<f32> = (self.disparity.iter().zip(&self.valid))
            .filter(|(_, &v)| v)
            .map(|(&d, _)| d)
            .collect();
        values.sort_by(f32::total_cmp);
        let threshold = match values.len() {
            0 => f32::INFINITY,
            n => values[n - n.div_ceil(4)],
        };
        GroundTruthMap {
            valid: (self.disparity.iter().zip(&self.valid))
                .map(|(&d, &v)| v && d >= threshold)
                .collect(),
            ..self.clone()
        }
    }
}

/// Loads a disparity map in its `gt_format` at its stored resolution: 8-bit PGM or PNG, 16-bit
/// PNG, or float32 PFM, always one channel.
pub fn load_ground_truth(gt: &GroundTruth) -> Result<GroundTruthMap> {
    let path = &gt.path;
    let (width, height, disparity, valid) = match gt.format {
        GtFormat::Pfm => {
            let stored = crate::io::pfm::load(path, "ground truth")?;
            let valid: Vec<bool> = stored
                .values
                .iter()
                .map(|&v| v.is_finite() && gt.invalid.is_none_or(|i| v != f32::from(i)))
                .collect();
            // 0 where invalid, so no `inf` reaches a resize or a metric.
            let disparity = stored
                .values
                .iter()
                .zip(&valid)
                .map(|(&v, &ok)| if ok { v / gt.scale } else { 0.0 })
                .collect();
            (stored.width, stored.height, disparity, valid)
        }
        format => {
            let decoded = crate::io::image_io::decode(path, "ground truth")?;
            let (width, height) = (decoded.width() as usize, decoded.height() as usize);
            // Like the Python loader, refuse colour or another bit depth instead of converting.
            let raw: Vec<u16> = match (format, decoded) {
                (GtFormat::PgmU8 | GtFormat::PngU8, DynamicImage::ImageLuma8(b)) => {
                    b.into_raw().into_iter().map(u16::from).collect()
                }
                (GtFormat::PngU16, DynamicImage::ImageLuma16(b)) => b.into_raw(),
                (format, other) => bail!(
                    "{}: expected {} single-channel disparity map (gt_format {format}), got {:?}",
                    path.display(),
                    if format == GtFormat::PngU16 {
                        "a 16-bit"
                    } else {
                        "an 8-bit"
                    },
                    other.color()
                ),
            };
            let invalid = gt.invalid;
            let disparity = raw.iter().map(|&v| f32::from(v) / gt.scale).collect();
            let valid = raw.iter().map(|&v| Some(v) != invalid).collect();
            (width, height, disparity, valid)
        }
    };
    ensure!(width > 0 && height > 0, "{}: empty disparity map", path.display());
    Ok(GroundTruthMap {
        width,
        height,
        disparity,
        valid,
    })
}

/// Brings ground truth to a profile: nearest resize (OpenCV `INTER_NEAREST_EXACT`, see
/// [`super::nearest`]) of disparity and mask to the profile's size, bottom rows dropped to a
/// multiple of 4, disparity times the width factor.
/// [`Profile::Native`] keeps the map as it is (its sides must be multiples of 4).
pub fn resize_ground_truth(map: &GroundTruthMap, profile: Profile) -> Result<GroundTruthMap> {
    let size = profile.size(map.width, map.height)?;
    let (width, full_height) = size.resized;
    let kept = width * size.kept_rows;
    let factor = profile.scale(map.width);
    let disparity = resize_nearest_exact(&map.disparity, map.width, map.height, width, full_height);
    let valid = resize_nearest_exact(&map.valid, map.width, map.height, width, full_height);
    Ok(GroundTruthMap {
        width,
        height: size.kept_rows,
        disparity: disparity[..kept].iter().map(|&d| d * factor).collect(),
        valid: valid[..kept].to_vec(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(width: usize, height: usize) -> GroundTruthMap {
        let n = width * height;
        GroundTruthMap {
            width,
            height,
            disparity: (0..n).map(|i| i as f32).collect(),
            valid: (0..n).map(|i| i % 3 != 0).collect(),
        }
    }

    #[test]
    fn resize_samples_centres_scales_and_crops() {
        // 320x10 -> w160: 160 x 5 rows, cropped to 4; every second column and row, disparity halved.
        let src = map(320, 10);
        let out = resize_ground_truth(&src, Profile::W160).unwrap();
        assert_eq!((out.width, out.height), (160, 4));
        // Destination (y, x) samples source (2y + 1, 2x + 1).
        for (y, x) in [(0, 0), (3, 159), (2, 77)] {
            let s = (2 * y + 1) * 320 + 2 * x + 1;
            assert_eq!(out.disparity[y * 160 + x], s as f32 * 0.5);
            assert_eq!(out.valid[y * 160 + x], src.valid[s]);
        }
    }

    #[test]
    fn native_keeps_the_map_and_needs_multiples_of_four() {
        let src = map(8, 4);
        assert_eq!(resize_ground_truth(&src, Profile::Native).unwrap(), src);
        assert!(resize_ground_truth(&map(8, 5), Profile::Native).is_err());
    }

    #[test]
    fn loads_pgm_with_scale_and_invalid_value() {
        let dir = std::env::temp_dir().join(format!("bino-eval-gt-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("disp.pgm");
        let mut bytes = b"P5\n3 1\n255\n".to_vec();
        bytes.extend([0u8, 8, 20]);
        std::fs::write(&path, bytes).unwrap();
        let gt = GroundTruth {
            path: path.clone(),
            format: GtFormat::PgmU8,
            scale: 8.0,
            invalid: Some(0),
        };
        let loaded = load_ground_truth(&gt).unwrap();
        assert_eq!((loaded.width, loaded.height), (3, 1));
        assert_eq!(loaded.disparity, vec![0.0, 1.0, 2.5]);
        assert_eq!(loaded.valid, vec![false, true, true]);
        let missing = GroundTruth {
            path: dir.join("missing.pgm"),
            ..gt
        };
        let err = format!("{:#}", load_ground_truth(&missing).unwrap_err());
        assert!(err.contains("missing.pgm"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    /// A fresh scratch folder for one test.
    fn scratch(name: &str) -> std::path::PathBuf {
        let dir = std::env::temp_dir().join(format!("bino-eval-gt-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn loads_pfm_of_either_byte_order_top_row_first_with_unknowns_masked() {
        let dir = scratch("pfm");
        // Asymmetric, so a missed row flip shows; inf and NaN are unknown, 0 is a disparity.
        let rows: [&[f32]; 2] = [&[1.0, 2.0, f32::INFINITY], &[0.0, f32::NAN, 12.0]];
        for little_endian in [true, false] {
            let path = dir.join(format!("disp-{little_endian}.pfm"));
            std::fs::write(&path, crate::io::pfm::encode(&rows, little_endian)).unwrap();
            let gt = GroundTruth {
                path,
                format: GtFormat::Pfm,
                scale: 2.0,
                invalid: None,
            };
            let loaded = load_ground_truth(&gt).unwrap();
            assert_eq!((loaded.width, loaded.height), (3, 2));
            assert_eq!(loaded.disparity, vec![0.5, 1.0, 0.0, 0.0, 0.0, 6.0]);
            assert_eq!(loaded.valid, vec![true, true, false, true, false, true]);
            // A stated gt_invalid masks that value too.
            let zero_unknown = GroundTruth { invalid: Some(0), ..gt };
            let loaded = load_ground_truth(&zero_unknown).unwrap();
            assert_eq!(loaded.valid, vec![true, true, false, false, false, true]);
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn loads_png_u16_as_value_over_scale_with_zero_unknown() {
        let dir = scratch("png16");
        let path = dir.join("disp.png");
        // KITTI's encoding: disparity * 256, 0 where unknown; 65535 = 255.996 px.
        image::ImageBuffer::<image::Luma<u16>, _>::from_raw(2, 2, vec![0u16, 256, 2560 + 128, 65535])
            .unwrap()
            .save(&path)
            .unwrap();
        let gt = GroundTruth {
            path,
            format: GtFormat::PngU16,
            scale: 256.0,
            invalid: Some(0),
        };
        let loaded = load_ground_truth(&gt).unwrap();
        assert_eq!((loaded.width, loaded.height), (2, 2));
        assert_eq!(loaded.disparity, vec![0.0, 1.0, 10.5, 65535.0 / 256.0]);
        assert_eq!(loaded.valid, vec![false, true, true, true]);
        // The bit depth must match the format, either way round.
        let as_u8 = GroundTruth {
            format: GtFormat::PngU8,
            scale: 1.0,
            ..gt.clone()
        };
        let err = format!("{:#}", load_ground_truth(&as_u8).unwrap_err());
        assert!(err.contains("disp.png") && err.contains("expected an 8-bit"), "{err}");
        let u8_path = dir.join("u8.png");
        image::GrayImage::from_pixel(2, 2, image::Luma([9]))
            .save(&u8_path)
            .unwrap();
        let u8_as_u16 = GroundTruth { path: u8_path, ..gt };
        let err = format!("{:#}", load_ground_truth(&u8_as_u16).unwrap_err());
        assert!(err.contains("u8.png") && err.contains("16-bit"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_large_disparity_subset_is_the_top_quartile_of_valid_pixels() {
        // Disparities 0..8 on valid pixels, one invalid pixel holding a large value.
        let mut disparity: Vec<f32> = (0..8).map(|d| d as f32).collect();
        disparity.push(100.0);
        let mut valid = vec![true; 8];
        valid.push(false);
        let gt = GroundTruthMap {
            width: 9,
            height: 1,
            disparity,
            valid,
        };
        let large = gt.large_disparity_subset();
        // The two largest of 0..=7 (the invalid 100 does not count).
        let kept: Vec<usize> = (0..9).filter(|&i| large.valid[i]).collect();
        assert_eq!(kept, [6, 7]);
        assert_eq!(large.disparity, gt.disparity);
        let none = GroundTruthMap {
            valid: vec![false; 9],
            ..gt
        };
        assert_eq!(none.large_disparity_subset().valid_count(), 0);
    }
}
