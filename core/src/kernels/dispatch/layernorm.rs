//! Integer LayerNorm without its affine part (gamma and beta are folded into the next linear
//! layer by the quantiser), robust to the large per-channel offsets of a ViT residual stream.
//!
//! The input is int8 with a per-channel format `real = scale[c] * (q - zero[c])`; `rel[c]`
//! holds `scale[c]` in a common unit, so `v[c] = (q - zero[c]) * rel[c]` is the real value in
//! that unit. The row is centred exactly (`D * v - sum v`), renormalised to 24 significant
//! bits so the variance fits in 64 bits, and divided by an integer square root. The output is
//! `z / out_scale`, rounded and saturated to int8.

use crate::fixed::{bit_length, sat_i8_i64, Requant};
use crate::kernels::layernorm::{layernorm_row, BUFFERED_DIM};
pub use crate::kernels::reference::layernorm::layernorm_rows_reference;
use crate::kernels::reference::layernorm::{narrow_shift, reciprocal_std, NarrowShift, RECIP_BITS, WORK_BITS};
pub use crate::kernels::types::layernorm::{LayerNormQ, Z_FRAC_BITS};
use crate::kernels::I32s;

/// Normalises each `dim`-channel row of `x` into `out`. Never inlined: its parameter and lane
/// buffers (3 KiB) then live on the stack only while it runs.
#[inline(never)]
pub fn layernorm_rows<Z: I32s + ?Sized, R: I32s + ?Sized>(
    x: &[i8],
    dim: usize,
    p: &LayerNormQ<'_, Z, R>,
    out: &mut [i8],
) {
    if dim == 0 {
        return;
    }
    let mut storage = [0i32; 2 * BUFFERED_DIM];
    if let Some(narrow) = NarrowParams::decode(p, dim, &mut storage) {
        crate::kernels::arch::vectorised(
            #[inline(always)]
            || narrow.rows(x, out),
        );
        return;
    }
    for (row, out_row) in x.chunks_exact(dim).zip(out.chunks_exact_mut(dim)) {
        layernorm_row(row, p, out_row);
    }
}
/// A LayerNorm's per-channel parameters decoded once into plain arrays, for formats whose
/// values `(q - zero) * rel` fit 32 bits (`|zero|, |rel| <= 2^15`: quantiser-made formats
/// have `|zero| < 2^9` and `rel <= 2^15`) and rows of at most [`BUFFERED_DIM`] channels. Gives
/// the codes of [`layernorm_row`] bit for bit, with 32-bit values and one 32 x 32 -> 64-bit
/// product per step where 64 bits are needed (the bounds are at each step).
struct NarrowParams<'s> {
    zero: &'s [i32],
    rel: &'s [i32],
    dim: usize,
    eps: i64,
    out: Requant,
}

/// A LayerNorm's parameters decoded and checked once for the calls of a pass that share them
/// (the encoder normalises one token block at a time), in storage the caller lends (two words
/// a channel), instead of once per call.
pub struct PreparedLayerNorm<'s> {
    narrow: NarrowParams<'s>,
    values: &'s mut [i32],
    normalised: &'s mut [i32],
}

impl<'s> PreparedLayerNorm<'s> {
    /// Words of storage [`PreparedLayerNorm::new`] takes for rows of `dim` channels: the
    /// parameters and the lanes' two buffers.
    pub const fn storage_words(dim: usize) -> usize {
        2 * dim + 2 * LANE_DIM
    }

    /// `p` for rows of `dim` channels, in `storage`; `None` for formats outside the narrow
    /// path's bounds (zero points and scales within `2^15`, `dim` at most 256) or a `storage`
    /// of fewer than [`PreparedLayerNorm::storage_words`] (then [`layernorm_rows`]).
    pub fn new<Z: I32s + ?Sized, R: I32s + ?Sized>(
        p: &LayerNormQ<'_, Z, R>,
        dim: usize,
        storage: &'s mut [i32],
    ) -> Option<Self> {
        let (params, lanes) = storage.get_mut(..Self::storage_words(dim))?.split_at_mut(2 * dim);
        let (values, normalised) = lanes.split_at_mut(LANE_DIM);
        let narrow = NarrowParams::decode(p, dim, params)?;
        Some(PreparedLayerNorm {
            narrow,
            values,
            normalised,
        })
    }
}

/// [`layernorm_rows`] with the parameters prepared once.
pub fn layernorm_rows_prepared(x: &[i8], p: &mut PreparedLayerNorm<'_>, out: &mut [i8]) {
    crate::kernels::arch::vectorised(
        #[inline(always)]
        || p.narrow.rows_with(x, out, p.values, p.normalised),
    );
}

