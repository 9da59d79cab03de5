//! The saturating 64-bit LayerNorm: the specification of every faster path (the buffered
//! rows, the narrow rows and their 32-bit lanes, the Helium and DSP loops).

use crate::fixed::{bit_length, isqrt_u64, round_shift, sat_i8_i64};
use crate::kernels::types::layernorm::{LayerNormQ, Z_FRAC_BITS};
use crate::kernels::types::params::I32s;

/// Significant bits the centred values are renormalised to.
pub const WORK_BITS: i32 = 24;
/// Fraction bits of the reciprocal standard deviation.
pub const RECIP_BITS: u32 = 40;

/// `dispatch::layernorm_rows` by the saturating 64-bit path only: the specification every faster path
/// (the narrow rows, their 32-bit lanes, the Helium loops) is tested against.
pub fn layernorm_rows_reference<Z: I32s + ?Sized, R: I32s + ?Sized>(
    x: &[i8],
    dim: usize,
    p: &LayerNormQ<'_, Z, R>,
    out: &mut [i8],
) {
    if dim == 0 {
        return;
    }
    for (row, out_row) in x.chunks_exact(dim).zip(out.chunks_exact_mut(dim)) {
        layernorm_row_unbuffered(row, p, out_row);
    }
}

/// How the narrow (32-bit lane) paths bring a row's centred values to [`WORK_BITS`]:
/// `n = ((v << left) + add) >> right` centres `v` (the row's `d` values summing to `sum`) and
/// carries the factor `d` and `2^-shift` of [`reciprocal_std`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NarrowShift {
    /// Bits of the deviation above [`WORK_BITS`] (the scale [`reciprocal_std`] takes).
    pub shift: i32,
    /// Left shift of each value.
    pub left: u32,
    /// What centres and rounds the shifted value.
    pub add: i32,
    /// Right shift after the add.
    pub right: u32,
}

/// The [`NarrowShift`] of a row of `d` values with sum `sum`, least `lo` and greatest `hi`;
/// `None` where the deviation is too wide for the narrow paths (the 64-bit path then).
#[inline(always)]
pub fn narrow_shift(sum: i64, lo: i32, hi: i32, d: i64) -> Option<NarrowShift> {
    let max_dev = (hi as i64 * d - sum).max(sum - lo as i64 * d) as u64;
    let shift = bit_length(max_dev) as i32 - WORK_BITS;
    let (left, add, right) = match shift {
        ..=0 => (
            (7 - shift) as u32,
            sum.wrapping_neg().wrapping_shl((-shift) as u32) as i32,
            0,
        ),
        1..=7 => ((7 - shift) as u32, (((1i64 << (shift - 1)) - sum) >> shift) as i32, 0),
        8..=13 => (0, (((1i64 << (shift - 1)) - sum) >> 7) as i32, (shift - 7) as u32),
        _ => return None,
    };
    Some(NarrowShift {
        shift,
        left,
        add,
        right,
    })
}

/// `2^RECIP_BITS / sqrt(var + eps)`, with eps (in unit^2) brought to the centred values'
/// scale: they carry a factor `d` and `2^-shift`.
#[inline(always)]
pub fn reciprocal_std(var: i64, eps: i64, d: i64, shift: i32) -> i64 {
    reciprocal_of_root(isqrt_u64(variance_radicand(var, eps, d, shift)))
}

/// The square root's argument in [`reciprocal_std`]: `var + eps` at the centred values' scale
/// (kernels that take several rows' roots at once split the formula here).
#[inline(always)]
pub fn variance_radicand(var: i64, eps: i64, d: i64, shift: i32) -> u64 {
    let eps = scale_pow2(eps.saturating_mul(d * d), -2 * shift);
    var.saturating_add(eps).max(0) as u64
}

/// `2^RECIP_BITS / root` for the floor square root of [`variance_radicand`] (a zero root
/// counts as one).
#[inline(always)]
pub fn reciprocal_of_root(root: u32) -> i64 {
    (1i64 << RECIP_BITS) / (root as i64).max(1)
}

/// One row (`row.len()` channels) by the saturating formulas.
pub fn layernorm_row_unbuffered<Z: I32s + ?Sized, R: I32s + ?Sized>(
    row: &[i8],
    p: &LayerNormQ<'_, Z, R>,
    out: &mut [i8],
) {
    let d = row.len() as i64;
    let value = |c: usize, q: i8| (q as i64 - p.zero.at(c) as i64) * p.rel.at(c) as i64;
    let sum: i64 = row
        .iter()
        .enumerate()
        .map(|(c, &q)| value(c, q))
        .fold(0, i64::saturating_add);
    // Centred and scaled by D, exactly: no rounding of the mean.
    let centred = |c: usize, q: i8| value(c, q).saturating_mul(d).saturating_sub(sum);
    let max_dev = row
        .iter()
        .enumerate()
        .map(|(c, &q)| centred(c, q).unsigned_abs())
        .max()
        .unwrap_or(0);
    let shift = bit_length(max_dev) as i32 - WORK_BITS;
    let norm = |c: usize, q: i8| scale_pow2(centred(c, q), -shift);
    let sum_sq = row.iter().enumerate().map(|(c, &q)| {
        let v = norm(c, q);
        v.saturating_mul(v)
    });
    let recip = reciprocal_std(sum_sq.fold(0i64, i64::saturating_add) / d, p.eps, d, shift);
    for (c, (&q, o)) in row.iter().zip(out.iter_mut()).enumerate() {
        let z_q16 = round_shift(norm(c, q).saturating_mul(recip), RECIP_BITS - Z_FRAC_BITS);
        *o = sat_i8_i64(p.out.apply_i64(z_q16));
    }
}

/// `x * 2^e`, saturating, rounding on right shifts.
fn scale_pow2(x: i64, e: i32) -> i64 {
    if e >= 0 {
        let e = e.min(62) as u32;
        x.checked_mul(1i64 << e)
            .unwrap_or(if x < 0 { i64::MIN } else { i64::MAX })
    } else {
        round_shift(x, e.unsigned_abs())
    }
}
