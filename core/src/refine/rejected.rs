//! The `+lr+ref` readouts' rule for the cells the left-right check rejected: their pixels keep
//! the bilinear `d0` of the filled grid rather than the census match.

use super::{bilinear, token_rows, TokenRows};
use crate::config::{CELL_W, PATCH_H};
use crate::Error;

/// The `+lr+ref` readouts' rule for the cells their left-right check rejected: the pixels of a
/// rejected cell keep `d0`, the bilinear step of the (filled) grid, instead of the census match
/// in `out`. Rejected cells are mostly occlusions, where the right view holds no true match for
/// the census to find; there it moved pixels away from the filled disparity by up to the search
/// radius. Chosen off the eval split (`train/experiments.json`, `keep_rejected`): at 320 px the
/// sgm+lr+ref bad1tok fell on all three validations (2.27 -> 2.26, 8.79 -> 7.79, 12.70 -> 12.03).
///
/// `y` is the output row, `tokens` its two token rows ([`token_rows`]) and `kept` the mask of
/// its own grid row `y / 4` (0: rejected), `ceil(W / 4)` cells each, `W = out.len()`.
/// Errors: [`Error::BufferSize`] for a token or mask row of the wrong length.
pub fn keep_rejected_row(y: usize, tokens: &TokenRows<'_>, kept: &[u8], out: &mut [u16]) -> Result<(), Error> {
    let cells = out.len().div_ceil(CELL_W);
    Error::check_len("first token row", cells, tokens.first.len())?;
    Error::check_len("second token row", cells, tokens.second.len())?;
    Error::check_len("left-right mask row", cells, kept.len())?;
    for (x, o) in out.iter_mut().enumerate() {
        if kept.get(x / CELL_W).is_some_and(|&k| k == 0) {
            *o = bilinear(x, y, tokens, cells).min(u16::MAX as u32) as u16;
        }
    }
    Ok(())
}

/// [`keep_rejected_row`] over whole maps: `tokens` the filled grid and `kept` its mask (each
/// `ceil(H / 4) x ceil(W / 4)`, `W = width`), `out` the `H x W` refined map, in place.
///
/// Errors: [`Error::EmptyImage`] for `width` 0, [`Error::BufferSize`] for a map that is not
/// whole rows or a grid or mask of the wrong size.
pub fn keep_rejected_map(width: usize, tokens: &[u16], kept: &[u8], out: &mut [u16]) -> Result<(), Error> {
    if width == 0 || out.is_empty() {
        return Err(Error::EmptyImage);
    }
    if !out.len().is_multiple_of(width) {
        return Err(Error::BufferSize {
            what: "refined disparity",
            expected: out.len() / width * width,
            found: out.len(),
        });
    }
    let height = out.len() / width;
    let (grid_rows, cells) = (height.div_ceil(PATCH_H), width.div_ceil(CELL_W));
    Error::check_len("token grid", grid_rows * cells, tokens.len())?;
    Error::check_len("left-right mask", grid_rows * cells, kept.len())?;
    let grid_row = |t: usize| tokens.get(t * cells..(t + 1) * cells).unwrap_or_default();
    for (y, row) in out.chunks_exact_mut(width).enumerate() {
        let (first, second) = token_rows(y, grid_rows);
        let rows = TokenRows {
            first: grid_row(first),
            second: grid_row(second),
        };
        let own = y / PATCH_H;
        keep_rejected_row(
            y,
            &rows,
            kept.get(own * cells..(own + 1) * cells).unwrap_or_default(),
            row,
        )?;
    }
    Ok(())
}
