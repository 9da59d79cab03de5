//! A band's encoder passes a few token rows at a time ([`Passes::TokenRows`]): [`RowPasses`]
//! answers the pipeline's band passes with one pass per [`TOKEN_ROWS_PER_PASS`] token rows, each
//! pass's output written after the last, so the band's outputs are the bytes one band pass
//! writes while the encoder's scratch holds a single pass's work. The sizes of both ways are
//! [`scratch_bytes`].

use super::api::{BandEncoder, Passes, TOKEN_ROWS_PER_PASS};
use super::layout::sum;
use crate::config::PATCH_H;
use crate::model::encoder::{self, GrayBand};
use crate::Error;

/// Pixel rows of a [`Passes::TokenRows`] pass.
const PASS_PIXEL_ROWS: usize = TOKEN_ROWS_PER_PASS * PATCH_H;

/// Arena bytes of the encoder's scratch for a band of `band_rows` pixel rows, `width` pixels
/// wide, whose pass writes `out_row_len` bytes a token row: one band pass's scratch, or with
/// [`Passes::TokenRows`] the outputs of the band's rows before its last full pass and that
/// pass's scratch after them. A pass of fewer rows, or one after rows kept from the band
/// before, ends no further: a token row more of a pass's scratch (`2 x cols` tokens of 388
/// bytes) is more than a token row of its outputs (at most `2 x cols x DIM` bytes).
pub(super) const fn scratch_bytes(passes: Passes, band_rows: usize, width: usize, out_row_len: usize) -> usize {
    match passes {
        Passes::Band => encoder::arena_bytes(band_rows, width),
        Passes::TokenRows => {
            let token_rows = band_rows / PATCH_H;
            let pass = if token_rows < TOKEN_ROWS_PER_PASS {
                token_rows
            } else {
                TOKEN_ROWS_PER_PASS
            };
            sum(&[
                (token_rows - pass).saturating_mul(out_row_len),
                encoder::arena_bytes(pass * PATCH_H, width),
            ])
        }
    }
}

/// `encoder`'s passes as the pipeline asks for them, by band or ([`Passes::TokenRows`]) a few
/// token rows at a time. One type for both, so a firmware carries one copy of each band loop.
pub(super) struct RowPasses<'e, E> {
    pub(super) encoder: &'e mut E,
    pub(super) passes: Passes,
}

impl<E: BandEncoder> BandEncoder for RowPasses<'_, E> {
    fn view_pass(&mut self, view: GrayBand<'_>, arena: &mut [u8]) -> Result<(usize, usize), Error> {
        match self.passes {
            Passes::Band => self.encoder.view_pass(view, arena),
            Passes::TokenRows => by_rows(view.height(), arena, |first, rows, arena| {
                self.encoder.view_pass(view.rows(first, rows)?, arena)
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
            Passes::TokenRows => by_rows(left.height(), arena, |first, rows, arena| {
                let (l, r) = (left.rows(first, rows)?, right.rows(first, rows)?);
                self.encoder.pair_pass(l, r, arena)
            }),
        }
    }
}

/// `pass` on each run of up to [`TOKEN_ROWS_PER_PASS`] token rows of a band of `pixel_rows`
/// rows (its first pixel row and its pixel rows given), in `arena` after the runs before's
/// outputs: the high-water and the outputs' length, as one band pass answers.
fn by_rows(
    pixel_rows: usize,
    arena: &mut [u8],
    mut pass: impl FnMut(usize, usize, &mut [u8]) -> Result<(usize, usize), Error>,
) -> Result<(usize, usize), Error> {
    let (mut at, mut used) = (0usize, 0usize);
    let whole = pixel_rows - pixel_rows % PATCH_H;
    for first in (0..whole).step_by(PASS_PIXEL_ROWS) {
        let available = arena.len();
        let rest = arena
            .get_mut(at..)
            .ok_or(Error::ArenaTooSmall { needed: at, available })?;
        let (pass_used, len) = pass(first, PASS_PIXEL_ROWS.min(whole - first), rest)?;
        used = used.max(at.saturating_add(pass_used));
        at = at.saturating_add(len);
    }
    Ok((used, at))
}
