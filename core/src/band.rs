//! Overlapping bands: how a fixed 48-row encoder covers an image of any height.
//!
//! The encoder's row embedding has [`BAND_TOKEN_ROWS`] entries, so it always sees at most
//! that many token rows. A taller image is cut into bands whose starts are spread evenly,
//! at most [`BAND_STRIDE_TOKEN_ROWS`] apart; each output token row is taken from the band
//! in which it sits furthest from a cut edge (the cut between two bands lies in the middle
//! of their overlap). Memory therefore depends on the band and the width, never on the height.
//!
//! ```
//! use bino_core::band::BandPlan;
//! let plan = BandPlan::new(24)?; // a 96-row image
//! let bands: Vec<_> = plan.iter().map(|b| (b.start, b.keep_from, b.keep_to)).collect();
//! assert_eq!(bands, [(0, 0, 9), (6, 9, 15), (12, 15, 24)]);
//! # Ok::<(), bino_core::Error>(())
//! ```

use crate::config::{BAND_STRIDE_TOKEN_ROWS, BAND_TOKEN_ROWS, MAX_HEIGHT, MAX_TOKEN_ROWS, PATCH_H};
use crate::Error;

/// One band, in token rows of the whole image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Band {
    /// First token row the encoder sees.
    pub start: usize,
    /// Token rows the encoder sees (at most [`BAND_TOKEN_ROWS`]).
    pub rows: usize,
    /// First token row whose output this band provides.
    pub keep_from: usize,
    /// One past the last token row whose output this band provides.
    pub keep_to: usize,
}

impl Band {
    /// The band's token rows within `reach` rows of those it keeps (clipped to the band): what
    /// a readout that reads `reach` rows above and below each of its rows takes from this band
    /// alone, as the native pathway's head does (`model::head::ROW_REACH`).
    pub fn around_kept(&self, reach: usize) -> core::ops::Range<usize> {
        let first = self.keep_from.saturating_sub(reach).max(self.start);
        let end = self
            .keep_to
            .saturating_add(reach)
            .min(self.start.saturating_add(self.rows));
        first..end.max(first)
    }
}

/// The bands covering an image of `token_rows` token rows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BandPlan {
    token_rows: usize,
    count: usize,
}

impl BandPlan {
    /// Plans the bands of an image with `token_rows` token rows (image rows / 4), at most
    /// [`MAX_TOKEN_ROWS`]: beyond it the plan is [`Error::TooTall`], so band starts never wrap.
    pub fn new(token_rows: usize) -> Result<Self, Error> {
        if token_rows == 0 {
            return Err(Error::EmptyImage);
        }
        if token_rows > MAX_TOKEN_ROWS {
            return Err(Error::TooTall {
                height: token_rows.saturating_mul(PATCH_H),
                max: MAX_HEIGHT,
            });
        }
        let count = if token_rows <= BAND_TOKEN_ROWS {
            1
        } else {
            (token_rows - BAND_TOKEN_ROWS).div_ceil(BAND_STRIDE_TOKEN_ROWS) + 1
        };
        Ok(Self { token_rows, count })
    }

    /// Number of bands.
    pub fn len(&self) -> usize {
        self.count
    }

    /// Always false: a plan has at least one band.
    pub fn is_empty(&self) -> bool {
        false
    }

    fn start(&self, index: usize) -> usize {
        // index < count <= MAX_TOKEN_ROWS and the span is below MAX_TOKEN_ROWS, so the product
        // stays below 2^28; checked all the same, a wrap would end the plan (`get` gives None).
        let span = self.token_rows.saturating_sub(BAND_TOKEN_ROWS);
        index
            .checked_mul(span)
            .and_then(|x| x.checked_div(self.count - 1))
            .unwrap_or(0)
    }

    fn cut(&self, index: usize) -> usize {
        // Between band `index` and `index + 1`: the middle of their overlap.
        (self.start(index + 1) + self.start(index) + BAND_TOKEN_ROWS) / 2
    }

    /// Band `index`, or `None` past the end.
    pub fn get(&self, index: usize) -> Option<Band> {
        if index >= self.count {
            return None;
        }
        let start = self.start(index);
        let keep_from = if index == 0 { 0 } else { self.cut(index - 1) };
        let keep_to = if index + 1 == self.count {
            self.token_rows
        } else {
            self.cut(index)
        };
        let rows = BAND_TOKEN_ROWS.min(self.token_rows);
        Some(Band {
            start,
            rows,
            keep_from,
            keep_to,
        })
    }

    /// The first token row band `index` must encode when each band keeps the token rows it
    /// shares with the band before ([`Encoder::rows_independent`] weights): the end of the
    /// previous band, or the band's start for the first band (and past the end, `None`).
    ///
    /// [`Encoder::rows_independent`]: crate::model::encoder::Encoder::rows_independent
    pub fn fresh_from(&self, index: usize) -> Option<usize> {
        let band = self.get(index)?;
        let fresh = match index.checked_sub(1).and_then(|i| self.get(i)) {
            Some(before) => (before.start + before.rows).clamp(band.start, band.start + band.rows),
            None => band.start,
        };
        Some(fresh)
    }

    /// The token rows band `index`'s encoder passes compute: with `shared` rows (weights whose
    /// token rows are independent) those from [`BandPlan::fresh_from`] to the band's end, else the
    /// whole band; `None` past the end.
    pub fn encoded(&self, index: usize, shared: bool) -> Option<core::ops::Range<usize>> {
        let band = self.get(index)?;
        let first = match shared {
            true => self.fresh_from(index)?,
            false => band.start,
        };
        Some(first..band.start + band.rows)
    }

