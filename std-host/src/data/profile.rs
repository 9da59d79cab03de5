//! The resolution profiles of `EVAL.md`: every view is resized to a fixed width before the
//! encoder sees it, so that numbers from the CLI, the training code and baselines agree.

use std::fmt;
use std::str::FromStr;

use anyhow::{bail, ensure, Result};
use bino_core::config::{CELL_W, PATCH_H};

use crate::io::image_io::GrayImage;

/// How a view is brought to the size the encoder runs at.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Profile {
    /// Width 160 px (the paper's 40 patch columns); the default.
    W160,
    /// Width 320 px.
    W320,
    /// No resize; the view must already be a multiple of 4 in both directions.
    Native,
}

impl Profile {
    /// Target width in pixels, `None` for [`Profile::Native`].
    pub fn width(self) -> Option<usize> {
        match self {
            Profile::W160 => Some(160),
            Profile::W320 => Some(320),
            Profile::Native => None,
        }
    }

    /// Disparity scale factor from the original image to the profile (`P / W`).
    pub fn scale(self, original_width: usize) -> f32 {
        self.width().map_or(1.0, |p| p as f32 / original_width as f32)
    }

    /// Size (width, height) of a `width` x `height` view under this profile: the resize
    /// target, then the bottom rows dropped to a multiple of 4. Fails if nothing is left.
    pub fn size(self, width: usize, height: usize) -> Result<ProfileSize> {
        ensure!(width > 0 && height > 0, "image is empty ({width}x{height})");
        let resized = match self.width() {
            Some(p) => (p, ((height * p) as f64 / width as f64).round() as usize),
            None => {
                ensure!(
                    width.is_multiple_of(CELL_W) && height.is_multiple_of(PATCH_H),
                    "{width}x{height} does not fit profile native: both sides must be multiples of 4"
                );
                (width, height)
            }
        };
        let kept = resized.1 - resized.1 % PATCH_H;
        ensure!(
            kept > 0,
            "{width}x{height} does not fit profile {self}: {} rows after resizing to width {}",
            resized.1,
            resized.0
        );
        Ok(ProfileSize {
            resized,
            kept_rows: kept,
        })
    }

    /// Resizes a view with area averaging and crops it to a multiple of 4 rows; values in [0, 1].
    pub fn apply(self, image: &GrayImage) -> Result<View> {
        let size = self.size(image.width, image.height)?;
        let (w, h) = size.resized;
        let source: Vec<f32> = image.pixels.iter().map(|&p| p as f32 / 255.0).collect();
        let resized = resize_area(&source, image.width, image.height, w, h);
        let pixels = resized[..w * size.kept_rows].to_vec();
        Ok(View {
            width: w,
            height: size.kept_rows,
            pixels,
        })
    }
}

impl fmt::Display for Profile {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Profile::W160 => "w160",
            Profile::W320 => "w320",
            Profile::Native => "native",
        })
    }
}

impl FromStr for Profile {
    type Err = anyhow::Error;

    fn from_str(s: &str) -> Result<Self> {
        match s {
            "w160" => Ok(Profile::W160),
            "w320" => Ok(Profile::W320),
            "native" => Ok(Profile::Native),
            other => bail!("unknown profile {other:?} (expected w160, w320 or native)"),
        }
    }
}

/// The sizes a profile produces for one image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ProfileSize {
    /// (width, height) after resizing, before the bottom rows are dropped.
    pub resized: (usize, usize),
    /// Rows kept: `resized.1` rounded down to a multiple of 4.
    pub kept_rows: usize,
}

/// A view ready for the encoder: gray values in [0, 1], both sides multiples of 4.
#[derive(Debug, Clone, PartialEq)]
pub struct View {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `width * height` values, row by row.
    pub pixels: Vec<f32>,
}

impl View {
    /// The view mirrored left to right (each row reversed): with the views swapped, the pair a
    /// right-view readout runs on.
    pub fn mirrored(&self) -> View {
        let mut pixels = self.pixels.clone();
        for row in pixels.chunks_exact_mut(self.width.max(1)) {
            row.reverse();
        }
        View { pixels, ..*self }
    }
}

