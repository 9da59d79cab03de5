//! 2D RoPE in fixed point on one token's query or key accumulators.
//!
//! Per head, the first half of the channels rotates by the token's row, the second half by its
//! patch column; within each half channel `i` pairs with `i + head_dim / 4` (rotate-half), as
//! in `train/bino_train/model.py`. Accumulators are first requantised to Q8 of the output
//! scale, rotated with Q14 cosines and sines, then rounded to int8.

use super::epilogue::ChannelRequant;
use super::I32s;
use crate::config::HEAD_DIM;
use crate::fixed::{round_shift, sat_i8_i64};

/// Frequencies per half of a head: pairs `(i, i + QUARTER)`.
pub const QUARTER: usize = HEAD_DIM / 4;
/// Fraction bits of the cosine / sine tables.
pub const TRIG_FRAC_BITS: u32 = 14;
/// Extra fraction bits the accumulators keep through the rotation.
pub const PRE_ROPE_FRAC_BITS: u32 = 8;
/// Bound on pre-rotation values: keeps products far inside 64 bits whatever the parameters.
const PRE_ROPE_LIMIT: i64 = 1 << 24;

/// Cosines and sines (Q14) of one position's angles, one per frequency.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Angles {
    /// `round(cos(angle_i) * 2^14)`.
    pub cos: [i16; QUARTER],
    /// `round(sin(angle_i) * 2^14)`.
    pub sin: [i16; QUARTER],
}

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::params::Uniform;
    use crate::testutil::Rng;

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
