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
    let rows = acc.len().min(out.len()) / n;
    let mut start = 0;
    while start < n {
        let len = (n - start).min(CHANNEL_CHUNK);
        match ChunkParams::decode(rq, start, len) {
            Some(params) => {
                let mut zeros = [0i64; CHANNEL_CHUNK];
                for (c, z) in zeros[..len].iter_mut().enumerate() {
                    *z = zero.at(start + c) as i64;
                }
                for r in 0..rows {
                    let at = r * n + start..r * n + start + len;
                    let (Some(acc_part), Some(out_part)) = (acc.get(at.clone()), out.get_mut(at)) else {
                        break;
                    };
                    for (i, (&a, o)) in acc_part.iter().zip(out_part.iter_mut()).enumerate() {
                        *o = sat_i8_i64(params.apply(i, a) + zeros[i]);
                    }
                }
            }
            None => {
                for r in 0..rows {
                    for c in start..start + len {
                        let i = r * n + c;
                        if let (Some(&a), Some(o)) = (acc.get(i), out.get_mut(i)) {
                            *o = sat_i8_i64(rq.apply(c, a) + zero.at(c) as i64);
                        }
                    }
                }
            }
        }
        start += len;
    }
}

/// Channels whose requantisation parameters are decoded at once (1 KiB of stack).
const CHANNEL_CHUNK: usize = 64;

/// One chunk of [`ChannelRequant`] decoded into plain arrays, for formats in which the exact
/// arithmetic needs no saturation: `|bias| < 2^30` and shifts in `1..=62` make
/// `|(acc + bias) * mult| < 1.5 * 2^62`, so adding the rounding half cannot overflow and the
/// result equals [`ChannelRequant::apply`] bit for bit. The quantiser only makes such formats.
struct ChunkParams {
    bias: [i32; CHANNEL_CHUNK],
    mult: [i32; CHANNEL_CHUNK],
    shift: [u32; CHANNEL_CHUNK],
}

impl ChunkParams {
    fn decode<B: I32s + ?Sized, M: I32s + ?Sized>(
        rq: &ChannelRequant<'_, B, M>,
        start: usize,
        len: usize,
    ) -> Option<Self> {
        let mut p = ChunkParams {
            bias: [0; CHANNEL_CHUNK],
            mult: [0; CHANNEL_CHUNK],
            shift: [1; CHANNEL_CHUNK],
        };
        for i in 0..len.min(CHANNEL_CHUNK) {
            let c = start + i;
            let (bias, shift) = (rq.bias.at(c), rq.shift.get(c).copied().unwrap_or(1) as u32);
            if bias.unsigned_abs() >= 1 << 30 || !(1..=62).contains(&shift) {
                return None;
            }
            (p.bias[i], p.mult[i], p.shift[i]) = (bias, rq.mult.at(c), shift);
        }
        Some(p)
    }

    /// [`ChannelRequant::apply`] for channel `start + i`, without saturation (see the type).
    #[inline(always)]
    fn apply(&self, i: usize, acc: i32) -> i64 {
        let i = i % CHANNEL_CHUNK;
        let product = (acc as i64 + self.bias[i] as i64).wrapping_mul(self.mult[i] as i64);
        let shift = self.shift[i] & 63;
        product.wrapping_add(1i64 << ((shift.wrapping_sub(1)) & 63)) >> shift
    }
}

/// The residual stream's per-channel int8 format: real value = `scale[c] * (q - zero[c])`.
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
    let rows = x.len().min(acc.len()) / n;
    let mut start = 0;
    while start < n {
        let len = (n - start).min(CHANNEL_CHUNK);
        match (
            ChunkParams::decode(delta, start, len),
            CarryParams::decode(carry, start, len),
        ) {
            (Some(d), Some(k)) => {
                let mut zeros = [0i64; CHANNEL_CHUNK];
                for (i, z) in zeros[..len].iter_mut().enumerate() {
                    *z = new_zero.at(start + i) as i64;
                }
                for r in 0..rows {
                    let at = r * n + start..r * n + start + len;
                    let (Some(x_part), Some(acc_part)) = (x.get_mut(at.clone()), acc.get(at)) else {
                        break;
                    };
                    for (i, (xq, &a)) in x_part.iter_mut().zip(acc_part).enumerate() {
                        *xq = sat_i8_i64(k.apply(i, *xq) + d.apply(i, a) + zeros[i % CHANNEL_CHUNK]);
                    }
                }
            }
            _ => {
                for r in 0..rows {
                    for c in start..start + len {
                        let i = r * n + c;
                        if let (Some(xq), Some(&a)) = (x.get_mut(i), acc.get(i)) {
                            let value = carry.apply(c, *xq) + delta.apply(c, a) + new_zero.at(c) as i64;
                            *xq = sat_i8_i64(value);
                        }
                    }
                }
            }
        }
        start += len;
    }
}

/// One chunk of a [`ChannelRescale`] decoded into plain arrays, for zero points within
/// `2^15` (quantiser-made formats: below `2^9`): `|q - zero| < 2^16` and `|mult| <= 2^31` keep
/// the product below `2^47`, so no saturation is reachable and plain arithmetic equals
/// [`ChannelRescale::apply`] bit for bit.
struct CarryParams {
    zero: [i32; CHANNEL_CHUNK],
    mult: [i32; CHANNEL_CHUNK],
    shift: [u32; CHANNEL_CHUNK],
}