/// Resizes a row-major image as OpenCV's `INTER_AREA` does when shrinking (each output pixel
/// is the overlap-weighted mean of the source pixels under it); enlarging falls back to
/// bilinear interpolation, as OpenCV does too.
pub fn resize_area(src: &[f32], sw: usize, sh: usize, dw: usize, dh: usize) -> Vec<f32> {
    let horizontal = axis_weights(sw, dw);
    let vertical = axis_weights(sh, dh);
    let mut rows = vec![0.0f32; sh * dw];
    for y in 0..sh {
        let line = &src[y * sw..(y + 1) * sw];
        for (x, taps) in horizontal.iter().enumerate() {
            rows[y * dw + x] = taps.iter().map(|&(i, w)| line[i] * w).sum();
        }
    }
    let mut out = vec![0.0f32; dh * dw];
    for (y, taps) in vertical.iter().enumerate() {
        for &(i, w) in taps {
            let line = &rows[i * dw..(i + 1) * dw];
            for (o, &v) in out[y * dw..(y + 1) * dw].iter_mut().zip(line) {
                *o += v * w;
            }
        }
    }
    out
}

// Source taps (index, weight) of every destination index along one axis.
fn axis_weights(src: usize, dst: usize) -> Vec<Vec<(usize, f32)>> {
    let scale = src as f64 / dst as f64;
    (0..dst)
        .map(|d| {
            if scale >= 1.0 {
                let (lo, hi) = (d as f64 * scale, (d + 1) as f64 * scale);
                let mut taps = Vec::new();
                let mut i = lo.floor() as usize;
                while (i as f64) < hi && i < src {
                    let overlap = (hi.min(i as f64 + 1.0) - lo.max(i as f64)) / scale;
                    if overlap > 1e-9 {
                        taps.push((i, overlap as f32));
                    }
                    i += 1;
                }
                taps
            } else {
                let x = ((d as f64 + 0.5) * scale - 0.5).max(0.0);
                let i = (x.floor() as usize).min(src - 1);
                let f = (x - i as f64) as f32;
                if i + 1 < src {
                    vec![(i, 1.0 - f), (i + 1, f)]
                } else {
                    vec![(i, 1.0)]
                }
            }
        })
        .collect()
}

/// Nearest-neighbour resize sampling at pixel centres (OpenCV `INTER_NEAREST_EXACT`: source
/// index `floor((d + 0.5) * src / dst)`), used for ground-truth disparity and its valid mask.
/// Pixel centres, not OpenCV's older floor rule, reproduce EVAL.md's StereoSGBM reference row.
pub fn resize_nearest<T: Copy>(src: &[T], sw: usize, sh: usize, dw: usize, dh: usize) -> Vec<T> {
    let centre = |d: usize, s: usize, n: usize| ((2 * d + 1) * s / (2 * n)).min(s - 1);
    let xs: Vec<usize> = (0..dw).map(|x| centre(x, sw, dw)).collect();
    (0..dh)
        .flat_map(|y| {
            let row = centre(y, sh, dh);
            xs.iter().map(move |&x| src[row * sw + x])
        })
        .collect()
}

/// Width of the view `profile` makes of the image file `path` (its header only): what the
/// width-dependent defaults (`Pathway::default_readout`) follow. Errors name the file.
pub fn view_width(path: &std::path::Path, profile: Profile) -> Result<usize> {
    use anyhow::Context;
    let (width, height) = crate::io::image_io::dimensions(path, "image")?;
    let size = profile
        .size(width, height)
        .with_context(|| format!("{}", path.display()))?;
    Ok(size.resized.0)
}

/// Loads a stereo pair and applies `profile` to both views; views of different sizes, or a size
/// the profile cannot take, are errors naming the files.
pub fn load_profiled_pair(left: &std::path::Path, right: &std::path::Path, profile: Profile) -> Result<(View, View)> {
    let (l, r, _) = load_profiled_pair_sized(left, right, profile)?;
    Ok((l, r))
}

