//! Band feeding: the band buffer filled from a [`RowSource`] as bands advance (the one step
//! every band loop starts with, [`BandRows::advance`]), the token rows a band keeps cut from
//! its descriptor maps, and the rows a band takes from the band before ([`Fresh`]).

use super::api::{RowSource, Sink, Stage};
use super::refine_stage::{BandView, Refinement};
use crate::band::{Band, BandPlan};
use crate::config::{DIM, PATCH_H};
use crate::Error;

/// The band buffer, filled from a [`RowSource`] as bands advance.
pub(super) struct BandRows<'s, S> {
    pub(super) source: &'s mut S,
    pub(super) width: usize,
    /// Image row held in buffer row 0.
    pub(super) first: usize,
    /// Image rows read so far.
    pub(super) loaded: usize,
}

impl<'s, S: RowSource> BandRows<'s, S> {
    /// An empty buffer of rows `width` pixels wide, filled from `source`.
    pub(super) fn new(source: &'s mut S, width: usize) -> Self {
        Self {
            source,
            width,
            first: 0,
            loaded: 0,
        }
    }

    /// The rows the buffers `left` and `right` hold now.
    pub(super) fn view<'b>(&self, left: &'b [u8], right: &'b [u8]) -> BandView<'b> {
        BandView {
            first: self.first,
            rows: self.loaded - self.first,
            width: self.width,
            left,
            right,
        }
    }

    /// The next band of a run into the buffers: after the first band, the refinement first keeps
    /// the rows it still needs that the load drops ([`Refinement::keep_before`]).
    pub(super) fn advance(
        &mut self,
        band: Band,
        left: &mut [u8],
        right: &mut [u8],
        refinement: Option<&mut Refinement<'_>>,
        sink: &mut impl Sink,
    ) -> Result<(), Error> {
        self.keep_for(band, left, right, refinement, sink)?;
        self.load(band, left, right, sink)
    }

    /// The first half of [`BandRows::advance`], for a caller that then reads `band`'s rows a
    /// few at a time ([`BandRows::load_until`]): rows the refinement still needs that `band`'s
    /// rows will replace go to its ring (none before the first band).
    pub(super) fn keep_for(
        &mut self,
        band: Band,
        left: &mut [u8],
        right: &mut [u8],
        refinement: Option<&mut Refinement<'_>>,
        sink: &mut impl Sink,
    ) -> Result<(), Error> {
        if let (true, Some(refinement)) = (self.loaded > 0, refinement) {
            refinement.keep_before(&self.view(left, right), band.start * PATCH_H, sink)?;
        }
        Ok(())
    }

    /// Makes the buffers hold `band`'s pixel rows: keeps the overlap with the previous band,
    /// reads the rest.
    fn load(&mut self, band: Band, left: &mut [u8], right: &mut [u8], sink: &mut impl Sink) -> Result<(), Error> {
        sink.stage(Stage::Rows);
        self.fill(band, (band.start + band.rows) * PATCH_H, left, right)
    }

    /// [`BandRows::load`] up to image row `until` (exclusive; at most the band's last row): a
    /// caller that needs a band's rows a few at a time reads each when it needs it, so a camera
    /// with a few line buffers keeps up. Enters [`Stage::Rows`] only when it reads or drops rows.
    pub(super) fn load_until(
        &mut self,
        band: Band,
        until: usize,
        left: &mut [u8],
        right: &mut [u8],
        sink: &mut impl Sink,
    ) -> Result<(), Error> {
        let end = until.min((band.start + band.rows) * PATCH_H);
        if band.start * PATCH_H > self.first || self.loaded < end {
            sink.stage(Stage::Rows);
            self.fill(band, end, left, right)?;
        }
        Ok(())
    }