    /// The bands, top to bottom.
    pub fn iter(&self) -> impl Iterator<Item = Band> + '_ {
        (0..self.count).filter_map(move |i| self.get(i))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_row_is_kept_exactly_once_and_inside_its_band() -> Result<(), Error> {
        for rows in 1..200 {
            let plan = BandPlan::new(rows)?;
            let mut next = 0;
            for band in plan.iter() {
                assert_eq!(band.keep_from, next, "rows {rows}: gap or overlap");
                assert!(band.keep_to > band.keep_from, "rows {rows}: empty band {band:?}");
                assert!(band.start <= band.keep_from && band.keep_to <= band.start + band.rows);
                assert!(band.start + band.rows <= rows);
                next = band.keep_to;
            }
            assert_eq!(next, rows);
        }
        Ok(())
    }

    #[test]
    fn the_rows_around_the_kept_ones_stay_inside_the_band() -> Result<(), Error> {
        for rows in 1..80 {
            for band in BandPlan::new(rows)?.iter() {
                for reach in [0, 1, 6, 100] {
                    let around = band.around_kept(reach);
                    assert!(band.start <= around.start && around.end <= band.start + band.rows);
                    assert!(around.start <= band.keep_from && band.keep_to <= around.end);
                    assert_eq!(around.start, band.keep_from.saturating_sub(reach).max(band.start));
                }
                assert_eq!(band.around_kept(0), band.keep_from..band.keep_to);
            }
        }
        // The second band of a 96-row image (token rows 6..18, keeping 9..15) reads 6..18.
        let band = BandPlan::new(24)?.get(1).ok_or(Error::EmptyImage)?;
        assert_eq!(band.around_kept(6), 6..18);
        assert_eq!(band.around_kept(2), 7..17);
        Ok(())
    }

    #[test]
    fn shared_rows_leave_every_token_row_encoded_exactly_once() -> Result<(), Error> {
        for rows in 1..200 {
            let plan = BandPlan::new(rows)?;
            let mut next = 0;
            for (i, band) in plan.iter().enumerate() {
                let fresh = plan.fresh_from(i).ok_or(Error::EmptyImage)?;
                assert_eq!(fresh, next, "rows {rows}: band {i} starts its pass at {fresh}");
                assert!(band.start <= fresh && fresh < band.start + band.rows);
                next = band.start + band.rows;
                assert_eq!(plan.encoded(i, true), Some(fresh..next));
                assert_eq!(plan.encoded(i, false), Some(band.start..next));
            }
            assert_eq!(plan.encoded(plan.len(), true), None);
            assert_eq!(next, rows);
            assert_eq!(plan.fresh_from(plan.len()), None);
        }
        // A 120-row frame: four bands of 12 token rows, 30 encoded instead of 48.
        let plan = BandPlan::new(30)?;
        let fresh: heapless_free::Starts = (0..plan.len()).filter_map(|i| plan.fresh_from(i)).collect();
        assert_eq!(fresh.0[..fresh.1], [0, 12, 18, 24]);
        Ok(())
    }

    #[test]
    fn bands_are_no_further_apart_than_the_stride() -> Result<(), Error> {
        let plan = BandPlan::new(93)?;
        let starts: heapless_free::Starts = plan.iter().map(|b| b.start).collect();
        for pair in starts.0[..starts.1].windows(2) {
            assert!(pair[1] - pair[0] <= BAND_STRIDE_TOKEN_ROWS);
        }
        Ok(())
    }

    #[test]
    fn short_image_is_one_band() {
        let band = BandPlan::new(7).ok().and_then(|plan| plan.get(0));
        assert_eq!(
            band,
            Some(Band {
                start: 0,
                rows: 7,
                keep_from: 0,
                keep_to: 7
            })
        );
        assert_eq!(BandPlan::new(0), Err(Error::EmptyImage));
    }

    /// Regression (fuzzing, issue 12): `index * (token_rows - 12)` overflowed for
    /// token_rows near 2^34, and in release builds the band loop ran for ~2^59 bands.
    #[test]
    fn absurd_heights_are_errors_not_endless_plans() -> Result<(), Error> {
        for rows in [MAX_TOKEN_ROWS + 1, 1 << 34, usize::MAX] {
            assert!(matches!(
                BandPlan::new(rows),
                Err(Error::TooTall { max: MAX_HEIGHT, .. })
            ));
        }
        let plan = BandPlan::new(MAX_TOKEN_ROWS)?;
        let last = plan.get(plan.len() - 1).ok_or(Error::EmptyImage)?;
        assert_eq!(last.keep_to, MAX_TOKEN_ROWS);
        assert_eq!(last.start + last.rows, MAX_TOKEN_ROWS);
        assert_eq!(plan.iter().count(), plan.len());
        Ok(())
    }

    mod heapless_free {
        /// A fixed-capacity collector, since core tests run without `alloc`.
        pub struct Starts(pub [usize; 32], pub usize);
        impl FromIterator<usize> for Starts {
            fn from_iter<I: IntoIterator<Item = usize>>(iter: I) -> Self {
                let mut s = Starts([0; 32], 0);
                for v in iter {
                    s.0[s.1] = v;
                    s.1 += 1;
                }
                s
            }
        }
    }
}