/// Bound on `|zero|` and `|rel|` of [`NarrowParams`].
const NARROW_LIMIT: u32 = 1 << 15;

impl<'s> NarrowParams<'s> {
    /// `p`'s zero points and scales for `dim` channels copied into `storage` (`2 dim` words)
    /// and checked; `None` outside the bounds.
    fn decode<Z: I32s + ?Sized, R: I32s + ?Sized>(
        p: &LayerNormQ<'_, Z, R>,
        dim: usize,
        storage: &'s mut [i32],
    ) -> Option<Self> {
        if dim > BUFFERED_DIM || p.eps < 0 || !(1..=crate::fixed::MAX_SHIFT).contains(&p.out.shift) {
            return None;
        }
        let (zeros, rels) = storage.get_mut(..2 * dim)?.split_at_mut(dim);
        for (c, (z, r)) in zeros.iter_mut().zip(rels.iter_mut()).enumerate() {
            let (zero, rel) = (p.zero.at(c), p.rel.at(c));
            if zero.unsigned_abs() > NARROW_LIMIT || rel.unsigned_abs() > NARROW_LIMIT {
                return None;
            }
            (*z, *r) = (zero, rel);
        }
        Some(NarrowParams {
            zero: zeros,
            rel: rels,
            dim,
            eps: p.eps,
            out: p.out,
        })
    }

    /// Every `dim`-channel row of `x` into `out`.
    #[inline(always)]
    fn rows(&self, x: &[i8], out: &mut [i8]) {
        let (mut values, mut normalised) = ([0i32; LANE_DIM], [0i32; LANE_DIM]);
        self.rows_with(x, out, &mut values, &mut normalised);
    }

    /// [`NarrowParams::rows`] with the lanes' buffers lent (`LANE_DIM` words each).
    #[inline(always)]
    fn rows_with(&self, x: &[i8], out: &mut [i8], values: &mut [i32], normalised: &mut [i32]) {
        if self.dim == 0 {
            return;
        }
        let mut scratch = LaneScratch { values, normalised };
        #[cfg(target_arch = "x86_64")]
        if self.rows_in_x86_lanes(x, out, &mut scratch) {
            return;
        }
        for (row, out_row) in x.chunks_exact(self.dim).zip(out.chunks_exact_mut(self.dim)) {
            self.row(row, out_row, &mut scratch);
        }
    }

    /// [`layernorm_row`] of one row (`dim` codes).
    // Inlined on x86 so that `dispatch::vectorised` compiles it for the CPU's vector unit.
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    fn row(&self, row: &[i8], out: &mut [i8], scratch: &mut LaneScratch) {
        let dim = self.dim.min(row.len()).min(out.len());
        if dim == 0 {
            return;
        }
        let (row, out) = (&row[..dim], &mut out[..dim]);
        // On x86 hosts LLVM vectorises the lanes' 32-bit arithmetic as well.
        if cfg!(any(bino_mve, bino_dsp, test, target_arch = "x86_64")) && self.row_in_lanes(row, out, scratch) {
            return;
        }
        let d = dim as i64;
        // |q - zero| <= 2^15 + 128 and |rel| <= 2^15: every value fits 31 bits.
        let mut v = [0i32; BUFFERED_DIM];
        let v = &mut v[..dim];
        for (((x, &q), &zero), &rel) in v.iter_mut().zip(row).zip(self.zero).zip(self.rel) {
            *x = (q as i32 - zero).wrapping_mul(rel);
        }
        let sum = v.iter().fold(0i64, |a, &x| a + x as i64);
        let (lo, hi) = v
            .iter()
            .fold((i32::MAX, i32::MIN), |(lo, hi), &x| (lo.min(x), hi.max(x)));
        // d * v - sum grows with v: its largest magnitude is at the smallest or largest value.
        let max_dev = (hi as i64 * d - sum).max(sum - lo as i64 * d) as u64;
        let shift = bit_length(max_dev) as i32 - WORK_BITS;
        // Normalised values have at most 24 significant bits (one more after rounding up).
        let mut n = [0i32; BUFFERED_DIM];
        let n = &mut n[..dim];
        if shift > 0 {
            let (half, s) = ((1i64 << (shift - 1)) - sum, shift as u32 & 63);
            for (y, &x) in n.iter_mut().zip(v.iter()) {
                *y = ((x as i64 * d + half) >> s) as i32;
            }
        } else {
            let s = (-shift) as u32 & 63;
            for (y, &x) in n.iter_mut().zip(v.iter()) {
                *y = ((x as i64 * d - sum) << s) as i32;
            }
        }
        // Squares < 2^50 each, at most 2^58 summed.
        let sum_sq = n.iter().fold(0i64, |a, &y| a + y as i64 * y as i64);
        // At most 2^21 whenever some value is non-zero (see layernorm_row); when all are zero
        // the product is zero whatever the reciprocal, so clamping it changes nothing.
        let recip = reciprocal_std(sum_sq / d, self.eps, d, shift).min(i32::MAX as i64);
        let z_half = 1i64 << (RECIP_BITS - Z_FRAC_BITS - 1);
        let (mult, out_shift) = (self.out.mult as i64, self.out.shift & 63);
        let out_half = 1i64 << (out_shift.wrapping_sub(1) & 63);
        for (o, &y) in out.iter_mut().zip(n.iter()) {
            // |z| <= 2^21 and |mult| < 2^31: the output product never saturates.
            let z = (y as i64 * recip + z_half) >> (RECIP_BITS - Z_FRAC_BITS);
            *o = sat_i8_i64((z * mult + out_half) >> out_shift);
        }
    }
}

