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
/// `ring` rows, with its own row scratch: [`resident_bytes`] and [`row_bytes`].
pub(super) const fn bytes(width: usize, candidates: usize, ring: usize) -> usize {
    resident_bytes(width, candidates, ring).saturating_add(row_bytes(width, candidates))
}

/// Arena bytes of what the stage carries from row to row: the census SGM's state, the ring of
/// rows and masks, and the fused row and its mask.
pub(super) const fn resident_bytes(width: usize, candidates: usize, ring: usize) -> usize {
    let cols = width / CELL_W;
    let n = census::disparities(candidates);
    sum(&[
        census::state_u16_len(width, n)
            .saturating_mul(2)
            .saturating_add(ALIGN_SLACK),
        cols.saturating_mul(ring).saturating_mul(2).saturating_add(ALIGN_SLACK),
        cols.saturating_mul(ring),
        cols.saturating_mul(2).saturating_add(ALIGN_SLACK),
        cols,
    ])
}

/// Arena bytes of one row's scratch of the census SGM ([`census::scratch_u32_len`],
/// [`census::row_u16_len`]): what a stage without its own scratch is brought each row
/// ([`CensusStage::compute_in`]).
pub(super) const fn row_bytes(width: usize, candidates: usize) -> usize {
    let n = census::disparities(candidates);
    sum(&[
        census::scratch_u32_len(width, n)
            .saturating_mul(4)
            .saturating_add(ALIGN_SLACK),
        census::row_u16_len(width, n).saturating_mul(2),
    ])
}

/// One row's scratch of the census SGM, cut from an arena of [`row_bytes`].
pub(super) struct RowScratch<'s> {
    u32s: &'s mut [u32],
    u16s: &'s mut [u16],
}

impl<'s> RowScratch<'s> {
    /// The scratch for views `width` px wide and a head of `candidates`, cut by `carver`.
    pub(super) fn carve(carver: &mut Carver<'s>, width: usize, candidates: usize) -> Result<Self, Error> {
        let n = census::disparities(candidates);
        Ok(Self {
            u32s: carver.u32s(census::scratch_u32_len(width, n))?,
            u16s: carver.u16s(census::row_u16_len(width, n))?,
        })
    }
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
    /// (at least one), cut from the front of `arena` ([`bytes`]), its own row scratch
    /// included (with `own_scratch`; without, [`resident_bytes`] and each row brings its
    /// scratch, [`CensusStage::compute_in`]); its check keeps cells within `lr_max_diff_q8`.
    /// Returns it and the bytes it took.
    pub(super) fn carve(
        arena: &'a mut [u8],
        width: usize,
        height: usize,
        (candidates, lr_max_diff_q8): (usize, u16),
        ring: usize,
        own_scratch: bool,
    ) -> Result<(Self, usize), Error> {
        let cols = width / CELL_W;
        let n = census::disparities(candidates);
        let ring = ring.max(1);
        let needed = match own_scratch {
            true => bytes(width, candidates, ring),
            false => resident_bytes(width, candidates, ring),
        };
        let mut carver = Carver::new(arena, needed)?;
        let state = carver.u16s(census::state_u16_len(width, n))?;
        let rows = carver.u16s(cols.saturating_mul(ring))?;
        let out = carver.u16s(cols)?;
        let masks = carver.u8s(cols.saturating_mul(ring))?;
        let out_mask = carver.u8s(cols)?;
        let penalties = census::DEFAULT_PENALTIES;
        let sgm = match own_scratch {
            true => {
                let RowScratch { u32s, u16s } = RowScratch::carve(&mut carver, width, candidates)?;
                CensusSgm::state_only(width, n, penalties, lr_max_diff_q8, state)?.with_scratch(u32s, u16s)?
            }
            false => CensusSgm::state_only(width, n, penalties, lr_max_diff_q8, state)?,
        };
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

    /// Computes token row `row` (the next one) from the band buffer `view`, in the stage's own
    /// row scratch.
    pub(super) fn compute(&mut self, row: usize, view: &BandView<'_>) -> Result<(), Error> {
        self.compute_with(row, view, None)
    }

    /// [`CensusStage::compute`] in the row scratch `scratch` (a stage carved without its own).
    pub(super) fn compute_in(
        &mut self,
        row: usize,
        view: &BandView<'_>,
        scratch: &mut RowScratch<'_>,
    ) -> Result<(), Error> {
        self.compute_with(row, view, Some(scratch))
    }

    fn compute_with(
        &mut self,
        row: usize,
        view: &BandView<'_>,
        scratch: Option<&mut RowScratch<'_>>,
    ) -> Result<(), Error> {
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
        match scratch {
            Some(s) => (self.sgm).push_row_in(&left, &right, (&mut *s.u32s, &mut *s.u16s), disparity, kept)?,
            None => self.sgm.push_row(&left, &right, disparity, kept)?,
        };
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
