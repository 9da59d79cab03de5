//! 2D RoPE in fixed point on one token's query or key accumulators.
//!
//! Per head, the first half of the channels rotates by the token's row, the second half by its
//! patch column; within each half channel `i` pairs with `i + head_dim / 4` (rotate-half), as
//! in `train/bino_train/model.py`. Accumulators are first requantised to Q8 of the output
//! scale, rotated with Q14 cosines and sines, then rounded to int8.

use super::epilogue::ChannelRequant;
use crate::config::{DIM, HEAD_DIM};
use crate::fixed::{round_shift, sat_i8_i64};
use crate::kernels::types::rope::PRE_ROPE_LIMIT;
pub use crate::kernels::types::rope::{Angles, PRE_ROPE_FRAC_BITS, QUARTER, TRIG_FRAC_BITS};
use crate::kernels::I32s;

/// Requantises `acc` (all heads of one token, `heads * HEAD_DIM` channels; `rq` must give Q8 of
/// the output scale) and rotates each head by the row and column angles into `out`.
pub fn rope_token<B: I32s + ?Sized, M: I32s + ?Sized>(
    acc: &[i32],
    rq: &ChannelRequant<'_, B, M>,
    row: &Angles,
    col: &Angles,
    out: &mut [i8],
) {
    for (h, (acc_head, out_head)) in acc
        .chunks_exact(HEAD_DIM)
        .zip(out.chunks_exact_mut(HEAD_DIM))
        .enumerate()
    {
        let base = h * HEAD_DIM;
        let (acc_row, acc_col) = acc_head.split_at(HEAD_DIM / 2);
        let (out_row, out_col) = out_head.split_at_mut(HEAD_DIM / 2);
        rotate_half(acc_row, base, rq, row, out_row);
        rotate_half(acc_col, base + HEAD_DIM / 2, rq, col, out_col);
    }
}

fn rotate_half<B: I32s + ?Sized, M: I32s + ?Sized>(
    acc: &[i32],
    base: usize,
    rq: &ChannelRequant<'_, B, M>,
    angles: &Angles,
    out: &mut [i8],
) {
    let (acc_a, acc_b) = acc.split_at(QUARTER);
    let (out_a, out_b) = out.split_at_mut(QUARTER);
    let shift = TRIG_FRAC_BITS + PRE_ROPE_FRAC_BITS;
    for i in 0..QUARTER {
        let (Some(&xa), Some(&xb)) = (acc_a.get(i), acc_b.get(i)) else {
            return;
        };
        let a = rq.apply(base + i, xa).clamp(-PRE_ROPE_LIMIT, PRE_ROPE_LIMIT);
        let b = rq.apply(base + QUARTER + i, xb).clamp(-PRE_ROPE_LIMIT, PRE_ROPE_LIMIT);
        let (c, s) = (angles.cos[i] as i64, angles.sin[i] as i64);
        if let (Some(oa), Some(ob)) = (out_a.get_mut(i), out_b.get_mut(i)) {
            *oa = sat_i8_i64(round_shift(a * c - b * s, shift));
            *ob = sat_i8_i64(round_shift(b * c + a * s, shift));
        }
    }
}

/// A query or key projection's per-channel requantisation prepared once per pass for
/// [`RopeLanes::token`]: [`rope_token`] in 32-bit lanes, bit for bit.
///
/// The requantisation `((acc + bias) mult + 2^(s-1)) >> s` is
/// `(hi32(((acc + bias) << e) mult) + 2^(s-33+e)) >> (s - 32 + e)` with `e = 1` for `s = 32`
/// and 0 above (the low word cannot carry past a multiple of the divisor); `acc + bias` and its
/// double stay in 32 bits for `|acc|, |bias| < 2^29` (checked). The rotation's
/// `(a c - b s + 2^21) >> 22` splits `a = 2^12 a_h + a_l` (`0 <= a_l < 2^12`, same for `b`):
/// `a c - b s = 2^12 (a_h c - b_h s) + (a_l c - b_l s)`, both parts below `2^28` for
/// `|a|, |b| <= 2^24` and any i16 cosine and sine, and the rounded shift is
/// `((a_h c - b_h s) + ((a_l c - b_l s + 2^21) >> 12)) >> 10`.
pub struct RopeLanes {
    bias: [i32; DIM],
    mult: [i32; DIM],
    /// `2^(s-33+e)`.
    round: [i32; DIM],
    /// `e`, the left shift before the product.
    pre: [u8; DIM],
    /// `s - 32 + e`, the right shift after it.
    post: [u8; DIM],
    /// The requantised token, reused token after token (zeroing it per token cost a 512-byte
    /// `memclr` each).
    values: [i32; DIM],
}

