//! The head's rows on their way out: forwarded to the sink, kept for the head's left-right
//! check, checked against the mirrored head's rows (export pathway) or against the right view
//! read from their own logits (native pathway, one pass), fused with the SGM rows kept for them
//! (export pathway; for `fuse-all` with the census rows first) or with the census rows (native
//! pathway), and fed to the refinement when it reads a head or fused readout.

use super::api::{FusedRow, HeadChecked, RefineInput, Sink, Stage};
use super::census_stage::CensusStage;
use super::layout::sum;
use super::refine_stage::{RefineIo, RefineStage};
use crate::arena::Carver;
use crate::config::BAND_TOKEN_ROWS;
use crate::lr::{consistent_row, fuse_row, CheckedRow};
use crate::model::head::{right_view_row, HeadRow, HeadSink, HeadWeights};
use crate::Error;

/// Rows of left head disparities kept for the check (export pathway): the rows a band keeps,
/// at most a whole band. The mirrored head reruns the band after the left one, on the same
/// stream, so every kept row waits for it.
pub(super) const HEAD_CHECK_ROWS: usize = BAND_TOKEN_ROWS;

/// Arena bytes of the fused readout's state beside a [`HeadCheck`] of `rows` rows: as many rows
/// of the left head's confidence and of SGM disparities (u16, aligned each) and the SGM's masks,
/// and the fused row (u16, aligned) and its mask.
pub(super) const fn fusion_bytes(cols: usize, rows: usize) -> usize {
    let cells = cols.saturating_mul(rows);
    sum(&[
        cells.saturating_mul(2).saturating_add(1),
        cells.saturating_mul(2).saturating_add(1),
        cells,
        cols.saturating_mul(2).saturating_add(1),
        cols,
    ])
}

/// Arena bytes of a [`HeadCheck`] keeping `rows` rows of `cols` left disparities (u16,
/// aligned) and its mask row.
pub(super) const fn check_rows_bytes(cols: usize, rows: usize) -> usize {
    sum(&[cols.saturating_mul(rows).saturating_mul(2).saturating_add(1), cols])
}

/// The refinement fed from inside a head stream's callback.
pub(super) struct Feed<'k, 'a, 'b> {
    /// The readout the refinement reads.
    pub(super) input: RefineInput,
    pub(super) stage: &'k mut RefineStage<'a>,
    pub(super) io: &'k mut RefineIo<'b>,
    /// The head stage to return to.
    pub(super) back: Stage,
}

impl Feed<'_, '_, '_> {
    /// The refinement's input `want`, when it is the run's, fed from head stage `back`.
    pub(super) fn of<'k, 'a, 'b>(
        refine: &'k mut Option<(RefineInput, RefineStage<'a>)>,
        io: &'k mut RefineIo<'b>,
        want: RefineInput,
        back: Stage,
    ) -> Option<Feed<'k, 'a, 'b>> {
        Self::when(refine, io, back, |input| input == want)
    }

    /// The refinement, when it reads a readout of the head's check (head+lr or fuse+lr), fed
    /// from head stage `back`.
    pub(super) fn checked<'k, 'a, 'b>(
        refine: &'k mut Option<(RefineInput, RefineStage<'a>)>,
        io: &'k mut RefineIo<'b>,
        back: Stage,
    ) -> Option<Feed<'k, 'a, 'b>> {
        Self::when(refine, io, back, RefineInput::needs_head_check)
    }

    /// The refinement, when the readout it reads passes `reads`, fed from head stage `back`.
    fn when<'k, 'a, 'b>(
        refine: &'k mut Option<(RefineInput, RefineStage<'a>)>,
        io: &'k mut RefineIo<'b>,
        back: Stage,
        reads: impl Fn(RefineInput) -> bool,
    ) -> Option<Feed<'k, 'a, 'b>> {
        match refine {
            Some((input, stage)) if reads(*input) => Some(Feed {
                input: *input,
                stage,
                io,
                back,
            }),
            _ => None,
        }
    }

    /// Pushes a head row (errors kept for [`RefineStage::check`]), back in the head stage after.
    fn push(&mut self, row: usize, disparity_q8: &[u16], mask: Option<&[u8]>, sink: &mut impl Sink) {
        sink.stage(Stage::Refine);
        self.stage.push_or_keep(row, disparity_q8, mask, self.io, sink);
        sink.stage(self.back);
    }
}

