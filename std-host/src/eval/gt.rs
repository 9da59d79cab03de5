//! Ground-truth disparity of a labeled pair, at its stored resolution and at a profile.
//!
//! Mirrors `pairs.load_gt` and `profile.resize_gt`: stored value / `gt_scale` is the disparity,
//! the stored value `gt_invalid` marks a pixel without ground truth, and the profile resize is
//! OpenCV's `INTER_NEAREST_EXACT` for disparity and mask alike, disparity times `P / W`.

use anyhow::{bail, ensure, Result};
use image::DynamicImage;

use super::nearest::resize_nearest_exact;
use crate::pairs::GroundTruth;
use crate::profile::Profile;

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
}

/// Loads an 8-bit single-channel disparity image (PGM or PNG) at its stored resolution.
pub fn load_ground_truth(gt: &GroundTruth) -> Result<GroundTruthMap> {
    let path = &gt.path;
    let decoded = crate::image_io::decode(path, "ground truth")?;
    // Like the Python loader, refuse colour or 16-bit maps instead of converting them.
    let stored = match decoded {
        DynamicImage::ImageLuma8(buffer) => buffer,
        other => bail!(
            "{}: expected an 8-bit single-channel disparity map, got {:?}",
            path.display(),
            other.color()
        ),
    };
    let (width, height) = (stored.width() as usize, stored.height() as usize);
    ensure!(width > 0 && height > 0, "{}: empty disparity map", path.display());
    let raw = stored.into_raw();
    Ok(GroundTruthMap {
        width,
        height,
        disparity: raw.iter().map(|&v| v as f32 / gt.scale).collect(),
        valid: raw.iter().map(|&v| v != gt.invalid).collect(),
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
            scale: 8.0,
            invalid: 0,
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
}
