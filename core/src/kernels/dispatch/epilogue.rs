//! What follows a matrix multiply: bias and per-channel requantisation to int8 (the residual
//! add is `kernels::dispatch::residual`).

pub use super::residual::{residual_add, residual_add_prepared, residual_add_reference, PreparedResidual};
use crate::fixed::sat_i8_i64;
pub use crate::kernels::types::requant::{ChannelRequant, ChannelRescale};
use crate::kernels::types::requant::{ChunkParams, NarrowChunk, CHANNEL_CHUNK};
use crate::kernels::I32s;

/// Rows of accumulators (`channels` per row) to int8: `out = sat(rq(acc) + zero[c])`.
pub fn requant_rows<B: I32s + ?Sized, M: I32s + ?Sized, Z: I32s + ?Sized>(
    acc: &[i32],
    rq: &ChannelRequant<'_, B, M>,
    zero: &Z,
    out: &mut [i8],
) {
    crate::kernels::arch::vectorised(
        #[inline(always)]
        || {
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
                        let narrow = NarrowChunk::new(&params, &zeros[..len]);
                        for r in 0..rows {
                            let at = r * n + start..r * n + start + len;
                            let (Some(acc_part), Some(out_part)) = (acc.get(at.clone()), out.get_mut(at)) else {
                                break;
                            };
                            if narrow.as_ref().is_some_and(|nc| nc.row(acc_part, out_part)) {
                                continue;
                            }
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
        },
    )
}

impl NarrowChunk {
    /// `None` where a shift, bias or zero point is outside the identity's range (and on
    /// targets without the vector row).
    #[cfg_attr(not(target_arch = "x86_64"), allow(unused_variables))]
    fn new(p: &ChunkParams, zeros: &[i64]) -> Option<Self> {
        #[cfg(not(target_arch = "x86_64"))]
        return None;
        #[cfg(target_arch = "x86_64")]
        {
            let mut c = NarrowChunk {
                bias: p.bias,
                mult: p.mult,
                addend: [0; CHANNEL_CHUNK],
                s: [1; CHANNEL_CHUNK],
                len: zeros.len().min(CHANNEL_CHUNK),
            };
            // Branch-free, so that it runs in vector lanes: this is paid per token block.
            let mut in_range = true;
            for ((&shift, &zero), (addend, s)) in p.shift.iter().zip(zeros).zip(c.addend.iter_mut().zip(&mut c.s)) {
                let wide = (shift as i64).wrapping_sub(32);
                let ok_shift = (1..=30).contains(&wide);
                let e = wide.clamp(1, 30);
                let a = (1i64 << (e - 1)) + (zero << e);
                in_range &= ok_shift & (-(1i64 << 30)..1i64 << 30).contains(&a);
                (*addend, *s) = (a as i32, e as i32);
            }
            if !in_range {
                return None;
            }
            Some(c)
        }
    }

    /// One row of the chunk (`acc` and `out` of `len` values); `false` where an accumulator
    /// lies outside `-2^30..2^30` or the lengths differ (`out` is then to be recomputed).
    #[inline]
    fn row(&self, acc: &[i32], out: &mut [i8]) -> bool {
        #[cfg(target_arch = "x86_64")]
        return crate::kernels::arch::x86::avx2::requant_row_narrow(self, acc, out);
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = (acc, out);
            false
        }
    }
}

/// `out = sat8((hi32(rnd_hi32(n * recip_q) * mult) + round) >> post)` per lane: a rounded
/// high-half scale, then a requantisation whose shift is `32 + post` (LayerNorm's output and
/// attention's normalised average). Helium on Cortex-M55, a DSP loop on Cortex-M7 (even
/// lengths), portable scalar code elsewhere. `false` (nothing written) on Cortex-M55 unless `n` and `out` have one length
/// `>= 1` and `post` is in `1..=31`; elsewhere the common length is taken.
#[inline(always)]
pub(crate) fn scaled_requant_lanes(n: &[i32], recip_q: i32, mult: i32, round: i32, post: u32, out: &mut [i8]) -> bool {
    #[cfg(bino_mve)]
    return crate::kernels::arch::scaled_requant_lanes(n, recip_q, mult, round, post, out);
    #[cfg(bino_dsp)]
    if crate::kernels::arch::dsp::scaled_requant(n, recip_q, mult, round, post, out) {
        return true;
    }
    #[cfg(not(bino_mve))]
    {
        for (o, &y) in out.iter_mut().zip(n) {
            let z = ((y as i64 * recip_q as i64 + (1 << 31)) >> 32) as i32;
            let high = ((z as i64 * mult as i64) >> 32) as i32;
            *o = (high.wrapping_add(round) >> (post & 31)).clamp(-128, 127) as i8;
        }
        true
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
    fn requant_rows_in_32_bit_lanes_equal_the_per_channel_formula() {
        // Shifts 33..=62 (the quantiser's GEMM outputs): the 32-bit lanes where the host has
        // them, for accumulators at and around the lanes' bound of 2^30 and far beyond it.
        const N: usize = 141; // two full chunks and a tail that is not a multiple of 8
        let mut rng = Rng::new(21);
        let edges = [
            (1 << 30) - 1,
            1 << 30,
            -(1 << 30),
            -(1 << 30) - 1,
            i32::MAX,
            i32::MIN,
            0,
            -1,
        ];
        for trial in 0..8 {
            let mult: [i32; N] = core::array::from_fn(|_| rng.range(i32::MIN as i64, i32::MAX as i64) as i32);
            // Up to 2^20 x 128 in the addend: every chunk in range, except in the last trial,
            // whose larger shifts leave chunks to the 64-bit formula.
            let top = if trial == 7 { 63 } else { 53 };
            let shift: [u8; N] = core::array::from_fn(|_| rng.range(33, top) as u8);
            let bias: [i32; N] = core::array::from_fn(|_| rng.range(-(1 << 30) + 1, 1 << 30) as i32);
            let zero: [i32; N] = core::array::from_fn(|_| rng.range(-128, 128) as i32);
            let rq = ChannelRequant {
                bias: &bias,
                mult: &mult,
                shift: &shift,
            };
            #[cfg(target_arch = "x86_64")]
            if trial < 7 {
                let params = ChunkParams::decode(&rq, 0, CHANNEL_CHUNK).unwrap();
                let zeros: [i64; CHANNEL_CHUNK] = core::array::from_fn(|c| zero[c] as i64);
                assert!(
                    NarrowChunk::new(&params, &zeros).is_some(),
                    "trial {trial}: lanes not taken"
                );
            }
            let acc: [i32; 4 * N] = core::array::from_fn(|i| match (trial, i % 97) {
                (0..=3, _) => rng.range(-(1 << 24), 1 << 24) as i32,
                (_, 0..=7) => edges[i % 97],
                _ => rng.range(-(1 << 30), 1 << 30) as i32,
            });
            let mut out = [0i8; 4 * N];
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
}