/// [`load_profiled_pair`], with the views' size as given (width, height), before the profile.
pub fn load_profiled_pair_sized(
    left: &std::path::Path,
    right: &std::path::Path,
    profile: Profile,
) -> Result<(View, View, (usize, usize))> {
    use anyhow::Context;
    let (l, r) = (
        crate::io::image_io::load_gray(left)?,
        crate::io::image_io::load_gray(right)?,
    );
    ensure!(
        (l.width, l.height) == (r.width, r.height),
        "the views differ in size: {} is {}x{}, {} is {}x{}",
        left.display(),
        l.width,
        l.height,
        right.display(),
        r.width,
        r.height
    );
    let apply =
        |image: &GrayImage, path: &std::path::Path| profile.apply(image).with_context(|| format!("{}", path.display()));
    Ok((apply(&l, left)?, apply(&r, right)?, (l.width, l.height)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn eval_profile_sizes() {
        // 432x381 (barn1): 160 x round(141.1) = 141 rows, 140 kept.
        let s = Profile::W160.size(432, 381).unwrap();
        assert_eq!(
            s,
            ProfileSize {
                resized: (160, 141),
                kept_rows: 140
            }
        );
        let s = Profile::W320.size(1344, 372).unwrap();
        assert_eq!(
            s,
            ProfileSize {
                resized: (320, 89),
                kept_rows: 88
            }
        );
        assert!(Profile::W160.size(2000, 4).is_err(), "a sliver has no 4-row band left");
        assert!(Profile::Native.size(162, 48).is_err());
        assert_eq!(Profile::Native.size(160, 48).unwrap().kept_rows, 48);
    }

    #[test]
    fn view_width_reads_the_header_and_applies_the_profile() {
        let dir = crate::io::train_python::tempdir("view-width").unwrap();
        let path = dir.join("view.pgm");
        std::fs::write(&path, crate::io::train_python::pgm(&[0; 432 * 381], 432, 381)).unwrap();
        assert_eq!(view_width(&path, Profile::W160).unwrap(), 160);
        assert_eq!(view_width(&path, Profile::W320).unwrap(), 320);
        // 381 rows do not fit `native` (not a multiple of 4): an error naming the file.
        let err = format!("{:#}", view_width(&path, Profile::Native).unwrap_err());
        assert!(err.contains("view.pgm") && err.contains("multiples of 4"), "{err}");
        let missing = format!("{:#}", view_width(&dir.join("none.png"), Profile::W160).unwrap_err());
        assert!(missing.contains("none.png"), "{missing}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn area_resize_averages_whole_and_fractional_cells() {
        // 2x shrink: plain 2x2 means.
        let src = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0];
        assert_eq!(resize_area(&src, 4, 2, 2, 1), vec![2.5, 4.5]);
        // 3 -> 2 along one axis: [a, (b)/2] weights 2/3,1/3 and 1/3,2/3.
        let out = resize_area(&[0.0, 3.0, 6.0], 3, 1, 2, 1);
        assert!((out[0] - 1.0).abs() < 1e-6 && (out[1] - 5.0).abs() < 1e-6, "{out:?}");
        // A constant image stays constant at any scale.
        let flat = vec![0.4f32; 37 * 23];
        assert!(resize_area(&flat, 37, 23, 16, 9).iter().all(|v| (v - 0.4).abs() < 1e-5));
        assert!(resize_area(&flat, 37, 23, 50, 31)
            .iter()
            .all(|v| (v - 0.4).abs() < 1e-5));
    }

    #[test]
    fn area_resize_matches_opencv() {
        // cv2.resize(a, (16, 9), interpolation=cv2.INTER_AREA) with a = ((i * 37) % 101) / 100.
        let src: Vec<f32> = (0..23 * 37).map(|i| ((i * 37) % 101) as f32 / 100.0).collect();
        let out = resize_area(&src, 37, 23, 16, 9);
        for ((y, x), expected) in [
            ((0, 0), 0.44964),
            ((3, 7), 0.46114),
            ((8, 15), 0.4602),
            ((5, 2), 0.48806),
        ] {
            assert!(
                (out[y * 16 + x] - expected).abs() < 2e-5,
                "({y},{x}): {} vs {expected}",
                out[y * 16 + x]
            );
        }
    }

    #[test]
    fn nearest_resize_samples_pixel_centres() {
        let src: Vec<u8> = (0..6).collect();
        assert_eq!(resize_nearest(&src, 6, 1, 3, 1), vec![1, 3, 5]);
        assert_eq!(resize_nearest(&src, 3, 2, 3, 1), vec![3, 4, 5]);
        // Enlarging repeats each source pixel.
        assert_eq!(resize_nearest(&[7u8, 9], 2, 1, 4, 1), vec![7, 7, 9, 9]);
    }

    #[test]
    fn parses_profile_names() {
        assert_eq!("w320".parse::<Profile>().unwrap(), Profile::W320);
        assert!("w999".parse::<Profile>().is_err());
    }
}