    /// Drops the rows above `band`, then reads rows until image row `end` (exclusive).
    fn fill(&mut self, band: Band, end: usize, left: &mut [u8], right: &mut [u8]) -> Result<(), Error> {
        let start = band.start * PATCH_H;
        let w = self.width;
        if start > self.first {
            let drop = (start - self.first).min(self.loaded - self.first);
            let keep = self.loaded - self.first - drop;
            for view in [&mut *left, &mut *right] {
                view.copy_within(drop * w..(drop + keep) * w, 0);
            }
            // Rows above the band that were never read (a caller that stopped short of the
            // last band's end) are read into the first buffer row and dropped.
            while self.loaded < start {
                let found = left.len().min(right.len());
                let (Some(l), Some(r)) = (left.get_mut(..w), right.get_mut(..w)) else {
                    return Err(Error::BufferSize {
                        what: "band buffer",
                        expected: w,
                        found,
                    });
                };
                self.source.next_row(l, r)?;
                self.loaded += 1;
            }
            self.first = start;
        }
        while self.loaded < end {
            let at = (self.loaded - self.first) * w;
            let (Some(l), Some(r)) = (left.get_mut(at..at + w), right.get_mut(at..at + w)) else {
                return Err(Error::BufferSize {
                    what: "band buffer",
                    expected: end - self.first,
                    found: left.len() / w.max(1),
                });
            };
            self.source.next_row(l, r)?;
            self.loaded += 1;
        }
        Ok(())
    }
}

/// Token row `row` of both descriptor maps of `band` (`cols x DIM` codes each).
pub(super) fn kept_row<'d>(
    band: Band,
    row: usize,
    cols: usize,
    left: &'d [i8],
    right: &'d [i8],
) -> Result<(&'d [i8], &'d [i8]), Error> {
    let row_len = cols * DIM;
    let at = (row - band.start) * row_len;
    match (left.get(at..at + row_len), right.get(at..at + row_len)) {
        (Some(l), Some(r)) => Ok((l, r)),
        _ => Err(Error::BufferSize {
            what: "descriptor band",
            expected: (band.keep_to - band.start) * row_len,
            found: left.len().min(right.len()),
        }),
    }
}

/// Which token rows a band's encoder pass computes. With weights whose token rows do not depend
/// on their place in the band ([`Encoder::rows_independent`]) a band keeps the rows it shares
/// with the band before, already encoded, and encodes the rest: a frame's encoder work is then
/// one pass per token row, overlaps paid once.
///
/// [`Encoder::rows_independent`]: crate::model::encoder::Encoder::rows_independent
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Fresh {
    /// The band's first token rows, taken from the band before.
    pub(super) kept: usize,
    /// Token rows from the start of the band before to this band's start.
    pub(super) shift: usize,
}

impl Fresh {
    /// Band `index` of `plan`; `shared`: whether bands share rows (else nothing is kept).
    pub(super) fn of(plan: &BandPlan, index: usize, shared: bool) -> Self {
        let (Some(band), Some(before), Some(encoded)) = (
            plan.get(index),
            index.checked_sub(1).and_then(|i| plan.get(i)),
            plan.encoded(index, shared),
        ) else {
            return Self { kept: 0, shift: 0 };
        };
        match encoded.start - band.start {
            0 => Self { kept: 0, shift: 0 },
            kept => Self {
                kept,
                shift: band.start - before.start,
            },
        }
    }

    /// Moves the kept rows of the band before's map (rows of `row_len` values from the front of
    /// `map`) to the front, where this band's map starts.
    pub(super) fn keep<T: Copy>(&self, map: &mut [T], row_len: usize, what: &'static str) -> Result<(), Error> {
        if self.kept == 0 {
            return Ok(());
        }
        let from = self.shift * row_len;
        let len = self.kept * row_len;
        if from + len > map.len() {
            return Err(Error::BufferSize {
                what,
                expected: from + len,
                found: map.len(),
            });
        }
        map.copy_within(from..from + len, 0);
        Ok(())
    }

    /// The band's pixel rows from its first fresh token row on.
    pub(super) fn pixels<'p>(&self, band: &'p [u8], width: usize) -> &'p [u8] {
        band.get(self.kept * PATCH_H * width..).unwrap_or_default()
    }
}
