//! The simulated board display: an RGB565 framebuffer (as a small SPI TFT's memory holds it)
//! that `embedded-graphics` draws on, saved as a PNG on the host.

use std::convert::Infallible;
use std::fmt;
use std::path::Path;
use std::str::FromStr;

use anyhow::{bail, ensure, Result};
use embedded_graphics::draw_target::DrawTarget;
use embedded_graphics::geometry::{Dimensions, OriginDimensions, Size};
use embedded_graphics::pixelcolor::raw::{RawData, RawU16};
use embedded_graphics::pixelcolor::{Rgb565, Rgb888, RgbColor};
use embedded_graphics::primitives::Rectangle;
use embedded_graphics::Pixel;

/// Width and height of a display in pixels (`--display WxH`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DisplaySize {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
}

impl DisplaySize {
    /// 320x240, the common 2.4"/2.8" SPI TFT of camera boards.
    pub const QVGA: Self = Self {
        width: 320,
        height: 240,
    };
    /// Smallest side accepted.
    pub const MIN_SIDE: usize = 32;
    /// Largest side accepted.
    pub const MAX_SIDE: usize = 4096;
}

impl fmt::Display for DisplaySize {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}x{}", self.width, self.height)
    }
}

impl FromStr for DisplaySize {
    type Err = anyhow::Error;

    fn from_str(s: &str) -> Result<Self> {
        let Some((w, h)) = s.split_once(['x', 'X']) else {
            bail!("display size {s:?} must be WIDTHxHEIGHT, e.g. 320x240");
        };
        let (width, height) = match (w.trim().parse::<usize>(), h.trim().parse::<usize>()) {
            (Ok(w), Ok(h)) => (w, h),
            _ => bail!("display size {s:?} must be WIDTHxHEIGHT, e.g. 320x240"),
        };
        let range = Self::MIN_SIDE..=Self::MAX_SIDE;
        ensure!(
            range.contains(&width) && range.contains(&height),
            "display size {s:?}: each side must be {} to {} pixels",
            Self::MIN_SIDE,
            Self::MAX_SIDE
        );
        Ok(Self { width, height })
    }
}

/// RGB565 pixels, row-major, one `u16` each (the display controller's format).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Framebuffer {
    size: DisplaySize,
    pixels: Vec<u16>,
}

impl Framebuffer {
    /// A black framebuffer.
    pub fn new(size: DisplaySize) -> Self {
        Self {
            size,
            pixels: vec![0; size.width * size.height],
        }
    }

    /// Its size.
    pub fn display_size(&self) -> DisplaySize {
        self.size
    }

    /// The raw RGB565 words, row-major.
    pub fn raw(&self) -> &[u16] {
        &self.pixels
    }

    /// The colour at `(x, y)`, `None` outside.
    pub fn pixel(&self, x: usize, y: usize) -> Option<Rgb565> {
        if x >= self.size.width {
            return None;
        }
        let word = *self.pixels.get(y * self.size.width + x)?;
        Some(Rgb565::from(RawU16::new(word)))
    }

    /// The picture as 8-bit RGB (each channel scaled by `round(v * 255 / max)`).
    pub fn to_rgb888(&self) -> image::RgbImage {
        let bytes = self
            .pixels
            .iter()
            .flat_map(|&word| {
                let c = Rgb888::from(Rgb565::from(RawU16::new(word)));
                [c.r(), c.g(), c.b()]
            })
            .collect();
        image::RgbImage::from_raw(self.size.width as u32, self.size.height as u32, bytes)
            .unwrap_or_else(|| image::RgbImage::new(self.size.width as u32, self.size.height as u32))
    }

    /// Writes the picture as PNG through a temporary file (no partial file on failure).
    pub fn save_png(&self, path: &Path) -> Result<()> {
        crate::io::files::save_png(&self.to_rgb888().into(), path)
    }

    fn index(&self, x: i32, y: i32) -> Option<usize> {
        let (x, y) = (usize::try_from(x).ok()?, usize::try_from(y).ok()?);
        (x < self.size.width && y < self.size.height).then(|| y * self.size.width + x)
    }
}

impl OriginDimensions for Framebuffer {
    fn size(&self) -> Size {
        Size::new(self.size.width as u32, self.size.height as u32)
    }
}

impl DrawTarget for Framebuffer {
    type Color = Rgb565;
    type Error = Infallible;

    /// Pixels outside the display are dropped, as a display driver clips them.
    fn draw_iter<I>(&mut self, pixels: I) -> Result<(), Self::Error>
    where
        I: IntoIterator<Item = Pixel<Self::Color>>,
    {
        for Pixel(at, colour) in pixels {
            if let Some(i) = self.index(at.x, at.y) {
                self.pixels[i] = RawU16::from(colour).into_inner();
            }
        }
        Ok(())
    }

