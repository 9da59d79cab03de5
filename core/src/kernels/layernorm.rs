//! The portable LayerNorm paths that the dispatch (`kernels::dispatch::layernorm`) runs where no
//! instruction set's kernel takes a row: the buffered 64-bit row and the 32-bit lane passes'
//! portable twins. No instruction set is named here.

use crate::fixed::bit_length;
use crate::fixed::sat_i8_i64;
use crate::kernels::reference::layernorm::{layernorm_row_unbuffered, reciprocal_std, RECIP_BITS, WORK_BITS};
use crate::kernels::types::layernorm::{LayerNormQ, Z_FRAC_BITS};
use crate::kernels::types::params::I32s;

/// Rows up to this many channels are normalised from a stack buffer of their values (computed
/// once instead of once per pass); longer rows recompute them.
pub const BUFFERED_DIM: usize = 256;

/// One row (`row.len()` channels) in 64-bit arithmetic from a stack buffer of its values, bit
/// for bit [`layernorm_row_unbuffered`] (which takes rows past [`BUFFERED_DIM`] channels and
/// formats no quantiser makes).
pub fn layernorm_row<Z: I32s + ?Sized, R: I32s + ?Sized>(row: &[i8], p: &LayerNormQ<'_, Z, R>, out: &mut [i8]) {
    if row.len() > BUFFERED_DIM {
        return layernorm_row_unbuffered(row, p, out);
    }
    let d = row.len() as i64;
    let mut buffer = [0i64; BUFFERED_DIM];
    let v = &mut buffer[..row.len()];
    let mut zero_bits = 0u32;
    for (c, (slot, &q)) in v.iter_mut().zip(row).enumerate() {
        let zero = p.zero.at(c);
        zero_bits |= zero.unsigned_abs();
        *slot = (q as i64 - zero as i64) * p.rel.at(c) as i64;
    }
    if zero_bits >= 1 << 16 {
        // Formats no quantiser makes: the saturating path handles them.
        return layernorm_row_unbuffered(row, p, out);
    }
    // From here nothing can overflow (|value| < 2^48, centred < 2^57, normalised < 2^25,
    // squares summed < 2^58, products with the reciprocal < 2^46: the reciprocal is at most
    // 2^40 / (2^23 / sqrt(256))), so the saturating path's results are reproduced exactly
    // with plain arithmetic that vectorises. Wrapping ops keep debug builds panic-free.
    let sum = v.iter().fold(0i64, |a, &x| a.wrapping_add(x));
    let mut max_dev = 0u64;
    for x in v.iter_mut() {
        *x = x.wrapping_mul(d).wrapping_sub(sum);
        max_dev = max_dev.max(x.unsigned_abs());
    }
    let shift = bit_length(max_dev) as i32 - WORK_BITS;
    if shift > 0 {
        let half = 1i64 << (shift - 1);
        v.iter_mut().for_each(|x| *x = x.wrapping_add(half) >> shift);
    } else {
        v.iter_mut().for_each(|x| *x <<= -shift);
    }
    let sum_sq = v.iter().fold(0i64, |a, &x| a.wrapping_add(x.wrapping_mul(x)));
    let recip = reciprocal_std(sum_sq / d, p.eps, d, shift);
    let z_half = 1i64 << (RECIP_BITS - Z_FRAC_BITS - 1);
    for (&x, o) in v.iter().zip(out.iter_mut()) {
        let z_q16 = x.wrapping_mul(recip).wrapping_add(z_half) >> (RECIP_BITS - Z_FRAC_BITS);
        *o = sat_i8_i64(p.out.apply_i64(z_q16));
    }
}

/// The portable twins of the lane passes of `dispatch::layernorm` (the same 32-bit lane
/// arithmetic as the Helium and DSP loops, so the host tests prove the identities the loops
/// rely on).
pub mod lanes {
    /// `v = (q - zero) * rel` per channel; the 64-bit sum, the minimum and the maximum.
    #[inline(always)]
    pub fn values(row: &[i8], zero: &[i32], rel: &[i32], v: &mut [i32]) -> Option<(i64, i32, i32)> {
        let (mut sum, mut lo, mut hi) = (0i64, i32::MAX, i32::MIN);
        for (((x, &q), &z), &r) in v.iter_mut().zip(row).zip(zero).zip(rel) {
            *x = (q as i32).wrapping_sub(z).wrapping_mul(r);
            sum = sum.wrapping_add(*x as i64);
            (lo, hi) = (lo.min(*x), hi.max(*x));
        }
        Some((sum, lo, hi))
    }

    /// `n = ((v << left) + add) >> right` (wrapping, arithmetic shift) and the 64-bit sum of
    /// the squares of `n`.
    #[inline(always)]
    pub fn normalise(v: &[i32], left: u32, add: i32, right: u32, n: &mut [i32]) -> Option<i64> {
        let mut sum_sq = 0i64;
        for (y, &x) in n.iter_mut().zip(v) {
            *y = (x.wrapping_shl(left).wrapping_add(add)) >> (right & 31);
            sum_sq = sum_sq.wrapping_add(*y as i64 * *y as i64);
        }
        Some(sum_sq)
    }
}