/// Forwards the left head's rows to the pipeline's sink, keeping their disparities for the
/// check when there is one, and to the refinement when it reads the head unchecked.
pub(super) struct HeadRows<'k, 'a, 'b, K> {
    pub(super) sink: &'k mut K,
    pub(super) check: Option<&'k mut HeadCheck<'a>>,
    pub(super) refine: Option<Feed<'k, 'a, 'b>>,
}

impl<K: Sink> HeadSink for HeadRows<'_, '_, '_, K> {
    fn row(&mut self, row: HeadRow<'_>) {
        if let Some(check) = self.check.as_deref_mut() {
            check.keep_left(&row);
        }
        let (index, disparity) = (row.row, row.disparity_q8);
        self.sink.head(row);
        if let Some(feed) = self.refine.as_mut() {
            feed.push(index, disparity, None, self.sink);
        }
    }
}

/// The head's left-right check: the left rows kept for it, its mask row, what it kept, and the
/// fused readout made from it.
pub(super) struct HeadCheck<'a> {
    pub(super) cols: usize,
    /// Rows of `left_rows`.
    pub(super) rows: usize,
    pub(super) lr_max_diff_q8: u16,
    /// `rows` rows of left disparities, row `r` in slot `r % rows` (export pathway,
    /// [`HEAD_CHECK_ROWS`]: every row a band keeps, so the mirrored head can rerun the band
    /// afterwards).
    pub(super) left_rows: &'a mut [u16],
    pub(super) mask: &'a mut [u8],
    pub(super) kept: usize,
    pub(super) fusion: Fusion<'a>,
}

/// The fused readout ([`fuse_row`]): the left head's confidence rows and the SGM rows and masks
/// kept until the head's checked rows catch up with them (slot `r % rows`, as the left head
/// rows), and the fused row.
pub(super) struct Fusion<'a> {
    head_weight: u8,
    confidence_rows: &'a mut [u16],
    sgm_rows: &'a mut [u16],
    sgm_masks: &'a mut [u8],
    out: &'a mut [u16],
    out_mask: &'a mut [u8],
    pub(super) kept: usize,
}

impl<'a> HeadCheck<'a> {
    /// A check keeping `rows` rows of `cols` left disparities (and as many SGM rows for the
    /// fusion, the head's share `head_weight`), cut from the front of `arena`
    /// ([`check_rows_bytes`] + [`fusion_bytes`]); returns it and the bytes it took.
    pub(super) fn carve(
        arena: &'a mut [u8],
        cols: usize,
        rows: usize,
        lr_max_diff_q8: u16,
        head_weight: u8,
    ) -> Result<(Self, usize), Error> {
        let needed = check_rows_bytes(cols, rows).saturating_add(fusion_bytes(cols, rows));
        let mut carver = Carver::new(arena, needed)?;
        let cells = cols.saturating_mul(rows);
        let check = HeadCheck {
            cols,
            rows,
            lr_max_diff_q8,
            left_rows: carver.u16s(cells)?,
            mask: carver.u8s(cols)?,
            kept: 0,
            fusion: Fusion {
                head_weight,
                confidence_rows: carver.u16s(cells)?,
                sgm_rows: carver.u16s(cells)?,
                sgm_masks: carver.u8s(cells)?,
                out: carver.u16s(cols)?,
                out_mask: carver.u8s(cols)?,
                kept: 0,
            },
        };
        Ok((check, carver.used()))
    }

    /// The cells of the slot that keeps token row `row` (in every ring of rows).
    fn slot(&self, row: usize) -> core::ops::Range<usize> {
        let at = (row % self.rows.max(1)) * self.cols;
        at..at + self.cols
    }

    /// Keeps SGM row `row` and its left-right mask for the fusion of the head's row `row`.
    pub(super) fn keep_sgm(&mut self, row: usize, sgm_q8: &[u16], consistent: &[u8]) -> Result<(), Error> {
        let slot = self.slot(row);
        let fusion = &mut self.fusion;
        let (Some(rows), Some(masks)) = (
            fusion.sgm_rows.get_mut(slot.clone()),
            fusion.sgm_masks.get_mut(slot.clone()),
        ) else {
            return Err(Error::BufferSize {
                what: "fused readout: SGM rows",
                expected: slot.end,
                found: fusion.sgm_rows.len(),
            });
        };
        Error::check_len("fused readout: SGM row", rows.len(), sgm_q8.len())?;
        Error::check_len("fused readout: SGM mask row", masks.len(), consistent.len())?;
        rows.copy_from_slice(sgm_q8);
        masks.copy_from_slice(consistent);
        Ok(())
    }