    fn fill_solid(&mut self, area: &Rectangle, colour: Self::Color) -> Result<(), Self::Error> {
        let area = area.intersection(&self.bounding_box());
        let Some(bottom_right) = area.bottom_right() else {
            return Ok(());
        };
        let word = RawU16::from(colour).into_inner();
        let (x0, x1) = (area.top_left.x as usize, bottom_right.x as usize + 1);
        for y in area.top_left.y as usize..=bottom_right.y as usize {
            let row = y * self.size.width;
            self.pixels[row + x0..row + x1].fill(word);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use embedded_graphics::mono_font::ascii::FONT_6X10;
    use embedded_graphics::mono_font::MonoTextStyle;
    use embedded_graphics::prelude::*;
    use embedded_graphics::primitives::PrimitiveStyle;
    use embedded_graphics::text::{Baseline, Text};

    use super::*;

    fn small() -> Framebuffer {
        Framebuffer::new(DisplaySize { width: 40, height: 32 })
    }

    #[test]
    fn rgb565_becomes_rgb888_by_channel_scaling() {
        let mut fb = small();
        let colours = [
            (Rgb565::new(31, 63, 31), [255, 255, 255]),
            (Rgb565::new(0, 0, 0), [0, 0, 0]),
            // round(16 * 255 / 31) = 132, round(32 * 255 / 63) = 130, round(8 * 255 / 31) = 66.
            (Rgb565::new(16, 32, 8), [132, 130, 66]),
            (Rgb565::new(1, 0, 0), [8, 0, 0]),
            (Rgb565::new(0, 1, 0), [0, 4, 0]),
        ];
        for (x, (colour, _)) in colours.iter().enumerate() {
            Pixel(Point::new(x as i32, 0), *colour).draw(&mut fb).unwrap();
        }
        // The word layout is the display's: RRRRRGGGGGGBBBBB.
        assert_eq!(fb.raw()[0], 0xFFFF);
        assert_eq!(fb.raw()[2], (16 << 11) | (32 << 5) | 8);
        let rgb = fb.to_rgb888();
        assert_eq!(rgb.dimensions(), (40, 32));
        for (x, (_, expected)) in colours.iter().enumerate() {
            assert_eq!(rgb.get_pixel(x as u32, 0).0, *expected, "pixel {x}");
        }
    }

    #[test]
    fn a_filled_rectangle_lands_on_its_pixels_only() {
        let mut fb = small();
        let red = Rgb565::RED;
        Rectangle::new(Point::new(3, 5), Size::new(4, 2))
            .into_styled(PrimitiveStyle::with_fill(red))
            .draw(&mut fb)
            .unwrap();
        for y in 0..32 {
            for x in 0..40 {
                let inside = (3..7).contains(&x) && (5..7).contains(&y);
                let expected = if inside { red } else { Rgb565::BLACK };
                assert_eq!(fb.pixel(x, y), Some(expected), "({x}, {y})");
            }
        }
        assert_eq!(fb.raw().iter().filter(|&&w| w != 0).count(), 8);
    }

    #[test]
    fn drawing_off_the_display_is_clipped() {
        let mut fb = small();
        Rectangle::new(Point::new(-5, 30), Size::new(8, 10))
            .into_styled(PrimitiveStyle::with_fill(Rgb565::GREEN))
            .draw(&mut fb)
            .unwrap();
        // Columns 0..3 of rows 30..32 survive.
        assert_eq!(fb.raw().iter().filter(|&&w| w != 0).count(), 6);
        assert_eq!(fb.pixel(2, 31), Some(Rgb565::GREEN));
        assert_eq!(fb.pixel(3, 31), Some(Rgb565::BLACK));
        // A stroked outline goes through draw_iter, which clips too.
        Rectangle::new(Point::new(35, -2), Size::new(10, 5))
            .into_styled(PrimitiveStyle::with_stroke(Rgb565::BLUE, 1))
            .draw(&mut fb)
            .unwrap();
        assert_eq!(fb.pixel(35, 0), Some(Rgb565::BLUE));
        assert_eq!(fb.pixel(36, 2), Some(Rgb565::BLUE));
        assert_eq!(fb.pixel(36, 1), Some(Rgb565::BLACK));
    }

    #[test]
    fn text_is_drawn_inside_its_cell() {
        let mut fb = small();
        let style = MonoTextStyle::new(&FONT_6X10, Rgb565::WHITE);
        Text::with_baseline("H", Point::new(10, 4), style, Baseline::Top)
            .draw(&mut fb)
            .unwrap();
        let lit: Vec<(usize, usize)> = (0..32)
            .flat_map(|y| (0..40).map(move |x| (x, y)))
            .filter(|&(x, y)| fb.pixel(x, y) == Some(Rgb565::WHITE))
            .collect();
        assert!(lit.len() > 8, "{lit:?}");
        assert!(
            lit.iter().all(|&(x, y)| (10..16).contains(&x) && (4..14).contains(&y)),
            "{lit:?}"
        );
    }

    #[test]
    fn display_sizes_parse_and_bad_ones_are_refused() {
        assert_eq!("320x240".parse::<DisplaySize>().unwrap(), DisplaySize::QVGA);
        assert_eq!(
            "128X64".parse::<DisplaySize>().unwrap(),
            DisplaySize { width: 128, height: 64 }
        );
        for bad in ["320", "x240", "320x", "axb", "8x8", "320x99999"] {
            assert!(bad.parse::<DisplaySize>().is_err(), "{bad}");
        }
    }
}
