//! [`DisplaySink`]: the pipeline sink that draws the chosen readout's rows onto the display
//! as they come out, and times the stages.

use std::time::{Duration, Instant};

use bino_core::config::HEAD_MAX_DISP;
use bino_core::crc32::Crc32;
use bino_core::matching::DISPARITY_FRAC_BITS;
use bino_core::model::head::HeadRow;
use bino_core::pipeline::{CensusRow, FusedRow, HeadChecked, MatchedRow, Sink, Stage};
use embedded_graphics::pixelcolor::{Rgb565, Rgb888};

use super::display::Framebuffer;
use super::layout::Panel;
use crate::io::colour::colourise;
use crate::readout::{Method, Readout};

/// Colour of cells the left-right check rejected.
pub const REJECTED: Rgb565 = Rgb565::new(3, 6, 3);

/// Draws each token row of the chosen readout onto the display as the pipeline emits it,
/// and times the pipeline's stages and its own drawing.
pub struct DisplaySink<'f> {
    fb: &'f mut Framebuffer,
    panel: Panel,
    readout: Readout,
    /// Colour scale: this many patch columns is the far end of the map.
    max_disparity: f32,
    /// Head rows waiting for their left-right check (it comes a row of the mirrored head later).
    pending_heads: Vec<(usize, Vec<u16>)>,
    /// Rows drawn: token rows, or pixel rows for a `+ref` readout.
    pub rows_drawn: usize,
    /// CRC-32 of a `+ref` readout's refined rows as they came (Q8 px, little-endian): the
    /// firmware's `refined` digest.
    refined_crc: Crc32,
    times: [Duration; Stage::ALL.len() + 1],
    current: Option<(usize, Instant)>,
}

impl<'f> DisplaySink<'f> {
    /// A sink drawing `readout` into `panel` of `fb`; `max_cols` candidates of nolink and sgm
    /// (the head's and the census's colour scale is the head's trained range).
    pub fn new(fb: &'f mut Framebuffer, panel: Panel, readout: Readout, max_cols: usize) -> Self {
        // The census searches as far as the head (4 px a head candidate).
        let head_range = readout.uses_head() || readout.method == Method::Census;
        let candidates = if head_range { HEAD_MAX_DISP } else { max_cols };
        Self {
            fb,
            panel,
            readout,
            max_disparity: candidates.saturating_sub(1).max(1) as f32,
            pending_heads: Vec::new(),
            rows_drawn: 0,
            refined_crc: Crc32::new(),
            times: [Duration::ZERO; Stage::ALL.len() + 1],
            current: None,
        }
    }

    /// Charges the time since the last switch to the current bucket and starts `bucket`.
    fn switch(&mut self, bucket: Option<usize>) -> Option<usize> {
        let now = Instant::now();
        let previous = self.current.take().map(|(b, since)| {
            self.times[b] += now - since;
            b
        });
        self.current = bucket.map(|b| (b, now));
        previous
    }

    /// The refined rows' digest (`refined_crc`), for a `+ref` readout.
    pub fn refined_digest(&self) -> Option<u32> {
        self.readout.refine.then(|| self.refined_crc.finish())
    }

    /// Stops the clock (after the run).
    pub fn finish(&mut self) {
        self.switch(None);
    }

    /// Time in each pipeline stage, then in drawing.
    pub fn stage_times(&self) -> Vec<(&'static str, Duration)> {
        let names = Stage::ALL.iter().map(|s| s.name()).chain(["draw"]);
        names.zip(self.times).collect()
    }

    /// Draws one token row of the readout: a `+lr` readout's rejected cells filled by its rule
    /// (`bino_core::lr::Fill`), the others' shown dark.
    fn show_row(&mut self, row: usize, disparity_q8: &[u16], consistent: &[u8]) {
        if self.readout.lr {
            let mut filled = disparity_q8.to_vec();
            if self.readout.method.fill().apply(&mut filled, consistent).is_ok() {
                self.draw_row(row, &filled, &vec![1; filled.len()]);
            }
        } else {
            self.draw_row(row, disparity_q8, consistent);
        }
    }

