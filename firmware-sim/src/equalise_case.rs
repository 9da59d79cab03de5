//! A half-defocused test pair for the sharpness-equalised refinement (issue 14), made the same
//! way by `build.rs` on the host, which bakes the CRC-32 of its refinement into the firmware,
//! and by the kernel-test firmware on the target, which refines it again and compares: the
//! committed band blurs no row, so its digests never reach the equalisation's blurring branch.
//!
//! The pair: a hashed texture, the right view the left shifted by 3 px, its lower half under a
//! 5x5 box (`refine::sharpness::box_row`); a token grid of about 3 px with a small pattern.

use bino_core::crc32::Crc32;
use bino_core::refine::sharpness::{box_row, decide_map_row, refine_map_equalised};
use bino_core::refine::{scratch_len, RefineParams};
use bino_core::Error;

/// Rows.
pub const HEIGHT: usize = 24;
/// Columns.
pub const WIDTH: usize = 64;
/// Pixels of one view.
pub const PIXELS: usize = HEIGHT * WIDTH;
/// Token cells.
pub const CELLS: usize = (HEIGHT / 4) * (WIDTH / 4);

/// The two views.
pub fn views() -> Result<([u8; PIXELS], [u8; PIXELS]), Error> {
    let texture = |x: usize, y: usize| -> u8 {
        let h = (x as u32).wrapping_mul(2_654_435_761) ^ (y as u32).wrapping_mul(40_503);
        let h = h.wrapping_mul(2_246_822_519);
        ((h >> 24) as u8 / 2).wrapping_add(((x / 3 + y / 2) % 2) as u8 * 100)
    };
    let mut left = [0u8; PIXELS];
    let mut shifted = [0u8; PIXELS];
    for (i, (l, r)) in left.iter_mut().zip(shifted.iter_mut()).enumerate() {
        let (y, x) = (i / WIDTH, i % WIDTH);
        (*l, *r) = (texture(x, y), texture(x + 3, y));
    }
    let mut right = shifted;
    for y in HEIGHT / 2..HEIGHT {
        let rows: [&[u8]; 5] = core::array::from_fn(|j| {
            let v = (y + j).saturating_sub(2).min(HEIGHT - 1);
            &shifted[v * WIDTH..(v + 1) * WIDTH]
        });
        box_row(&rows, 2, &mut right[y * WIDTH..(y + 1) * WIDTH])?;
    }
    Ok((left, right))
}

/// The token grid, Q8 patch columns (3 px = 0.75 patch columns, give or take).
pub fn tokens() -> [u16; CELLS] {
    core::array::from_fn(|i| 192 + (i * 37 % 7) as u16 * 8)
}

/// Rows whose census reads a blurred view.
pub fn blurred_rows(left: &[u8], right: &[u8]) -> Result<usize, Error> {
    let mut n = 0;
    for y in 0..HEIGHT {
        n += usize::from(decide_map_row(left, right, WIDTH, HEIGHT, y)?.radius > 0);
    }
    Ok(n)
}

/// CRC-32 of `refine_map_equalised` on the pair (values little-endian, rows top to bottom).
pub fn refined_crc() -> Result<u32, Error> {
    let (left, right) = views()?;
    let params = RefineParams::DEFAULT;
    let mut scratch = [0u32; scratch_len(WIDTH, &RefineParams::DEFAULT)];
    let mut out = [0u16; PIXELS];
    refine_map_equalised(&left, &right, WIDTH, &tokens(), &params, &mut scratch, &mut out)?;
    let mut crc = Crc32::new();
    for v in out {
        crc.update(&v.to_le_bytes());
    }
    Ok(crc.finish())
}
