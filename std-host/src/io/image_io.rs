//! Loading views: any PNG/PPM/PGM/JPEG, gray or colour, as 8-bit grayscale.
//!
//! Colour goes to gray with OpenCV's fixed-point BT.601 rule, so the Rust CLI and the Python
//! training code (which uses `cv2.cvtColor`) see the same pixels.

use std::io::Cursor;
use std::path::Path;

use anyhow::{bail, ensure, Context, Result};

/// Widest and tallest image any command decodes (EVAL.md's largest pairs are under 3,000
/// pixels wide); a file declaring more is refused from its header, before any pixel buffer
/// is allocated (a decompression bomb).
pub const MAX_IMAGE_SIDE: u32 = 16_384;
/// Most bytes one decoded image may take (the `image` crate's allocation limit).
pub const MAX_IMAGE_BYTES: u64 = 1 << 30;

/// An 8-bit grayscale image, row-major.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct GrayImage {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `width * height` pixels, row by row.
    pub pixels: Vec<u8>,
}

impl GrayImage {
    /// Wraps `pixels`; fails when the size disagrees or the image is empty.
    pub fn new(width: usize, height: usize, pixels: Vec<u8>) -> Result<Self> {
        ensure!(width > 0 && height > 0, "image is empty ({width}x{height})");
        ensure!(
            pixels.len() == width * height,
            "{width}x{height} image needs {} pixels, got {}",
            width * height,
            pixels.len()
        );
        Ok(Self { width, height, pixels })
    }
}

/// OpenCV's `COLOR_RGB2GRAY` on 8-bit input: (4899 R + 9617 G + 1868 B + 2^13) >> 14.
pub fn rgb_to_gray(r: u8, g: u8, b: u8) -> u8 {
    ((4899 * r as u32 + 9617 * g as u32 + 1868 * b as u32 + (1 << 13)) >> 14) as u8
}

/// Decodes the image file `path` (the command's `what`: "image", "ground truth"): a regular,
/// non-empty file whose header declares at most [`MAX_IMAGE_SIDE`] pixels a side, decoded
/// under the `image` crate's allocation limit. Every error names the file.
pub fn decode(path: &Path, what: &str) -> Result<image::DynamicImage> {
    let bytes = crate::io::files::read(path, what)?;
    declared_size(&bytes, path, what)?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIDE);
    limits.max_image_height = Some(MAX_IMAGE_SIDE);
    limits.max_alloc = Some(MAX_IMAGE_BYTES);
    let mut decoder = reader(&bytes, path, what)?;
    decoder.limits(limits);
    decoder.decode().with_context(|| {
        format!(
            "cannot decode {what} {} (PNG, PPM/PGM or JPEG expected)",
            path.display()
        )
    })
}

/// Width and height the image file `path` declares, read from its header; errors as
/// [`decode`]'s.
pub fn dimensions(path: &Path, what: &str) -> Result<(usize, usize)> {
    let bytes = crate::io::files::read(path, what)?;
    let (width, height) = declared_size(&bytes, path, what)?;
    Ok((width as usize, height as usize))
}

fn reader<'a>(bytes: &'a [u8], path: &Path, what: &str) -> Result<image::ImageReader<Cursor<&'a [u8]>>> {
    image::ImageReader::new(Cursor::new(bytes))
        .with_guessed_format()
        .with_context(|| format!("cannot read {what} {}", path.display()))
}

/// The header's size, refused above [`MAX_IMAGE_SIDE`] a side.
fn declared_size(bytes: &[u8], path: &Path, what: &str) -> Result<(u32, u32)> {
    let (width, height) = reader(bytes, path, what)?.into_dimensions().with_context(|| {
        format!(
            "cannot decode {what} {} (PNG, PPM/PGM or JPEG expected)",
            path.display()
        )
    })?;
    if width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
        bail!(
            "{what} {} declares {width}x{height} pixels, more than the {MAX_IMAGE_SIDE}x{MAX_IMAGE_SIDE} limit",
            path.display()
        );
    }
    Ok((width, height))
}

/// Loads an image file as 8-bit gray. The error names the file and what is wrong with it.
pub fn load_gray(path: &Path) -> Result<GrayImage> {
    let decoded = decode(path, "image")?;
    let (width, height) = (decoded.width() as usize, decoded.height() as usize);
    let pixels = if decoded.color().has_color() {
        decoded
            .to_rgb8()
            .pixels()
            .map(|p| rgb_to_gray(p[0], p[1], p[2]))
            .collect()
    } else {
        decoded.to_luma8().into_raw()
    };
    GrayImage::new(width, height, pixels).with_context(|| format!("image {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gray_rule_matches_opencv_reference_values() {
        // Values from cv2.cvtColor(np.uint8([[[r, g, b]]]), cv2.COLOR_RGB2GRAY).
        assert_eq!(rgb_to_gray(255, 255, 255), 255);
        assert_eq!(rgb_to_gray(0, 0, 0), 0);
        assert_eq!(rgb_to_gray(255, 0, 0), 76);
        assert_eq!(rgb_to_gray(0, 255, 0), 150);
        assert_eq!(rgb_to_gray(0, 0, 255), 29);
        assert_eq!(rgb_to_gray(12, 200, 99), 132);
    }

    #[test]
    fn missing_and_garbage_files_are_named_in_errors() {
        let dir = std::env::temp_dir().join(format!("bino-image-io-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let missing = dir.join("missing.png");
        let err = format!("{:#}", load_gray(&missing).unwrap_err());
        assert!(err.contains("missing.png") && err.contains("does not exist"), "{err}");
        let garbage = dir.join("garbage.png");
        std::fs::write(&garbage, b"definitely not an image").unwrap();
        let err = format!("{:#}", load_gray(&garbage).unwrap_err());
        assert!(err.contains("garbage.png"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
