//! The census SGM ([`crate::census`]) as a stage of either pathway, for the fused readouts
//! ([`RefineInput::FusedCensusLr`](super::RefineInput::FusedCensusLr) on the native pathway,
//! [`RefineInput::FusedAllLr`](super::RefineInput::FusedAllLr) on the export one).
//!
//! Token row `t`'s census row is computed while the band holding it is in the buffer (native:
//! just before the head takes its pair token row; export: beside the row's matching): it reads
//! view rows `4t - 2 ..= 4t + 5`, which lie inside that band (the band plan keeps rows at least
//! [`CUT_MARGIN`] token rows from a cut; the image's own edges clamp). The SGM runs over the
//! token rows top to bottom, once each, as the host's whole-map readout does. The row waits in
//! a ring until the head's checked row `t` comes out (native: [`RING_ROWS`], [`HEAD_LAG`] rows
//! later; export: as many rows as the head's check keeps), and the two are fused by
//! [`fuse_row`] with the head's share [`census::FUSE_HEAD_WEIGHT`].

use super::layout::{sum, CUT_MARGIN, HEAD_LAG};
use super::refine_stage::BandView;
use crate::arena::{Carver, ALIGN_SLACK};
use crate::census::{self, CensusSgm, CENSUS_RADIUS, WINDOW_ROWS};
use crate::config::{CELL_W, PATCH_H};
use crate::lr::{fuse_row, CheckedRow};
use crate::Error;

/// Census rows the native pathway keeps for the head: the row being fused and the
/// [`HEAD_LAG`] computed after it.
pub(super) const RING_ROWS: usize = HEAD_LAG + 1;

// The census window reaches two view rows beyond a token row's; the band plan's margin keeps
// them inside the band that holds the row.
const _: () = assert!(PATCH_H * CUT_MARGIN >= CENSUS_RADIUS);

/// Arena bytes of the stage for views `width` px wide, a head of `candidates` and a ring of
/// `ring` rows: the census SGM's stream, the ring of rows and masks, and the fused row and its
/// mask.
pub(super) const fn bytes(width: usize, candidates: usize, ring: usize) -> usize {
    let cols = width / CELL_W;
    let n = census::disparities(candidates);
    sum(&[
        census::scratch_u32_len(width, n)
            .saturating_mul(4)
            .saturating_add(ALIGN_SLACK),
        census::scratch_u16_len(width, n)
            .saturating_mul(2)
            .saturating_add(ALIGN_SLACK),
        cols.saturating_mul(ring).saturating_mul(2).saturating_add(ALIGN_SLACK),
        cols.saturating_mul(ring),
        cols.saturating_mul(2).saturating_add(ALIGN_SLACK),
        cols,
    ])
}

/// The stage: the census SGM, its rows kept for the head, the fused row.
pub(super) struct CensusStage<'a> {
    sgm: CensusSgm<'a>,
    cols: usize,
    height: usize,
    /// Rows of the ring.
    ring: usize,
    rows: &'a mut [u16],
    masks: &'a mut [u8],
    /// The fused row and its mask (1 where the head or the census passes its check).
    pub(super) out: &'a mut [u16],
    pub(super) out_mask: &'a mut [u8],
    /// Next token row to compute.
    next: usize,
    /// Cells the fused rows kept.
    pub(super) kept: usize,
}

impl<'a> CensusStage<'a> {
    /// The stage for `height x width` views, a head of `candidates` and a ring of `ring` rows
    /// (at least one), cut from the front of `arena` ([`bytes`]); its check keeps cells within
    /// `lr_max_diff_q8`. Returns it and the bytes it took.
    pub(super) fn carve(
        arena: &'a mut [u8],
        width: usize,
        height: usize,
        candidates: usize,
        lr_max_diff_q8: u16,
        ring: usize,
    ) -> Result<(Self, usize), Error> {
        let cols = width / CELL_W;
        let n = census::disparities(candidates);
        let ring = ring.max(1);
        let mut carver = Carver::new(arena, bytes(width, candidates, ring))?;
        let s32 = carver.u32s(census::scratch_u32_len(width, n))?;
        let s16 = carver.u16s(census::scratch_u16_len(width, n))?;
        let rows = carver.u16s(cols.saturating_mul(ring))?;
        let masks = carver.u8s(cols.saturating_mul(ring))?;
        let out = carver.u16s(cols)?;
        let out_mask = carver.u8s(cols)?;
        let sgm = CensusSgm::new(width, n, census::DEFAULT_PENALTIES, lr_max_diff_q8, s32, s16)?;
        let stage = Self {
            sgm,
            cols,
            height,
            ring,
            rows,
            masks,
            out,
            out_mask,
            next: 0,
            kept: 0,
        };
        Ok((stage, carver.used()))
    }

