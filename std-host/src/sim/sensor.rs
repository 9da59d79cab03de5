//! A simulated stereo camera: the pair's rows handed out one line at a time, top to bottom,
//! the way a sensor's line stream (DCMI / MIPI CSI line interrupt) reaches the band buffer.
//! A sensor cannot rewind, so every row is delivered once; the count says how many were.

use bino_core::pipeline::{RowSource, SlicePair};
use bino_core::Error;

/// Rows of a pair in memory, delivered once each, in order.
#[derive(Debug, Clone, Copy)]
pub struct SensorSource<'a> {
    pair: SlicePair<'a>,
    width: usize,
    height: usize,
    delivered: usize,
}

impl<'a> SensorSource<'a> {
    /// A `width x height` pair (gray, row-major); both views must hold exactly that many
    /// pixels.
    pub fn new(left: &'a [u8], right: &'a [u8], width: usize, height: usize) -> Result<Self, Error> {
        Ok(Self {
            pair: SlicePair::new(left, right, width, height)?,
            width,
            height,
            delivered: 0,
        })
    }

    /// Rows delivered so far (the next row's index).
    pub fn rows_delivered(&self) -> usize {
        self.delivered
    }

    /// Whether the whole frame has been delivered.
    pub fn frame_done(&self) -> bool {
        self.delivered == self.height
    }
}

impl RowSource for SensorSource<'_> {
    fn width(&self) -> usize {
        self.width
    }

    fn height(&self) -> usize {
        self.height
    }

    /// The next line of both views; past the last line, an error (the frame is over).
    fn next_row(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), Error> {
        self.pair.next_row(left, right)?;
        self.delivered += 1;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_row_is_delivered_once_in_order() {
        let (width, height) = (6, 5);
        // Row y of the left view is filled with y, of the right view with 100 + y.
        let left: Vec<u8> = (0..width * height).map(|i| (i / width) as u8).collect();
        let right: Vec<u8> = left.iter().map(|&y| 100 + y).collect();
        let mut sensor = SensorSource::new(&left, &right, width, height).unwrap();
        assert_eq!((sensor.width(), sensor.height()), (width, height));
        let (mut l, mut r) = (vec![0u8; width], vec![0u8; width]);
        for y in 0..height {
            assert_eq!(sensor.rows_delivered(), y);
            assert!(!sensor.frame_done());
            sensor.next_row(&mut l, &mut r).unwrap();
            assert_eq!(l, vec![y as u8; width], "left row {y}");
            assert_eq!(r, vec![100 + y as u8; width], "right row {y}");
        }
        assert!(sensor.frame_done());
        // The frame is over: no row 5, and the count stays.
        assert!(sensor.next_row(&mut l, &mut r).is_err());
        assert_eq!(sensor.rows_delivered(), height);
    }

    #[test]
    fn a_short_line_buffer_or_mismatched_views_are_errors() {
        let px = vec![0u8; 4 * 4];
        assert!(SensorSource::new(&px, &px[..12], 4, 4).is_err());
        assert!(SensorSource::new(&px, &px, 4, 5).is_err());
        let mut sensor = SensorSource::new(&px, &px, 4, 4).unwrap();
        let (mut l, mut r) = (vec![0u8; 3], vec![0u8; 4]);
        assert!(sensor.next_row(&mut l, &mut r).is_err());
        assert_eq!(sensor.rows_delivered(), 0, "a failed read delivers nothing");
    }
}
