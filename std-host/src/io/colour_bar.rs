//! The colour bar under `bino run`'s `disparity.png`: the Turbo scale from 0 to the picture's
//! largest disparity, labelled with both ends in pixels, drawn with embedded-graphics' fixed
//! font (the same the simulated display uses), so the picture reads without the PFM.

use embedded_graphics::mono_font::ascii::FONT_6X10;
use embedded_graphics::mono_font::MonoTextStyle;
use embedded_graphics::pixelcolor::Rgb888;
use embedded_graphics::prelude::*;
use embedded_graphics::text::{Alignment, Baseline, Text, TextStyleBuilder};
use image::RgbImage;

use super::colour::colourise;

/// Rows of the gradient strip.
const BAR_ROWS: u32 = 8;
/// Rows of the label line under it (the font's height and a gap).
const LABEL_ROWS: u32 = 12;

/// `picture` with the colour bar of the range `0..=max` px below it: a gradient strip across its
/// width and the range's ends as text (left `0 px`, right `max px`, whenever they fit).
pub fn with_colour_bar(picture: RgbImage, max: f32) -> RgbImage {
    let (w, h) = picture.dimensions();
    let mut out = RgbImage::new(w, h + 1 + BAR_ROWS + LABEL_ROWS);
    image::imageops::replace(&mut out, &picture, 0, 0);
    let ramp: Vec<f32> = (0..w).map(|x| max * x as f32 / (w.max(2) - 1) as f32).collect();
    let colours = colourise(&ramp, max);
    for y in h + 1..h + 1 + BAR_ROWS {
        for x in 0..w {
            let at = 3 * x as usize;
            out.put_pixel(x, y, image::Rgb([colours[at], colours[at + 1], colours[at + 2]]));
        }
    }
    let (low, high) = ("0 px".to_string(), format!("{max:.1} px"));
    let font_width = FONT_6X10.character_size.width;
    let fits = (low.len() + high.len() + 2) as u32 * font_width <= w;
    if fits {
        let style = MonoTextStyle::new(&FONT_6X10, Rgb888::WHITE);
        let baseline = Point::new(0, (h + 1 + BAR_ROWS + 1) as i32);
        let mut target = Picture(&mut out);
        for (text, x, alignment) in [(&low, 0, Alignment::Left), (&high, w as i32 - 1, Alignment::Right)] {
            let layout = TextStyleBuilder::new()
                .alignment(alignment)
                .baseline(Baseline::Top)
                .build();
            // Drawing into an in-memory picture cannot fail (pixels outside it are skipped).
            let _ = Text::with_text_style(text, Point::new(x, baseline.y), style, layout).draw(&mut target);
        }
    }
    out
}

/// An `RgbImage` as an embedded-graphics draw target.
struct Picture<'a>(&'a mut RgbImage);

impl OriginDimensions for Picture<'_> {
    fn size(&self) -> Size {
        Size::new(self.0.width(), self.0.height())
    }
}

impl DrawTarget for Picture<'_> {
    type Color = Rgb888;
    type Error = core::convert::Infallible;

    fn draw_iter<I: IntoIterator<Item = Pixel<Rgb888>>>(&mut self, pixels: I) -> Result<(), Self::Error> {
        for Pixel(p, c) in pixels {
            if let (Ok(x), Ok(y)) = (u32::try_from(p.x), u32::try_from(p.y)) {
                if x < self.0.width() && y < self.0.height() {
                    self.0.put_pixel(x, y, image::Rgb([c.r(), c.g(), c.b()]));
                }
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bar_spans_the_range_below_the_picture_with_its_ends_labelled() {
        let picture = RgbImage::from_pixel(160, 48, image::Rgb([10, 20, 30]));
        let out = with_colour_bar(picture, 40.0);
        assert_eq!(out.dimensions(), (160, 48 + 1 + BAR_ROWS + LABEL_ROWS));
        assert_eq!(out.get_pixel(5, 5).0, [10, 20, 30], "the picture is kept");
        // The strip runs from the scale's far end (blue) to its near end (red): a tenth in from
        // each side.
        let (first, last) = (out.get_pixel(16, 50).0, out.get_pixel(143, 50).0);
        assert!(first[2] > first[0] && last[0] > last[2], "{first:?} {last:?}");
        // Both labels drew white text on the label line.
        let white = |xs: std::ops::Range<u32>| {
            xs.flat_map(|x| (57..out.height()).map(move |y| (x, y)))
                .filter(|&(x, y)| out.get_pixel(x, y).0 == [255, 255, 255])
                .count()
        };
        assert!(white(0..30) > 10 && white(120..160) > 10);
        // Too narrow for labels: the strip alone.
        let narrow = with_colour_bar(RgbImage::new(20, 8), 40.0);
        assert_eq!(narrow.dimensions(), (20, 8 + 1 + BAR_ROWS + LABEL_ROWS));
    }
}