impl NarrowParams<'_> {
    /// [`NarrowParams::rows_with`] on x86 hosts with AVX-512 VNNI or AVX2 for rows of
    /// [`LANE_DIM`] channels: eight rows at a time in `kernels::arch::x86::vnni::layernorm` or
    /// `kernels::arch::x86::avx2::layernorm` (bit for bit [`NarrowParams::row_in_lanes`]), any
    /// row it leaves by [`NarrowParams::row`]. `false` (nothing written) where it does not apply.
    #[cfg(target_arch = "x86_64")]
    #[inline(always)]
    fn rows_in_x86_lanes(&self, x: &[i8], out: &mut [i8], scratch: &mut LaneScratch) -> bool {
        use crate::kernels::arch::x86::{avx2, vnni, vnni::layernorm};
        let (Ok(zero), Ok(rel)) = (
            <&[i32; LANE_DIM]>::try_from(self.zero),
            <&[i32; LANE_DIM]>::try_from(self.rel),
        ) else {
            return false;
        };
        let kernel = if vnni::available() {
            layernorm::rows
        } else if crate::kernels::arch::x86::avx2() {
            avx2::layernorm::rows
        } else {
            return false;
        };
        if self.dim != LANE_DIM {
            return false;
        }
        let lanes = layernorm::NormLanes {
            zero,
            rel,
            eps: self.eps,
            mult: self.out.mult,
            shift: self.out.shift,
        };
        let rows = x.len().min(out.len()) / LANE_DIM;
        let (Some(x), Some(out)) = (x.get(..rows * LANE_DIM), out.get_mut(..rows * LANE_DIM)) else {
            return false;
        };
        let block = layernorm::ROWS * LANE_DIM;
        for (x8, o8) in x.chunks(block).zip(out.chunks_mut(block)) {
            let left = kernel(&lanes, x8, o8).unwrap_or(u8::MAX);
            for (r, (row, out_row)) in x8.chunks_exact(LANE_DIM).zip(o8.chunks_exact_mut(LANE_DIM)).enumerate() {
                if left & (1 << r) != 0 {
                    self.row(row, out_row, scratch);
                }
            }
        }
        true
    }

    /// [`NarrowParams::row`] in 32-bit lanes, three passes that are Helium loops on Cortex-M55
    /// (`kernels::arch`; portable twins below on Cortex-M7, where 32-bit lanes in scalar code
    /// also beat 64-bit arithmetic, and in host tests), for rows of [`LANE_DIM`]
    /// channels. `false` (nothing written) where an identity below needs more: a shift above
    /// 13, a reciprocal from `2^23`, an output shift below 33.
    ///
    /// With `d = 2^7`, `H = half - sum` and the row's shift `s`, the scalar path's normalised
    /// value `((v d + H) >> s) as i32` is, for `s <= 7`, `(v << (7 - s)) + (H >> s)` modulo 2^32
    /// (no bits leave a right shift; for `s <= 0`, `H = -sum` and `>> s` is `<< -s`), and for
    /// `7 < s <= 13` it is `(v + (H >> 7)) >> (s - 7)` (the 7 low bits of `H` never carry past a
    /// multiple of `2^(s-7)`), whose sum is exact in 32 bits because `|v d - sum| < 2^(24+s)`.
    /// The output's `(n recip + 2^23) >> 24` is `vrmulh(n, recip << 8)`, and
    /// `(z mult + 2^(sh-1)) >> sh` for `sh >= 33` is `(vmulh(z, mult) + 2^(sh-33)) >> (sh - 32)`,
    /// as in the fused GEMM epilogue.
    #[cfg_attr(not(any(bino_mve, bino_dsp, test, target_arch = "x86_64")), allow(dead_code))]
    #[cfg_attr(target_arch = "x86_64", inline(always))]
    fn row_in_lanes(&self, row: &[i8], out: &mut [i8], scratch: &mut LaneScratch) -> bool {
        let dim = row.len();
        if dim != LANE_DIM || out.len() != dim || self.out.shift < 33 {
            return false;
        }
        let (Some(zero), Some(rel)) = (self.zero.get(..dim), self.rel.get(..dim)) else {
            return false;
        };
        let (Some(v), Some(n)) = (scratch.values.get_mut(..dim), scratch.normalised.get_mut(..dim)) else {
            return false;
        };
        let Some((sum, lo, hi)) = lanes::values(row, zero, rel, v) else {
            return false;
        };
        let d = dim as i64;
        let Some(NarrowShift {
            shift,
            left,
            add,
            right,
        }) = narrow_shift(sum, lo, hi, d)
        else {
            return false;
        };
        let Some(sum_sq) = lanes::normalise(v, left, add, right, n) else {
            return false;
        };
        // `sum_sq / d` for d = 2^7: a sum of squares below 2^58 is not negative.
        let recip = reciprocal_std(sum_sq >> 7, self.eps, d, shift).min(i32::MAX as i64);
        if recip >= 1 << 23 {
            return false;
        }
        let post = self.out.shift - 32;
        lanes::output(n, (recip << 8) as i32, self.out.mult, 1 << (post - 1), post, out)
    }
}

