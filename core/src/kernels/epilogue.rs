//! What follows a matrix multiply: bias, per-channel requantisation, residual addition.

use super::I32s;
use crate::fixed::{sat_i8_i64, Requant};

/// Per-output-channel `acc -> (acc + bias[c]) * mult[c] / 2^shift[c]`.
#[derive(Clone, Copy)]
pub struct ChannelRequant<'p, B: I32s + ?Sized, M: I32s + ?Sized> {
    /// Bias in accumulator units.
    pub bias: &'p B,
    /// Fixed-point multipliers.
    pub mult: &'p M,
    /// Right shifts (validated `1..=62` when the weights are loaded).
    pub shift: &'p [u8],
}

impl<B: I32s + ?Sized, M: I32s + ?Sized> ChannelRequant<'_, B, M> {
    /// Output channels.
    pub fn channels(&self) -> usize {
        self.shift.len()
    }

    /// Channel `c` of an accumulator, rescaled (not yet saturated).
    #[inline(always)]
    pub fn apply(&self, c: usize, acc: i32) -> i64 {
        let shift = self.shift.get(c).copied().unwrap_or(1) as u32;
        let r = Requant {
            mult: self.mult.at(c),
            shift,
        };
        r.apply_i64(acc as i64 + self.bias.at(c) as i64)
    }
}

/// Rows of accumulators (`channels` per row) to int8: `out = sat(rq(acc) + zero[c])`.
pub fn requant_rows<B: I32s + ?Sized, M: I32s + ?Sized, Z: I32s + ?Sized>(
    acc: &[i32],
    rq: &ChannelRequant<'_, B, M>,
    zero: &Z,
    out: &mut [i8],
) {
    let n = rq.channels();
    if n == 0 {
        return;
    }
    for (acc_row, out_row) in acc.chunks_exact(n).zip(out.chunks_exact_mut(n)) {
        for (c, (&a, o)) in acc_row.iter().zip(out_row.iter_mut()).enumerate() {
            *o = sat_i8_i64(rq.apply(c, a) + zero.at(c) as i64);
        }
    }
}

/// The residual stream's per-channel int8 format: real value = scale[c] * (q - zero[c]).
/// The scales themselves never appear in the int8 path: only ratios between formats do.
#[derive(Clone, Copy)]
pub struct ChannelRescale<'p, Z: I32s + ?Sized, M: I32s + ?Sized> {
    /// Zero points of the input format.
    pub zero: &'p Z,
    /// Multipliers from the input format's scale to the output format's.
    pub mult: &'p M,
    /// Their shifts.
    pub shift: &'p [u8],
}

impl<Z: I32s + ?Sized, M: I32s + ?Sized> ChannelRescale<'_, Z, M> {
    #[inline(always)]
    fn apply(&self, c: usize, q: i8) -> i64 {
        let shift = self.shift.get(c).copied().unwrap_or(1) as u32;
        let r = Requant {
            mult: self.mult.at(c),
            shift,
        };
        r.apply_i64(q as i64 - self.zero.at(c) as i64)
    }
}

/// `x <- sat(carry(x) + delta(acc) + new_zero)`: adds a layer's output to the residual stream
/// while moving the stream to the next stage's per-channel format.
pub fn residual_add<Z, M, B, M2, Z2>(
    x: &mut [i8],
    carry: &ChannelRescale<'_, Z, M>,
    acc: &[i32],
    delta: &ChannelRequant<'_, B, M2>,
    new_zero: &Z2,
) where
    Z: I32s + ?Sized,
    M: I32s + ?Sized,
    B: I32s + ?Sized,
    M2: I32s + ?Sized,
    Z2: I32s + ?Sized,
{
    let n = delta.channels();
    if n == 0 {
        return;
    }
    for (x_row, acc_row) in x.chunks_exact_mut(n).zip(acc.chunks_exact(n)) {
        for (c, (xq, &a)) in x_row.iter_mut().zip(acc_row).enumerate() {
            let value = carry.apply(c, *xq) + delta.apply(c, a) + new_zero.at(c) as i64;
            *xq = sat_i8_i64(value);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::params::Uniform;
    use crate::testutil::{requant_of, Rng};

    fn factor(real: f64) -> (i32, u8) {
        let r = requant_of(real);
        (r.mult, r.shift as u8)
    }

    #[test]
    fn requant_rows_matches_float_within_half_lsb() {
        let mut rng = Rng::new(3);
        let scales = [0.0123, 0.5, 1.7e-3, 0.031];
        let mut mult = [0i32; 4];
        let mut shift = [0u8; 4];
        for (c, &s) in scales.iter().enumerate() {
            (mult[c], shift[c]) = factor(s);
        }
        let bias = [100, -2000, 0, 7];
        let rq = ChannelRequant {
            bias: &bias,
            mult: &mult,
            shift: &shift,
        };
        let mut acc = [0i32; 40];
        for a in acc.iter_mut() {
            *a = rng.range(-20_000, 20_000) as i32;
        }
        let mut out = [0i8; 40];
        requant_rows(&acc, &rq, &Uniform(-3), &mut out);
        for (i, (&a, &o)) in acc.iter().zip(&out).enumerate() {
            let c = i % 4;
            let want = ((a + bias[c]) as f64 * scales[c] - 3.0).clamp(-128.0, 127.0);
            assert!((o as f64 - want).abs() <= 0.5 + 1e-6, "{i}: {o} vs {want}");
        }
    }

    #[test]
    fn residual_add_changes_format_and_adds() {
        let (cm, cs) = factor(0.5);
        let (dm, ds) = factor(0.25);
        let carry = ChannelRescale {
            zero: &Uniform(10),
            mult: &[cm; 2],
            shift: &[cs; 2],
        };
        let delta = ChannelRequant {
            bias: &Uniform(4),
            mult: &[dm; 2],
            shift: &[ds; 2],
        };
        let mut x = [30i8, -10, 127, -128];
        let acc = [36, -4, 1000, -1000];
        residual_add(&mut x, &carry, &acc, &delta, &Uniform(-5));
        // (30-10)/2 + (36+4)/4 - 5 = 15; (-10-10)/2 + 0 - 5 = -15; saturated; saturated.
        assert_eq!(x, [15, -15, 127, -128]);
    }
}