    fn keep_left(&mut self, row: &HeadRow<'_>) {
        let range = self.slot(row.row);
        if let Some(slot) = self.left_rows.get_mut(range.clone()) {
            if slot.len() == row.disparity_q8.len() {
                slot.copy_from_slice(row.disparity_q8);
            }
        }
        if let Some(slot) = self.fusion.confidence_rows.get_mut(range) {
            if slot.len() == row.confidence_q8.len() {
                slot.copy_from_slice(row.confidence_q8);
            }
        }
    }
}

impl Fusion<'_> {
    /// `fuse-all`: the checked left head row `head` (row `row`, mask `head_mask`) fused with the
    /// census row kept for it, then that with the SGM row kept in slot `slot`.
    fn fuse_all(
        &mut self,
        slot: core::ops::Range<usize>,
        census: &mut CensusStage<'_>,
        row: usize,
        head: &[u16],
        head_mask: &[u8],
    ) -> Result<(), Error> {
        let confidence = self.confidence_rows.get(slot.clone()).ok_or(Error::BufferSize {
            what: "fused readout: confidence rows",
            expected: slot.end,
            found: self.confidence_rows.len(),
        })?;
        census.fuse(row, head, head_mask, confidence)?;
        self.fuse(slot, census.out, census.out_mask)
    }

    /// Fuses the checked left head row `head` (its mask `head_mask`) with the confidence and
    /// SGM rows kept in slot `slot` into [`Fusion::out`] and [`Fusion::out_mask`].
    fn fuse(&mut self, slot: core::ops::Range<usize>, head: &[u16], head_mask: &[u8]) -> Result<(), Error> {
        let (Some(confidence), Some(sgm), Some(sgm_mask)) = (
            self.confidence_rows.get(slot.clone()),
            self.sgm_rows.get(slot.clone()),
            self.sgm_masks.get(slot.clone()),
        ) else {
            return Err(Error::BufferSize {
                what: "fused readout: kept rows",
                expected: slot.end,
                found: self.sgm_rows.len(),
            });
        };
        let head = CheckedRow {
            disparity_q8: head,
            kept: head_mask,
        };
        let sgm = CheckedRow {
            disparity_q8: sgm,
            kept: sgm_mask,
        };
        self.kept += fuse_row(head, confidence, sgm, self.head_weight, self.out, self.out_mask)?;
        Ok(())
    }
}

/// Checks the mirrored head's rows against the left rows kept for them, fuses the checked rows
/// with the SGM's (with a census stage: with the census's first, `fuse-all`); feeds the
/// refinement the filled left row (head+lr) or fused row (fuse+lr, fuse-all+lr).
pub(super) struct CheckedRows<'k, 'a, 'b, K> {
    pub(super) sink: &'k mut K,
    pub(super) check: &'k mut HeadCheck<'a>,
    pub(super) census: Option<&'k mut CensusStage<'a>>,
    pub(super) refine: Option<Feed<'k, 'a, 'b>>,
}

impl<K: Sink> HeadSink for CheckedRows<'_, '_, '_, K> {
    fn row(&mut self, row: HeadRow<'_>) {
        let slot = self.check.slot(row.row);
        let HeadCheck {
            lr_max_diff_q8,
            left_rows,
            mask,
            kept,
            fusion,
            ..
        } = &mut *self.check;
        let Some(left) = left_rows.get(slot.clone()) else {
            return;
        };
        // Equal lengths by construction (both streams are `cols` wide); a mismatch emits nothing.
        let Ok(row_kept) = consistent_row(left, row.disparity_q8, *lr_max_diff_q8, mask) else {
            return;
        };
        *kept += row_kept;
        self.sink.head_checked(&HeadChecked {
            row: row.row,
            right_q8: row.disparity_q8,
            consistent: mask,
        });
        // Sizes are equal by construction; a failure emits no fused row, and a fuse+lr
        // refinement misses the row, which it reports.
        let fused = match self.census.as_deref_mut() {
            Some(census) => fusion.fuse_all(slot, census, row.row, left, mask),
            None => fusion.fuse(slot, left, mask),
        }
        .is_ok();
        if fused {
            self.sink.fused(&FusedRow {
                row: row.row,
                disparity_q8: fusion.out,
                consistent: fusion.out_mask,
            });
        }
        if let Some(feed) = self.refine.as_mut() {
            match feed.input {
                RefineInput::FusedLr | RefineInput::FusedAllLr if fused => {
                    feed.push(row.row, fusion.out, Some(fusion.out_mask), self.sink)
                }
                RefineInput::FusedLr | RefineInput::FusedAllLr => {}
                _ => feed.push(row.row, left, Some(mask), self.sink),
            }
        }
    }
}