    /// The ring slot of token row `row`.
    fn slot(&self, row: usize) -> core::ops::Range<usize> {
        let at = (row % self.ring) * self.cols;
        at..at + self.cols
    }

    /// Computes token row `row` (the next one) from the band buffer `view`.
    pub(super) fn compute(&mut self, row: usize, view: &BandView<'_>) -> Result<(), Error> {
        if row != self.next {
            return Err(Error::OutOfRange {
                what: "census token row",
                value: row,
                min: self.next,
                max: self.next,
            });
        }
        let mut left: [&[u8]; WINDOW_ROWS] = [&[]; WINDOW_ROWS];
        let mut right: [&[u8]; WINDOW_ROWS] = [&[]; WINDOW_ROWS];
        for (j, (l, r)) in left.iter_mut().zip(right.iter_mut()).enumerate() {
            let v = census::window_row(row, j, self.height);
            let Some(rows) = view.row(v) else {
                return Err(Error::OutOfRange {
                    what: "view row of the census SGM",
                    value: v,
                    min: view.first,
                    max: view.first + view.rows,
                });
            };
            (*l, *r) = rows;
        }
        let slot = self.slot(row);
        let ring_error = self.ring_error();
        let (Some(disparity), Some(kept)) = (self.rows.get_mut(slot.clone()), self.masks.get_mut(slot)) else {
            return Err(ring_error);
        };
        self.sgm.push_row(&left, &right, disparity, kept)?;
        self.next += 1;
        Ok(())
    }

    /// The ring slot of token row `row`, when it was computed and is still kept.
    fn kept_slot(&self, row: usize) -> Result<core::ops::Range<usize>, Error> {
        if row >= self.next || row + self.ring < self.next {
            return Err(Error::OutOfRange {
                what: "census row kept",
                value: row,
                min: self.next.saturating_sub(self.ring),
                max: self.next.saturating_sub(1),
            });
        }
        Ok(self.slot(row))
    }

    /// The error of a ring shorter than its rows (a carving bug; never from input).
    fn ring_error(&self) -> Error {
        Error::BufferSize {
            what: "census rows",
            expected: self.cols.saturating_mul(self.ring),
            found: self.rows.len(),
        }
    }

    /// Token row `row` of the census SGM (computed, still in the ring): its disparity (Q8 patch
    /// columns) and its check's mask (1 where the cell passes the left-right check and the
    /// uniqueness test).
    pub(super) fn row(&self, row: usize) -> Result<(&[u16], &[u8]), Error> {
        let slot = self.kept_slot(row)?;
        match (self.rows.get(slot.clone()), self.masks.get(slot)) {
            (Some(disparity), Some(kept)) => Ok((disparity, kept)),
            _ => Err(self.ring_error()),
        }
    }

    /// Fuses the head's checked row `row` (`head`, its mask and confidence) with the census
    /// row kept for it into [`CensusStage::out`] and [`CensusStage::out_mask`].
    pub(super) fn fuse(&mut self, row: usize, head: &[u16], head_mask: &[u8], confidence: &[u16]) -> Result<(), Error> {
        let slot = self.kept_slot(row)?;
        let (Some(disparity), Some(kept)) = (self.rows.get(slot.clone()), self.masks.get(slot)) else {
            return Err(self.ring_error());
        };
        let head = CheckedRow {
            disparity_q8: head,
            kept: head_mask,
        };
        let census = CheckedRow {
            disparity_q8: disparity,
            kept,
        };
        self.kept += fuse_row(
            head,
            confidence,
            census,
            census::FUSE_HEAD_WEIGHT,
            self.out,
            self.out_mask,
        )?;
        Ok(())
    }
}