impl RopeLanes {
    /// The lanes of a `DIM`-channel requantisation, or `None` where the identities do not
    /// hold (shifts below 32, biases from `2^29`): [`rope_token`] then.
    pub fn new<B: I32s + ?Sized, M: I32s + ?Sized>(rq: &ChannelRequant<'_, B, M>) -> Option<Self> {
        if rq.channels() != DIM {
            return None;
        }
        let mut lanes = RopeLanes {
            bias: [0; DIM],
            mult: [0; DIM],
            round: [0; DIM],
            pre: [0; DIM],
            post: [1; DIM],
            values: [0; DIM],
        };
        for c in 0..DIM {
            let (bias, shift) = (rq.bias.at(c), rq.shift.get(c).copied().unwrap_or(0) as u32);
            if !(32..=62).contains(&shift) || bias.unsigned_abs() >= 1 << 29 {
                return None;
            }
            let pre = (shift == 32) as u32;
            lanes.bias[c] = bias;
            lanes.mult[c] = rq.mult.at(c);
            lanes.round[c] = 1 << (shift + pre - 33);
            lanes.pre[c] = pre as u8;
            lanes.post[c] = (shift + pre - 32) as u8;
        }
        Some(lanes)
    }

    /// [`rope_token`] of one token's `DIM` accumulators; `false` (nothing written) for
    /// accumulators from `2^29` in magnitude or slices of another length.
    pub fn token(&mut self, acc: &[i32], row: &Angles, col: &Angles, out: &mut [i8]) -> bool {
        // AVX-512 lanes where the VNNI kernels run (`kernels::arch::x86::vnni::rope`), else AVX2.
        #[cfg(target_arch = "x86_64")]
        if let (Some(acc), Some(out)) = (acc.first_chunk::<DIM>(), out.first_chunk_mut::<DIM>()) {
            let params = crate::kernels::arch::x86::vnni::rope::RopeParams {
                bias: &self.bias,
                mult: &self.mult,
                round: &self.round,
                pre: &self.pre,
                post: &self.post,
                limit: PRE_ROPE_LIMIT as i32,
            };
            let done = crate::kernels::arch::x86::vnni::rope::token(&params, acc, row, col, out)
                .or_else(|| crate::kernels::arch::x86::avx2::rope::token(&params, acc, row, col, out));
            if let Some(done) = done {
                return done;
            }
        }
        crate::kernels::arch::vectorised(
            #[inline(always)]
            || {
                let (Some(acc), Some(out)) = (acc.first_chunk::<DIM>(), out.first_chunk_mut::<DIM>()) else {
                    return false;
                };
                #[cfg(bino_dsp)]
                if self.token_on_m7(acc, row, col, out) {
                    return true;
                }
                if acc.iter().fold(0u32, |m, &a| m.max(a.unsigned_abs())) >= 1 << 29 {
                    return false;
                }
                let limit = PRE_ROPE_LIMIT as i32;
                let RopeLanes {
                    bias,
                    mult,
                    round,
                    pre,
                    post,
                    values: v,
                } = self;
                // Helium lanes on Cortex-M55 (`kernels::arch`), this loop elsewhere.
                #[cfg(bino_mve)]
                let done = crate::kernels::arch::mve::rope_requant(acc, bias, mult, round, pre, post, limit, v);
                #[cfg(not(bino_mve))]
                let done = false;
                if !done {
                    for c in 0..DIM {
                        let x = (acc[c] + bias[c]) << (pre[c] & 1);
                        let high = ((x as i64 * mult[c] as i64) >> 32) as i32;
                        v[c] = ((high + round[c]) >> (post[c] & 31)).clamp(-limit, limit);
                    }
                }
                for (v_head, out_head) in v.chunks_exact(HEAD_DIM).zip(out.chunks_exact_mut(HEAD_DIM)) {
                    let (v_row, v_col) = v_head.split_at(HEAD_DIM / 2);
                    let (out_row, out_col) = out_head.split_at_mut(HEAD_DIM / 2);
                    rotate_half_lanes(v_row, row, out_row);
                    rotate_half_lanes(v_col, col, out_col);
                }
                true
            },
        )
    }
}

impl RopeLanes {
    /// [`RopeLanes::token`] in the Cortex-M7's assembly (`kernels::arch::dsp`): the
    /// requantisation, then the eight half heads' rotations; `false` (nothing written) where
    /// an accumulator passes `2^29` in magnitude.
    #[cfg(bino_dsp)]
    fn token_on_m7(&mut self, acc: &[i32; DIM], row: &Angles, col: &Angles, out: &mut [i8; DIM]) -> bool {
        use crate::kernels::arch::dsp::{rope_requant, rope_rotate_half};
        let bits = rope_requant(
            acc,
            &self.bias,
            &self.mult,
            &self.round,
            &self.pre,
            &self.post,
            &mut self.values,
        );
        if bits >= 1 << 29 {
            return false;
        }
        for (half, (v, o)) in self.values.chunks_exact(16).zip(out.chunks_exact_mut(16)).enumerate() {
            if let (Ok(v), Ok(o)) = (<&[i32; 16]>::try_from(v), <&mut [i8; 16]>::try_from(o)) {
                rope_rotate_half(v, if half % 2 == 0 { row } else { col }, o);
            }
        }
        true
    }
}