/// The one-pass left-right check (native pathway): the right view's row read from the left
/// head's logits, and the mask row of what it kept.
pub(super) struct OnePassCheck<'a> {
    pub(super) lr_max_diff_q8: u16,
    pub(super) right: &'a mut [u16],
    pub(super) mask: &'a mut [u8],
    pub(super) kept: usize,
}

impl<'a> OnePassCheck<'a> {
    /// A check over rows of `cols` cells, cut from the front of `arena` ([`check_rows_bytes`]
    /// of one row); returns it and the bytes it took.
    pub(super) fn carve(arena: &'a mut [u8], cols: usize, lr_max_diff_q8: u16) -> Result<(Self, usize), Error> {
        let mut carver = Carver::new(arena, check_rows_bytes(cols, 1))?;
        let check = OnePassCheck {
            lr_max_diff_q8,
            right: carver.u16s(cols)?,
            mask: carver.u8s(cols)?,
            kept: 0,
        };
        Ok((check, carver.used()))
    }

    /// Checks the left head's `row` against the right view read from its logits: the mask
    /// row, and the number of cells kept.
    fn check(&mut self, weights: &HeadWeights<'_>, row: &HeadRow<'_>) -> Result<usize, Error> {
        right_view_row(weights, row, self.right)?;
        consistent_row(row.disparity_q8, self.right, self.lr_max_diff_q8, self.mask)
    }
}

/// Forwards the native head's rows to the sink with their one-pass check, fuses each checked
/// row with the census row kept for it (with a census stage), and feeds the refinement the row
/// (`head`), the filled row (`head+lr`, `checked`) or the fused row (`fuse-census+lr`).
pub(super) struct OnePassRows<'k, 'a, 'b, 'w, K> {
    pub(super) sink: &'k mut K,
    pub(super) weights: &'k HeadWeights<'w>,
    pub(super) check: &'k mut OnePassCheck<'a>,
    pub(super) census: Option<&'k mut CensusStage<'a>>,
    pub(super) refine: Option<Feed<'k, 'a, 'b>>,
    /// Whether the refinement reads a checked readout (the mask goes with each row) rather
    /// than head.
    pub(super) checked: bool,
}

impl<K: Sink> HeadSink for OnePassRows<'_, '_, '_, '_, K> {
    fn row(&mut self, row: HeadRow<'_>) {
        let checked = self.check.check(self.weights, &row);
        let (index, disparity, confidence) = (row.row, row.disparity_q8, row.confidence_q8);
        self.sink.head(row);
        let check = &mut *self.check;
        // Equal lengths by construction (the row and the check are `cols` wide); a mismatch
        // emits no check, and a head+lr refinement misses the row, which it reports.
        if let Ok(kept) = checked {
            check.kept += kept;
            self.sink.head_checked(&HeadChecked {
                row: index,
                right_q8: check.right,
                consistent: check.mask,
            });
        }
        // The fused row; a failure (a census row not kept) emits none, and a fuse-census+lr
        // refinement misses the row, which it reports.
        let fused = match (self.census.as_deref_mut(), checked.is_ok()) {
            (Some(census), true) => census.fuse(index, disparity, check.mask, confidence).is_ok().then(|| {
                self.sink.fused(&FusedRow {
                    row: index,
                    disparity_q8: census.out,
                    consistent: census.out_mask,
                });
                (&*census.out, &*census.out_mask)
            }),
            _ => None,
        };
        if let Some(feed) = self.refine.as_mut() {
            match (feed.input, self.checked, checked.is_ok()) {
                (RefineInput::FusedCensusLr, _, _) => {
                    if let Some((out, mask)) = fused {
                        feed.push(index, out, Some(mask), self.sink);
                    }
                }
                (_, false, _) => feed.push(index, disparity, None, self.sink),
                (_, true, true) => feed.push(index, disparity, Some(check.mask), self.sink),
                (_, true, false) => {}
            }
        }
    }
}
