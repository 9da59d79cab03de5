//! One token row's buffers of the export pathway's matching readouts (the norms, both views'
//! cost rows and SGM sums, the WTA and SGM rows and masks, the guides) and the census SGM's row
//! scratch: nothing in them outlives the row, so they are cut from each band's scratch after
//! the encoder passes rather than kept beside it ([`row_bytes`]).

use super::census_stage::{self, RowScratch};
use super::layout::sum;
use crate::arena::{Carver, ALIGN_SLACK};
use crate::sgm::state_len;
use crate::Error;

/// Arena bytes of [`RowBuffers`] for `cols` patch columns and `max_cols` candidates (with the
/// guides when `guided`), and the census SGM's row scratch for views `census = Some((width,
/// head candidates))` (saturating).
pub(super) const fn row_bytes(cols: usize, max_cols: usize, guided: bool, census: Option<(usize, usize)>) -> usize {
    let volume_row = state_len(cols, max_cols);
    let words = cols.saturating_mul(4).saturating_add(ALIGN_SLACK); // one u32 row
    let halves = volume_row.saturating_mul(2).saturating_add(1); // one u16 cost row
    let sums = volume_row.saturating_mul(4).saturating_add(ALIGN_SLACK); // one u32 cost row
    let disparity = cols.saturating_mul(2).saturating_add(1); // one u16 disparity row
    let census = match census {
        Some((width, candidates)) => census_stage::row_bytes(width, candidates),
        None => 0,
    };
    sum(&[
        words.saturating_mul(2),                         // inverse norms, left and right
        halves.saturating_mul(2),                        // cost rows, left and right view
        sums.saturating_mul(2),                          // SGM sums, left and right view
        disparity.saturating_mul(4),                     // WTA and SGM rows, both views
        cols.saturating_mul(2),                          // left-right masks
        if guided { cols.saturating_mul(2) } else { 0 }, // SGM guides of the row
        census,
    ])
}

/// One token row's buffers (see the module).
pub(super) struct RowBuffers<'b> {
    pub(super) inv_left: &'b mut [u32],
    pub(super) inv_right: &'b mut [u32],
    pub(super) cost: &'b mut [u16],
    pub(super) cost_right: &'b mut [u16],
    pub(super) sum: &'b mut [u32],
    pub(super) sum_right: &'b mut [u32],
    pub(super) wta: &'b mut [u16],
    pub(super) wta_right: &'b mut [u16],
    pub(super) sgm_out: &'b mut [u16],
    pub(super) sgm_right_out: &'b mut [u16],
    pub(super) wta_mask: &'b mut [u8],
    pub(super) sgm_mask: &'b mut [u8],
    /// Each cell's mean grey level in the left and right view (guided SGM only; else empty).
    pub(super) guide_left: &'b mut [u8],
    pub(super) guide_right: &'b mut [u8],
    /// The census SGM's row scratch (with the census stage).
    pub(super) census: Option<RowScratch<'b>>,
}

impl<'b> RowBuffers<'b> {
    /// The buffers of [`row_bytes`] with the same arguments, cut from the front of `arena`;
    /// returns them and the bytes they took.
    pub(super) fn carve(
        arena: &'b mut [u8],
        cols: usize,
        max_cols: usize,
        guided: bool,
        census: Option<(usize, usize)>,
    ) -> Result<(Self, usize), Error> {
        let mut carver = Carver::new(arena, row_bytes(cols, max_cols, guided, census))?;
        let volume_row = state_len(cols, max_cols);
        let guide_cols = if guided { cols } else { 0 };
        let buffers = Self {
            inv_left: carver.u32s(cols)?,
            inv_right: carver.u32s(cols)?,
            cost: carver.u16s(volume_row)?,
            cost_right: carver.u16s(volume_row)?,
            sum: carver.u32s(volume_row)?,
            sum_right: carver.u32s(volume_row)?,
            wta: carver.u16s(cols)?,
            wta_right: carver.u16s(cols)?,
            sgm_out: carver.u16s(cols)?,
            sgm_right_out: carver.u16s(cols)?,
            wta_mask: carver.u8s(cols)?,
            sgm_mask: carver.u8s(cols)?,
            guide_left: carver.u8s(guide_cols)?,
            guide_right: carver.u8s(guide_cols)?,
            census: match census {
                Some((width, candidates)) => Some(RowScratch::carve(&mut carver, width, candidates)?),
                None => None,
            },
        };
        Ok((buffers, carver.used()))
    }
}
