//! A side-by-side stereo frame as the pipeline's row source: each captured line holds the left
//! view's row, then the right view's (`2 x width` bytes of 8-bit gray), which is how one camera
//! interface (the H7's DCMI) carries a rectified pair from a stereo module.

use bino_core::pipeline::RowSource;
use bino_core::Error;

/// Rows of a side-by-side frame in memory, top to bottom.
#[derive(Debug, Clone, Copy)]
pub struct SideBySide<'a> {
    frame: &'a [u8],
    width: usize,
    height: usize,
    next: usize,
}

impl<'a> SideBySide<'a> {
    /// A frame of `height` lines of `2 * width` bytes; `frame` must hold exactly that many.
    pub fn new(frame: &'a [u8], width: usize, height: usize) -> Result<Self, Error> {
        let expected = width.saturating_mul(2).saturating_mul(height);
        if frame.len() != expected {
            return Err(Error::BufferSize {
                what: "side-by-side frame",
                expected,
                found: frame.len(),
            });
        }
        Ok(Self {
            frame,
            width,
            height,
            next: 0,
        })
    }
}

/// Writes the views `left` and `right` (`width` pixels a row, the same size) side by side into
/// `frame`, line by line, as a camera interface lays out a stereo module's frame: what
/// [`SideBySide`] reads. [`Error::BufferSize`] when the views differ in size, are not whole rows
/// or `frame` does not hold both exactly.
pub fn interleave(left: &[u8], right: &[u8], width: usize, frame: &mut [u8]) -> Result<(), Error> {
    let sizes_agree = width > 0 && left.len() == right.len() && left.len().is_multiple_of(width);
    if !sizes_agree || frame.len() != 2 * left.len() {
        return Err(Error::BufferSize {
            what: "side-by-side frame",
            expected: left.len().saturating_mul(2),
            found: frame.len(),
        });
    }
    let lines = frame.chunks_exact_mut(2 * width);
    for ((line, l), r) in lines.zip(left.chunks_exact(width)).zip(right.chunks_exact(width)) {
        let (out_l, out_r) = line.split_at_mut(width);
        out_l.copy_from_slice(l);
        out_r.copy_from_slice(r);
    }
    Ok(())
}

impl RowSource for SideBySide<'_> {
    fn width(&self) -> usize {
        self.width
    }

    fn height(&self) -> usize {
        self.height
    }

    fn next_row(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), Error> {
        let line = 2 * self.width;
        let Some(row) = self.frame.get(self.next * line..(self.next + 1) * line) else {
            return Err(Error::EndOfRows {
                row: self.next,
                height: self.height,
            });
        };
        let (l, r) = row.split_at(self.width);
        for (out, src) in [(left, l), (right, r)] {
            if out.len() != src.len() {
                return Err(Error::BufferSize {
                    what: "row buffer",
                    expected: src.len(),
                    found: out.len(),
                });
            }
            out.copy_from_slice(src);
        }
        self.next += 1;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn splits_each_line_into_left_then_right() {
        // 2 lines of 2 x 3 pixels: left row, then right row.
        let frame = [1, 2, 3, 11, 12, 13, 4, 5, 6, 14, 15, 16];
        let mut src = SideBySide::new(&frame, 3, 2).unwrap();
        let (mut l, mut r) = ([0u8; 3], [0u8; 3]);
        src.next_row(&mut l, &mut r).unwrap();
        assert_eq!((l, r), ([1, 2, 3], [11, 12, 13]));
        src.next_row(&mut l, &mut r).unwrap();
        assert_eq!((l, r), ([4, 5, 6], [14, 15, 16]));
        assert!(matches!(
            src.next_row(&mut l, &mut r),
            Err(Error::EndOfRows { row: 2, height: 2 })
        ));
    }

    #[test]
    fn interleaves_views_into_the_lines_it_splits() {
        let (left, right) = ([1, 2, 3, 4, 5, 6], [11, 12, 13, 14, 15, 16]);
        let mut frame = [0u8; 12];
        interleave(&left, &right, 3, &mut frame).unwrap();
        assert_eq!(frame, [1, 2, 3, 11, 12, 13, 4, 5, 6, 14, 15, 16]);
        // Views of different sizes, rows cut short, or a frame of another size: refused.
        for (l, r, width, len) in [
            (&left[..], &right[..3], 3, 12),
            (&left[..], &right[..], 4, 12),
            (&left[..], &right[..], 3, 10),
        ] {
            let mut frame = [0u8; 12];
            assert!(matches!(
                interleave(l, r, width, &mut frame[..len]),
                Err(Error::BufferSize { .. })
            ));
        }
    }

    #[test]
    fn rejects_a_frame_of_the_wrong_size_and_short_row_buffers() {
        assert!(matches!(
            SideBySide::new(&[0; 11], 3, 2),
            Err(Error::BufferSize {
                expected: 12,
                found: 11,
                ..
            })
        ));
        let frame = [0u8; 12];
        let mut src = SideBySide::new(&frame, 3, 2).unwrap();
        let (mut l, mut r) = ([0u8; 2], [0u8; 3]);
        assert!(matches!(
            src.next_row(&mut l, &mut r),
            Err(Error::BufferSize {
                expected: 3,
                found: 2,
                ..
            })
        ));
    }
}