/// The lane passes' values and normalised values (`LANE_DIM` each), kept by
/// [`layernorm_rows`] for all its rows and by a [`PreparedLayerNorm`] for a whole pass (zeroing
/// them per row cost a 1 KiB `memclr` each).
struct LaneScratch<'w> {
    values: &'w mut [i32],
    normalised: &'w mut [i32],
}

/// Row length of [`NarrowParams::row_in_lanes`]: the encoder's width, `2^7`.
const LANE_DIM: usize = 128;

/// The three lane passes of [`NarrowParams::row_in_lanes`]: the Helium loops of
/// `kernels::arch` on Cortex-M55 (and DSP loops on Cortex-M7), these portable
/// twins elsewhere (the same 32-bit lane arithmetic, so the host tests prove the identities
/// the loops rely on).
mod lanes {
    /// `v = (q - zero) * rel` per channel; the 64-bit sum, the minimum and the maximum.
    #[inline(always)]
    pub(super) fn values(row: &[i8], zero: &[i32], rel: &[i32], v: &mut [i32]) -> Option<(i64, i32, i32)> {
        #[cfg(bino_mve)]
        return crate::kernels::arch::layernorm_values(row, zero, rel, v);
        #[cfg(bino_dsp)]
        if let Some(found) = crate::kernels::arch::dsp::layernorm_values(row, zero, rel, v) {
            return Some(found);
        }
        #[cfg(not(bino_mve))]
        crate::kernels::layernorm::lanes::values(row, zero, rel, v)
    }

    /// `n = ((v << left) + add) >> right` (wrapping, arithmetic shift) and the 64-bit sum of
    /// the squares of `n`.
    #[inline(always)]
    pub(super) fn normalise(v: &[i32], left: u32, add: i32, right: u32, n: &mut [i32]) -> Option<i64> {
        #[cfg(bino_mve)]
        return crate::kernels::arch::layernorm_normalise(v, left, add, right, n);
        #[cfg(bino_dsp)]
        if let Some(sum_sq) = crate::kernels::arch::dsp::layernorm_normalise(v, left, add, right, n) {
            return Some(sum_sq);
        }
        #[cfg(not(bino_mve))]
        crate::kernels::layernorm::lanes::normalise(v, left, add, right, n)
    }

    /// `out = sat8((hi32(rnd_hi32(n * recip_q) * mult) + round) >> post)`.
    #[inline(always)]
    pub(super) fn output(n: &[i32], recip_q: i32, mult: i32, round: i32, post: u32, out: &mut [i8]) -> bool {
        crate::kernels::dispatch::epilogue::scaled_requant_lanes(n, recip_q, mult, round, post, out)
    }
}
#[cfg(test)]
mod tests;