/// One half of a head rotated: `(a c - b s + 2^21) >> 22` and `(b c + a s + 2^21) >> 22`,
/// saturated. With a Helium unit in the 32-bit lanes of [`rotate_half_in_lanes`]; elsewhere in
/// 64-bit products, one multiply-accumulate each on Cortex-M7 (`smlal`), which that function
/// equals because `a = 2^12 (a >> 12) + (a & 0xFFF)` and nested floors of powers of two are
/// one floor.
#[inline(always)]
fn rotate_half_lanes(v: &[i32], angles: &Angles, out: &mut [i8]) {
    // Helium lanes on Cortex-M55 (`kernels::arch`; the same as `rotate_half_in_lanes`).
    #[cfg(bino_mve)]
    match (
        v.first_chunk::<{ 2 * QUARTER }>(),
        out.first_chunk_mut::<{ 2 * QUARTER }>(),
    ) {
        (Some(v), Some(out)) => crate::kernels::arch::mve::rope_rotate_half(v, &angles.cos, &angles.sin, out),
        _ => rotate_half_in_lanes(v, angles, out),
    }
    #[cfg(not(bino_mve))]
    {
        let (Some(va), Some(vb)) = (
            v.first_chunk::<QUARTER>(),
            v.get(QUARTER..).and_then(|b| b.first_chunk::<QUARTER>()),
        ) else {
            return;
        };
        let Some(out) = out.first_chunk_mut::<{ 2 * QUARTER }>() else {
            return;
        };
        let (out_a, out_b) = out.split_at_mut(QUARTER);
        for i in 0..QUARTER {
            let (a, b) = (va[i] as i64, vb[i] as i64);
            let (c, s) = (angles.cos[i] as i64, angles.sin[i] as i64);
            let half = 1 << 21;
            out_a[i] = ((a * c - b * s + half) >> 22).clamp(-128, 127) as i8;
            out_b[i] = ((b * c + a * s + half) >> 22).clamp(-128, 127) as i8;
        }
    }
}