    /// Draws one token row (disparity in Q8 patch columns, 1 = passed the left-right check).
    pub(super) fn draw_row(&mut self, row: usize, disparity_q8: &[u16], consistent: &[u8]) {
        let previous = self.switch(Some(Stage::ALL.len()));
        let unit = (1u32 << DISPARITY_FRAC_BITS) as f32;
        let values: Vec<f32> = disparity_q8.iter().map(|&d| d as f32 / unit).collect();
        let colours = colourise(&values, self.max_disparity);
        let cell = crate::eval::PIXELS_PER_PATCH_COLUMN;
        for (c, rgb) in colours.chunks_exact(3).enumerate() {
            let colour = if consistent.get(c) == Some(&1) {
                Rgb565::from(Rgb888::new(rgb[0], rgb[1], rgb[2]))
            } else {
                REJECTED
            };
            self.panel.fill(
                self.fb,
                (c * cell, (c + 1) * cell),
                (row * cell, (row + 1) * cell),
                colour,
            );
        }
        self.rows_drawn += 1;
        self.switch(previous);
    }

    /// Draws one refined pixel row (Q8 px) on the token rows' colour scale.
    fn draw_pixel_row(&mut self, row: usize, disparity_q8: &[u16]) {
        let previous = self.switch(Some(Stage::ALL.len()));
        let unit = (1u32 << DISPARITY_FRAC_BITS) as f32;
        let values: Vec<f32> = disparity_q8.iter().map(|&d| d as f32 / unit).collect();
        let max_px = self.max_disparity * crate::eval::PIXELS_PER_PATCH_COLUMN as f32;
        for (x, rgb) in colourise(&values, max_px).chunks_exact(3).enumerate() {
            let colour = Rgb565::from(Rgb888::new(rgb[0], rgb[1], rgb[2]));
            self.panel.fill(self.fb, (x, x + 1), (row, row + 1), colour);
        }
        self.rows_drawn += 1;
        self.switch(previous);
    }
}

impl Sink for DisplaySink<'_> {
    fn stage(&mut self, stage: Stage) {
        let bucket = Stage::ALL.iter().position(|&s| s == stage);
        self.switch(bucket);
    }

    fn matched(&mut self, row: &MatchedRow<'_>) {
        if self.readout.refine {
            return;
        }
        match self.readout.method {
            Method::Nolink => self.show_row(row.row, row.wta_q8, row.wta_consistent),
            Method::Sgm => self.show_row(row.row, row.sgm_q8, row.sgm_consistent),
            Method::Head | Method::Fused | Method::Census | Method::CensusFused | Method::FusedAll => {}
        }
    }

    fn head(&mut self, row: HeadRow<'_>) {
        if self.readout.method == Method::Head && !self.readout.refine {
            self.pending_heads.push((row.row, row.disparity_q8.to_vec()));
        }
    }

    fn head_checked(&mut self, row: &HeadChecked<'_>) {
        let Some(at) = self.pending_heads.iter().position(|(r, _)| *r == row.row) else {
            return;
        };
        let (_, disparity) = self.pending_heads.remove(at);
        self.show_row(row.row, &disparity, row.consistent);
    }

    fn fused(&mut self, row: &FusedRow<'_>) {
        if self.readout.fuses() && !self.readout.refine {
            self.show_row(row.row, row.disparity_q8, row.consistent);
        }
    }

    fn census(&mut self, row: &CensusRow<'_>) {
        if self.readout.method == Method::Census && !self.readout.refine {
            self.show_row(row.row, row.disparity_q8, row.consistent);
        }
    }

    fn refined(&mut self, row: usize, disparity_q8: &[u16]) {
        if self.readout.refine {
            for d in disparity_q8 {
                self.refined_crc.update(&d.to_le_bytes());
            }
            self.draw_pixel_row(row, disparity_q8);
        }
    }
}
