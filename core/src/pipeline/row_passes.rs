//! A band's encoder passes one token row at a time ([`Passes::TokenRow`]): [`RowPasses`] answers
//! the pipeline's band passes with one pass per token row, each row's output written after the
//! last, so the band's outputs are the bytes one band pass writes while the encoder's scratch
//! holds a single row's work. The sizes of both ways are [`scratch_bytes`].

use super::api::{BandEncoder, Passes};
use super::layout::sum;
use crate::config::PATCH_H;
use crate::model::encoder::{self, GrayBand};
use crate::Error;

/// Arena bytes of the encoder's scratch for a band of `band_rows` pixel rows, `width` pixels
/// wide, whose pass writes `out_row_len` bytes a token row: one band pass's scratch, or with
/// [`Passes::TokenRow`] the band's outputs but the last row and one row's pass after them.
pub(super) const fn scratch_bytes(passes: Passes, band_rows: usize, width: usize, out_row_len: usize) -> usize {
    match passes {
        Passes::Band => encoder::arena_bytes(band_rows, width),
        Passes::TokenRow => match (band_rows / PATCH_H).checked_sub(1) {
            Some(before) => sum(&[before.saturating_mul(out_row_len), encoder::arena_bytes(PATCH_H, width)]),
            None => 0,
        },
    }
}

/// `encoder`'s passes as the pipeline asks for them, by band or ([`Passes::TokenRow`]) a token
/// row at a time. One type for both, so a firmware carries one copy of each band loop.
pub(super) struct RowPasses<'e, E> {
    pub(super) encoder: &'e mut E,
    pub(super) passes: Passes,
}

impl<E: BandEncoder> BandEncoder for RowPasses<'_, E> {
    fn view_pass(&mut self, view: GrayBand<'_>, arena: &mut [u8]) -> Result<(usize, usize), Error> {
        match self.passes {
            Passes::Band => self.encoder.view_pass(view, arena),
            Passes::TokenRow => by_rows(view.height(), arena, |first, arena| {
                self.encoder.view_pass(view.rows(first, PATCH_H)?, arena)
            }),
        }
    }

    fn pair_pass(
        &mut self,
        left: GrayBand<'_>,
        right: GrayBand<'_>,
        arena: &mut [u8],
    ) -> Result<(usize, usize), Error> {
        match self.passes {
            Passes::Band => self.encoder.pair_pass(left, right, arena),
            Passes::TokenRow => by_rows(left.height(), arena, |first, arena| {
                let (l, r) = (left.rows(first, PATCH_H)?, right.rows(first, PATCH_H)?);
                self.encoder.pair_pass(l, r, arena)
            }),
        }
    }
}

/// `pass` on each token row of a band of `pixel_rows` rows (its first pixel row given), in
/// `arena` after the rows before's outputs: the high-water and the outputs' length, as one band
/// pass answers.
fn by_rows(
    pixel_rows: usize,
    arena: &mut [u8],
    mut pass: impl FnMut(usize, &mut [u8]) -> Result<(usize, usize), Error>,
) -> Result<(usize, usize), Error> {
    let (mut at, mut used) = (0usize, 0usize);
    for row in 0..pixel_rows / PATCH_H {
        let available = arena.len();
        let rest = arena
            .get_mut(at..)
            .ok_or(Error::ArenaTooSmall { needed: at, available })?;
        let (row_used, len) = pass(row * PATCH_H, rest)?;
        used = used.max(at.saturating_add(row_used));
        at = at.saturating_add(len);
    }
    Ok((used, at))
}