/// [`rotate_half_lanes`] in 32-bit lanes: the operands split at bit 12 so that no product
/// needs more than 32 bits.
#[cfg_attr(not(any(bino_mve, test)), allow(dead_code))]
#[inline(always)]
fn rotate_half_in_lanes(v: &[i32], angles: &Angles, out: &mut [i8]) {
    let (Some(va), Some(vb)) = (
        v.first_chunk::<QUARTER>(),
        v.get(QUARTER..).and_then(|b| b.first_chunk::<QUARTER>()),
    ) else {
        return;
    };
    let (out_a, out_b) = out.split_at_mut(QUARTER.min(out.len()));
    let mut ra = [0i8; QUARTER];
    let mut rb = [0i8; QUARTER];
    for i in 0..QUARTER {
        let (a, b) = (va[i], vb[i]);
        let (c, s) = (angles.cos[i] as i32, angles.sin[i] as i32);
        let (a_h, a_l, b_h, b_l) = (a >> 12, a & 0xFFF, b >> 12, b & 0xFFF);
        let half = 1 << 21;
        let oa = ((a_h * c - b_h * s) + ((a_l * c - b_l * s + half) >> 12)) >> 10;
        let ob = ((b_h * c + a_h * s) + ((b_l * c + a_l * s + half) >> 12)) >> 10;
        ra[i] = oa.clamp(-128, 127) as i8;
        rb[i] = ob.clamp(-128, 127) as i8;
    }
    for (o, r) in out_a.iter_mut().zip(ra) {
        *o = r;
    }
    for (o, r) in out_b.iter_mut().zip(rb) {
        *o = r;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::params::Uniform;
    use crate::testutil::Rng;

    #[test]
    fn split_lanes_rotate_as_the_64_bit_products() {
        let mut rng = Rng::new(92);
        let limit = PRE_ROPE_LIMIT;
        for trial in 0..4000 {
            let v: [i32; 2 * QUARTER] = core::array::from_fn(|i| match (trial + i) % 5 {
                0 => limit as i32,
                1 => -limit as i32,
                _ => rng.range(-limit, limit) as i32,
            });
            let angles = Angles {
                cos: core::array::from_fn(|_| rng.range(i16::MIN as i64, i16::MAX as i64) as i16),
                sin: core::array::from_fn(|_| rng.range(i16::MIN as i64, i16::MAX as i64) as i16),
            };
            let (mut lanes, mut wide) = ([0i8; 2 * QUARTER], [0i8; 2 * QUARTER]);
            rotate_half_in_lanes(&v, &angles, &mut lanes);
            for i in 0..QUARTER {
                let (a, b) = (v[i] as i64, v[QUARTER + i] as i64);
                let (c, s) = (angles.cos[i] as i64, angles.sin[i] as i64);
                wide[i] = ((a * c - b * s + (1 << 21)) >> 22).clamp(-128, 127) as i8;
                wide[QUARTER + i] = ((b * c + a * s + (1 << 21)) >> 22).clamp(-128, 127) as i8;
            }
            assert_eq!(lanes, wide, "trial {trial}");
        }
    }

    #[test]
    fn lanes_equal_rope_token() {
        let mut rng = Rng::new(91);
        let mut taken = 0;
        for trial in 0..200 {
            let shifts: [u8; DIM] = core::array::from_fn(|_| rng.range(if trial % 9 == 8 { 20 } else { 32 }, 62) as u8);
            let mult: [i32; DIM] = core::array::from_fn(|_| rng.range(-(i32::MAX as i64), i32::MAX as i64) as i32);
            let bias: [i32; DIM] = core::array::from_fn(|_| rng.range(-(1 << 29) + 1, (1 << 29) - 1) as i32);
            let rq = ChannelRequant {
                bias: &bias,
                mult: &mult,
                shift: &shifts,
            };
            let angles = |rng: &mut Rng| Angles {
                cos: core::array::from_fn(|_| rng.range(i16::MIN as i64, i16::MAX as i64) as i16),
                sin: core::array::from_fn(|_| rng.range(i16::MIN as i64, i16::MAX as i64) as i16),
            };
            let (row, col) = (angles(&mut rng), angles(&mut rng));
            let acc: [i32; DIM] = core::array::from_fn(|_| match trial % 4 {
                0 => rng.range(-(1 << 29) + 1, (1 << 29) - 1) as i32,
                1 => rng.range(-(1 << 21), 1 << 21) as i32,
                2 => rng.range(-300, 300) as i32,
                _ => rng.range(i32::MIN as i64, i32::MAX as i64) as i32,
            });
            let mut want = [0i8; DIM];
            rope_token(&acc, &rq, &row, &col, &mut want);
            match RopeLanes::new(&rq) {
                Some(mut lanes) => {
                    let mut got = [0i8; DIM];
                    if lanes.token(&acc, &row, &col, &mut got) {
                        assert_eq!(got, want, "trial {trial}");
                        taken += 1;
                    } else {
                        assert_eq!(trial % 4, 3, "trial {trial}: declined small accumulators");
                    }
                }
                None => assert_eq!(trial % 9, 8, "trial {trial}: declined ordinary shifts"),
            }
        }
        assert!(taken >= 100, "{taken}");
    }

    #[test]
    fn rotates_pairs_like_the_float_model() {
        // Angles 0 and 90 degrees alternate; rq is x * 256 (acc already in output units).
        let mut row = Angles::default();
        let mut col = Angles::default();
        for i in 0..QUARTER {
            row.cos[i] = if i % 2 == 0 { 1 << 14 } else { 0 };
            row.sin[i] = if i % 2 == 0 { 0 } else { 1 << 14 };
            col.cos[i] = 11585; // 45 degrees
            col.sin[i] = 11585;
        }
        let shifts = [1u8; HEAD_DIM];
        let rq = ChannelRequant {
            bias: &Uniform(0),
            mult: &Uniform(512),
            shift: &shifts,
        };
        let mut rng = Rng::new(5);
        let mut acc = [0i32; HEAD_DIM];
        for a in acc.iter_mut() {
            *a = rng.range(-80, 80) as i32;
        }
        let mut out = [0i8; HEAD_DIM];
        rope_token(&acc, &rq, &row, &col, &mut out);
        let q = QUARTER;
        for i in 0..q {
            let (a, b) = (acc[i], acc[q + i]);
            let (ra, rb) = if i % 2 == 0 { (a, b) } else { (-b, a) };
            assert_eq!((out[i] as i32, out[q + i] as i32), (ra, rb), "row pair {i}");
            let (a, b) = (acc[2 * q + i] as f64, acc[3 * q + i] as f64);
            let h = core::f64::consts::FRAC_1_SQRT_2;
            assert!((out[2 * q + i] as f64 - (a * h - b * h)).abs() <= 0.51, "col pair {i}");
            assert!((out[3 * q + i] as f64 - (b * h + a * h)).abs() <= 0.51, "col pair {i}");
        }
    }
}