impl CarryParams {
    fn decode<Z: I32s + ?Sized, M: I32s + ?Sized>(
        carry: &ChannelRescale<'_, Z, M>,
        start: usize,
        len: usize,
    ) -> Option<Self> {
        let mut p = CarryParams {
            zero: [0; CHANNEL_CHUNK],
            mult: [0; CHANNEL_CHUNK],
            shift: [1; CHANNEL_CHUNK],
        };
        for i in 0..len.min(CHANNEL_CHUNK) {
            let c = start + i;
            let (zero, shift) = (carry.zero.at(c), carry.shift.get(c).copied().unwrap_or(1) as u32);
            if zero.unsigned_abs() > 1 << 15 || !(1..=62).contains(&shift) {
                return None;
            }
            (p.zero[i], p.mult[i], p.shift[i]) = (zero, carry.mult.at(c), shift);
        }
        Some(p)
    }

    /// [`ChannelRescale::apply`] for channel `start + i`, without saturation (see the type).
    #[inline(always)]
    fn apply(&self, i: usize, q: i8) -> i64 {
        let i = i % CHANNEL_CHUNK;
        let product = (q as i32 - self.zero[i]) as i64 * self.mult[i] as i64;
        let shift = self.shift[i] & 63;
        (product + (1i64 << (shift.wrapping_sub(1) & 63))) >> shift
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
    fn requant_rows_equals_the_per_channel_formula_across_chunks() {
        const N: usize = 130; // two full chunks and a tail
        let mut rng = Rng::new(9);
        for trial in 0..6 {
            let mult: [i32; N] = core::array::from_fn(|_| rng.range(1 << 30, i32::MAX as i64) as i32);
            let shift: [u8; N] = core::array::from_fn(|_| rng.range(20, 45) as u8);
            let mut bias: [i32; N] = core::array::from_fn(|_| rng.range(-1 << 20, 1 << 20) as i32);
            if trial >= 3 {
                // A bias no quantiser makes: that chunk takes the saturating path.
                bias[70] = i32::MIN;
            }
            let zero: [i32; N] = core::array::from_fn(|_| rng.range(-128, 127) as i32);
            let rq = ChannelRequant {
                bias: &bias,
                mult: &mult,
                shift: &shift,
            };
            let acc: [i32; 3 * N] = core::array::from_fn(|_| {
                if trial % 3 == 2 {
                    rng.range(i32::MIN as i64, i32::MAX as i64) as i32
                } else {
                    rng.range(-1 << 24, 1 << 24) as i32
                }
            });
            let mut out = [0i8; 3 * N];
            requant_rows(&acc, &rq, &zero, &mut out);
            for (i, (&a, &o)) in acc.iter().zip(&out).enumerate() {
                let c = i % N;
                assert_eq!(
                    o,
                    sat_i8_i64(rq.apply(c, a) + zero[c] as i64),
                    "trial {trial} index {i}"
                );
            }
        }
    }

    #[test]
    fn residual_add_equals_the_per_channel_formula_across_chunks() {
        const N: usize = 130;
        let mut rng = Rng::new(13);
        for trial in 0..6 {
            let mult: [i32; N] = core::array::from_fn(|_| rng.range(1 << 30, i32::MAX as i64) as i32);
            let shift: [u8; N] = core::array::from_fn(|_| rng.range(20, 45) as u8);
            let cmult: [i32; N] = core::array::from_fn(|_| rng.range(1 << 30, i32::MAX as i64) as i32);
            let cshift: [u8; N] = core::array::from_fn(|_| rng.range(28, 34) as u8);
            let mut bias: [i32; N] = core::array::from_fn(|_| rng.range(-1 << 20, 1 << 20) as i32);
            let mut zero: [i32; N] = core::array::from_fn(|_| rng.range(-300, 300) as i32);
            if trial >= 3 {
                // Parameters no quantiser makes: those chunks take the saturating path.
                bias[70] = i32::MIN;
                zero[5] = i32::MAX;
            }
            let new_zero: [i32; N] = core::array::from_fn(|_| rng.range(-128, 127) as i32);
            let delta = ChannelRequant {
                bias: &bias,
                mult: &mult,
                shift: &shift,
            };
            let carry = ChannelRescale {
                zero: &zero,
                mult: &cmult,
                shift: &cshift,
            };
            let acc: [i32; 3 * N] = core::array::from_fn(|_| {
                if trial % 3 == 2 {
                    rng.range(i32::MIN as i64, i32::MAX as i64) as i32
                } else {
                    rng.range(-1 << 24, 1 << 24) as i32
                }
            });
            let mut x = [0i8; 3 * N];
            rng.fill_i8(&mut x);
            let before = x;
            residual_add(&mut x, &carry, &acc, &delta, &new_zero);
            for i in 0..3 * N {
                let c = i % N;
                let want = sat_i8_i64(carry.apply(c, before[i]) + delta.apply(c, acc[i]) + new_zero[c] as i64);
                assert_eq!(x[i], want, "trial {trial} index {i}");
            }
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
