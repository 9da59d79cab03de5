//! A rectified pair through `bino-core` on the host: both views to grey at the preset's width
//! ([`WIDTH`], rows cropped to a multiple of 4), every row through the pipeline with the boards'
//! readouts ([`bino_core::preset`]), the refined disparity collected row by row.

use bino_core::blob::Blob;
use bino_core::pipeline::{Pipeline, Sink, SlicePair};
use bino_core::preset;
use image::imageops::{self, FilterType};
use image::{DynamicImage, GrayImage, ImageBuffer};

/// The width the pair runs at: the preset's (its refinement and the board budget are made for
/// 160-px views). Disparities are in pixels of this width.
pub const WIDTH: u32 = 160;

/// The shipped weight blob, embedded (a program could read it from a file instead).
pub static BLOB: &[u8] = include_bytes!("../../../weights/bino_int8.bin");

/// The refined disparity of a pair: one value per pixel, Q8 pixels (value / 256 = disparity in
/// pixels of the run's [`WIDTH`]-px views).
pub struct Disparity {
    /// Width in pixels ([`WIDTH`]).
    pub width: u32,
    /// Rows (the resized views' height, cropped to a multiple of 4).
    pub height: u32,
    /// Row-major Q8 pixels.
    pub q8: Vec<u16>,
}

impl Disparity {
    /// The disparity at `(x, y)` in pixels.
    pub fn px(&self, x: u32, y: u32) -> f32 {
        f32::from(self.q8[(y * self.width + x) as usize]) / 256.0
    }

    /// An 8-bit grey picture: 8 grey levels per pixel of disparity (saturating at 31.875 px,
    /// more than a 160-px view of a usual scene holds).
    pub fn to_image(&self) -> GrayImage {
        let grey = self.q8.iter().map(|&d| (d / 32).min(255) as u8).collect();
        ImageBuffer::from_raw(self.width, self.height, grey).expect("width x height values")
    }
}

/// Collects the refined rows.
struct Rows(Vec<u16>);

impl Sink for Rows {
    // The token-grid readouts (Q8 patch columns): not used here.
    fn refined(&mut self, _row: usize, disparity_q8: &[u16]) {
        self.0.extend_from_slice(disparity_q8);
    }
}

/// A view in grey at [`WIDTH`], its height scaled alike and cropped to a multiple of 4 rows.
pub fn prepare(view: &DynamicImage) -> GrayImage {
    let grey = view.to_luma8();
    if grey.width() == WIDTH && grey.height().is_multiple_of(4) {
        return grey;
    }
    let height = (f64::from(grey.height()) * f64::from(WIDTH) / f64::from(grey.width())).round() as u32;
    let resized = imageops::resize(&grey, WIDTH, height.max(4), FilterType::Triangle);
    imageops::crop_imm(&resized, 0, 0, WIDTH, resized.height() / 4 * 4).to_image()
}

/// The refined disparity of a rectified pair (any size, colour or grey; both views the same size).
pub fn disparity(left: &DynamicImage, right: &DynamicImage) -> Result<Disparity, Box<dyn std::error::Error>> {
    if left.width() != right.width() || left.height() != right.height() {
        return Err(bino_core::Error::PairMismatch.into());
    }
    let (left, right) = (prepare(left), prepare(right));
    let (width, height) = (left.width() as usize, left.height() as usize);
    let pipeline = Pipeline::new(Blob::parse(BLOB)?)?;
    // The arena: the preset's `const fn`, here at run time for this height (a board sizes a
    // static at compile time for its band).
    let mut arena = vec![0u8; preset::arena_bytes(height, width)];
    let mut rows = SlicePair::new(left.as_raw(), right.as_raw(), width, height)?;
    let mut sink = Rows(Vec::with_capacity(width * height));
    pipeline.run_refined(&mut rows, &preset::OPTIONS, &preset::REFINE, &mut arena, &mut sink)?;
    Ok(Disparity {
        width: WIDTH,
        height: height as u32,
        q8: sink.0,
    })
}

/// Writes `disparity` as an 8-bit grey PNG ([`Disparity::to_image`]).
pub fn save(disparity: &Disparity, path: &std::path::Path) -> image::ImageResult<()> {
    disparity.to_image().save_with_format(path, image::ImageFormat::Png)
}
