//! The head's rows on their way out: forwarded to the sink, kept for the head's left-right
//! check, checked against the mirrored head's rows (export pathway) or against the right view
//! read from their own logits (native pathway, one pass), and fed to the refinement when it
//! reads a head readout.

use super::api::{HeadChecked, RefineInput, Sink, Stage};
use super::refine_stage::{RefineIo, RefineStage};
use super::sizing::check_rows_bytes;
#[cfg(doc)]
use super::sizing::HEAD_CHECK_ROWS;
use crate::arena::Carver;
use crate::lr::consistent_row;
use crate::model::head::{right_view_row, HeadRow, HeadSink, HeadStream, HeadWeights};
use crate::Error;

/// The refinement fed from inside a head stream's callback.
pub(super) struct Feed<'k, 'a, 'b> {
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
        match refine {
            Some((input, stage)) if *input == want => Some(Feed { stage, io, back }),
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
            check.keep_left(row.row, row.disparity_q8);
        }
        let (index, disparity) = (row.row, row.disparity_q8);
        self.sink.head(row);
        if let Some(feed) = self.refine.as_mut() {
            feed.push(index, disparity, None, self.sink);
        }
    }
}

/// The head's left-right check: the left rows kept for it, its mask row, what it kept.
pub(super) struct HeadCheck<'a> {
    pub(super) cols: usize,
    /// Rows of `left_rows`.
    pub(super) rows: usize,
    pub(super) lr_max_diff_q8: u16,
    /// `rows` rows of left disparities, row `r` in slot `r % rows` (export pathway,
    /// [`HEAD_CHECK_ROWS`]; one band: every row of it, so the mirrored head can run afterwards).
    pub(super) left_rows: &'a mut [u16],
    pub(super) mask: &'a mut [u8],
    pub(super) kept: usize,
}

impl<'a> HeadCheck<'a> {
    /// A check keeping `rows` rows of `cols` left disparities, cut from the front of `arena`
    /// ([`check_rows_bytes`]); returns it and the bytes it took.
    pub(super) fn carve(
        arena: &'a mut [u8],
        cols: usize,
        rows: usize,
        lr_max_diff_q8: u16,
    ) -> Result<(Self, usize), Error> {
        let mut carver = Carver::new(arena, check_rows_bytes(cols, rows))?;
        let check = HeadCheck {
            cols,
            rows,
            lr_max_diff_q8,
            left_rows: carver.u16s(cols.saturating_mul(rows))?,
            mask: carver.u8s(cols)?,
            kept: 0,
        };
        Ok((check, carver.used()))
    }

    fn slot(&mut self, row: usize) -> Option<&mut [u16]> {
        let at = (row % self.rows.max(1)) * self.cols;
        self.left_rows.get_mut(at..at + self.cols)
    }

    fn keep_left(&mut self, row: usize, disparity_q8: &[u16]) {
        if let Some(slot) = self.slot(row) {
            if slot.len() == disparity_q8.len() {
                slot.copy_from_slice(disparity_q8);
            }
        }
    }
}

/// Checks the mirrored head's rows against the left rows kept for them; feeds the refinement
/// the filled left row when it reads head+lr.
pub(super) struct CheckedRows<'k, 'a, 'b, K> {
    pub(super) sink: &'k mut K,
    pub(super) check: &'k mut HeadCheck<'a>,
    pub(super) refine: Option<Feed<'k, 'a, 'b>>,
}

impl<K: Sink> HeadSink for CheckedRows<'_, '_, '_, K> {
    fn row(&mut self, row: HeadRow<'_>) {
        let check = &mut *self.check;
        let tolerance = check.lr_max_diff_q8;
        let at = (row.row % check.rows.max(1)) * check.cols;
        let Some(left) = check.left_rows.get(at..at + check.cols) else {
            return;
        };
        // Equal lengths by construction (both streams are `cols` wide); a mismatch emits nothing.
        let Ok(kept) = consistent_row(left, row.disparity_q8, tolerance, check.mask) else {
            return;
        };
        check.kept += kept;
        self.sink.head_checked(&HeadChecked {
            row: row.row,
            right_q8: row.disparity_q8,
            consistent: check.mask,
        });
        if let Some(feed) = self.refine.as_mut() {
            feed.push(row.row, left, Some(check.mask), self.sink);
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

/// Forwards the native head's rows to the sink with their one-pass check, and feeds the
/// refinement the row (`head`) or the filled row (`head+lr`, `checked`) when it reads the head.
pub(super) struct OnePassRows<'k, 'a, 'b, 'w, K> {
    pub(super) sink: &'k mut K,
    pub(super) weights: &'k HeadWeights<'w>,
    pub(super) check: &'k mut OnePassCheck<'a>,
    pub(super) refine: Option<Feed<'k, 'a, 'b>>,
    /// Whether the refinement reads head+lr (the mask goes with each row) rather than head.
    pub(super) checked: bool,
}

impl<K: Sink> HeadSink for OnePassRows<'_, '_, '_, '_, K> {
    fn row(&mut self, row: HeadRow<'_>) {
        let checked = self.check.check(self.weights, &row);
        let (index, disparity) = (row.row, row.disparity_q8);
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
        if let Some(feed) = self.refine.as_mut() {
            match (self.checked, checked.is_ok()) {
                (false, _) => feed.push(index, disparity, None, self.sink),
                (true, true) => feed.push(index, disparity, Some(check.mask), self.sink),
                (true, false) => {}
            }
        }
    }
}

/// One step of a head stream: the next descriptor row, or (`None`) the end of the input.
pub(super) fn head_step(
    stream: &mut HeadStream<'_, '_>,
    input: Option<(&[i8], &[i8])>,
    rows: &mut impl HeadSink,
) -> Result<(), Error> {
    match input {
        Some((left, right)) => stream.push_row(left, right, rows),
        None => stream.finish(rows),
    }
}
