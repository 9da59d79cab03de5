//! Where the pictures sit on the simulated display: [`Layout`] places the camera view, the
//! disparity panel and the status bar; a [`Panel`] scales an image-sized picture into its
//! rectangle.

use anyhow::{ensure, Result};
use embedded_graphics::mono_font::ascii::FONT_6X10;
use embedded_graphics::mono_font::MonoTextStyle;
use embedded_graphics::pixelcolor::{Rgb565, RgbColor};
use embedded_graphics::prelude::*;
use embedded_graphics::primitives::Rectangle;
use embedded_graphics::text::{Baseline, Text};

use super::display::{DisplaySize, Framebuffer};
use crate::io::image_io::GrayImage;

/// Status lines at the bottom of the display.
const STATUS_LINES: usize = 2;
/// Pixel rows per status line (FONT_6X10 is 10 rows high, plus one of spacing).
const LINE_PITCH: usize = 11;
/// Pixels between the camera view and the disparity panel.
const GAP: usize = 2;
/// Background of the status bar.
const STATUS_BACKGROUND: Rgb565 = Rgb565::new(0, 0, 6);

/// A rectangle of the display showing an image-sized picture scaled by `num / den`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Panel {
    /// Left column on the display.
    pub x: usize,
    /// Top row on the display.
    pub y: usize,
    /// Columns used.
    pub width: usize,
    /// Rows used.
    pub height: usize,
    num: usize,
    den: usize,
}

impl Panel {
    /// The largest scaling of an `image_w x image_h` picture into the `room_w x room_h`
    /// rectangle at `(x, y)`, centred in it.
    pub(super) fn fit(x: usize, y: usize, room_w: usize, room_h: usize, image_w: usize, image_h: usize) -> Self {
        // Scale = min(room_w / image_w, room_h / image_h), kept as a fraction.
        let (num, den) = if room_w * image_h <= room_h * image_w {
            (room_w, image_w)
        } else {
            (room_h, image_h)
        };
        let (width, height) = (image_w * num / den.max(1), image_h * num / den.max(1));
        Self {
            x: x + (room_w - width.min(room_w)) / 2,
            y: y + (room_h - height.min(room_h)) / 2,
            width,
            height,
            num,
            den: den.max(1),
        }
    }

    /// Display pixels `[start, end)` covered by image pixels `[from, to)` along one axis.
    fn span(&self, from: usize, to: usize) -> (usize, usize) {
        (from * self.num / self.den, to * self.num / self.den)
    }

    /// The image pixel shown at display offset `d` along one axis (nearest below).
    fn source(&self, d: usize) -> usize {
        d * self.den / self.num.max(1)
    }

    /// Fills the display rectangle covering image pixels `[x0, x1) x [y0, y1)`.
    pub(super) fn fill(
        &self,
        fb: &mut Framebuffer,
        (x0, x1): (usize, usize),
        (y0, y1): (usize, usize),
        colour: Rgb565,
    ) {
        let (dx0, dx1) = self.span(x0, x1);
        let (dy0, dy1) = self.span(y0, y1);
        let area = Rectangle::new(
            Point::new((self.x + dx0) as i32, (self.y + dy0) as i32),
            Size::new((dx1 - dx0) as u32, (dy1 - dy0) as u32),
        );
        let Ok(()) = fb.fill_solid(&area, colour);
    }

    /// The panel's rectangle on the display.
    pub fn rectangle(&self) -> Rectangle {
        Rectangle::new(
            Point::new(self.x as i32, self.y as i32),
            Size::new(self.width as u32, self.height as u32),
        )
    }
}

/// Where the camera view, the disparity map and the status bar sit on the display: the two
/// pictures one above the other or side by side, whichever shows them larger.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layout {
    /// The left camera view.
    pub camera: Panel,
    /// The disparity map (same scale as the camera view: cell (r, c) covers its 4x4 pixels).
    pub disparity: Panel,
    /// Top row of the status bar.
    pub status_y: usize,
}

impl Layout {
    /// The layout of a `width x height` pair on `display`.
    pub fn new(display: DisplaySize, width: usize, height: usize) -> Result<Self> {
        let (w, h) = (display.width, display.height);
        let status_y = h.saturating_sub(STATUS_LINES * LINE_PITCH + 1);
        let room = status_y.saturating_sub(GAP);
        let stacked = (
            Panel::fit(0, 0, w, room / 2, width, height),
            Panel::fit(0, room / 2 + GAP, w, room / 2, width, height),
        );
        let half = w.saturating_sub(GAP) / 2;
        let side = (
            Panel::fit(0, 0, half, room, width, height),
            Panel::fit(half + GAP, 0, half, room, width, height),
        );
        let (camera, disparity) = if side.0.width * side.0.height > stacked.0.width * stacked.0.height {
            side
        } else {
            stacked
        };
        ensure!(
            disparity.width >= 1 && disparity.height >= 1 && status_y > 0,
            "display {display} is too small for a {width}x{height} image and {STATUS_LINES} status lines"
        );
        Ok(Self {
            camera,
            disparity,
            status_y,
        })
    }

    /// Draws the left camera view (gray) into its panel.
    pub fn draw_camera(&self, fb: &mut Framebuffer, left: &GrayImage) {
        let p = &self.camera;
        let pixels = (0..p.height).flat_map(|dy| {
            let row = p.source(dy).min(left.height - 1) * left.width;
            (0..p.width).map(move |dx| {
                let g = left.pixels[row + p.source(dx).min(left.width - 1)];
                Rgb565::new(g >> 3, g >> 2, g >> 3)
            })
        });
        let Ok(()) = fb.fill_contiguous(&p.rectangle(), pixels);
    }

    /// Draws the status bar: one line of text per entry (FONT_6X10, white).
    pub fn draw_status(&self, fb: &mut Framebuffer, lines: &[String]) {
        let size = fb.display_size();
        let bar = Rectangle::new(
            Point::new(0, self.status_y as i32),
            Size::new(size.width as u32, (size.height - self.status_y) as u32),
        );
        let Ok(()) = fb.fill_solid(&bar, STATUS_BACKGROUND);
        let style = MonoTextStyle::new(&FONT_6X10, Rgb565::WHITE);
        for (i, line) in lines.iter().enumerate() {
            let at = Point::new(2, (self.status_y + 1 + i * LINE_PITCH) as i32);
            let Ok(_) = Text::with_baseline(line, at, style, Baseline::Top).draw(fb);
        }
    }
}
