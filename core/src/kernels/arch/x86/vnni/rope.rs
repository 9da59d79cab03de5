//! RoPE of one token in AVX-512 lanes: `dispatch::rope::RopeLanes::token` (the requantisation
//! to Q8, then each half head's rotation) sixteen channels a vector, bit for bit. The portable
//! loop compiled for AVX-512 took about 11 % of a VNNI pass (64-bit products per channel).
//!
//! A half head is one vector: lanes 0-7 its `a` channels, lanes 8-15 their `b` partners. With
//! the halves swapped (`b | a`), cosines `c | c` and sines `-s | s`, one product sum per lane
//! gives `a c - b s` in the low lanes and `b c + a s` in the high ones: the rotation in place,
//! in the 32-bit split of `rotate_half_in_lanes` (`x = 2^12 (x >> 12) + (x & 0xFFF)`).

use core::arch::x86_64::{
    __m512i, _mm512_abs_epi32, _mm512_add_epi32, _mm512_and_si512, _mm512_cmpge_epu32_mask, _mm512_cvtepi16_epi32,
    _mm512_cvtepu8_epi32, _mm512_mask_blend_epi32, _mm512_mask_sub_epi32, _mm512_max_epi32, _mm512_min_epi32,
    _mm512_mul_epi32, _mm512_mullo_epi32, _mm512_packs_epi16, _mm512_packs_epi32, _mm512_permutexvar_epi32,
    _mm512_set1_epi32, _mm512_set_epi32, _mm512_setzero_si512, _mm512_shuffle_i64x2, _mm512_sllv_epi32,
    _mm512_srai_epi32, _mm512_srav_epi32, _mm512_srli_epi64,
};

use bytemuck::must_cast;

use super::available;
use crate::config::DIM;
use crate::kernels::types::rope::{Angles, QUARTER};

/// Channels a vector: one half head.
const LANES: usize = 16;
const _: () = assert!(2 * QUARTER == LANES && DIM.is_multiple_of(2 * LANES));

/// A query or key projection's requantisation in lanes (`RopeLanes`'s arrays): `bias`, `mult`,
/// `round` = `2^(s-33+e)`, the shifts `pre` = `e` and `post` = `s - 32 + e`.
pub struct RopeParams<'a> {
    /// Per-channel biases.
    pub bias: &'a [i32; DIM],
    /// Per-channel multipliers.
    pub mult: &'a [i32; DIM],
    /// Per-channel rounding terms.
    pub round: &'a [i32; DIM],
    /// Left shifts before the product (0 or 1).
    pub pre: &'a [u8; DIM],
    /// Right shifts after it.
    pub post: &'a [u8; DIM],
    /// Bound of the requantised values (`PRE_ROPE_LIMIT`).
    pub limit: i32,
}

/// `RopeLanes::token` of `acc` into `out` where the kernels run (`None` elsewhere): `Some(false)`
/// (nothing written) where an accumulator reaches `2^29` in magnitude.
pub fn token(p: &RopeParams<'_>, acc: &[i32; DIM], row: &Angles, col: &Angles, out: &mut [i8; DIM]) -> Option<bool> {
    if !available() {
        return None;
    }
    // SAFETY: `available()` saw AVX-512 F/BW/VL/VNNI on this CPU, enabled by the OS.
    #[allow(unsafe_code)]
    Some(unsafe { token_avx512(p, acc, row, col, out) })
}

#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
fn token_avx512(p: &RopeParams<'_>, acc: &[i32; DIM], row: &Angles, col: &Angles, out: &mut [i8; DIM]) -> bool {
    // Sixteen lanes a load, straight from the arrays (casting a whole array copied it to the
    // stack first).
    let lanes = |x: &[i32; LANES]| -> __m512i { must_cast(*x) };
    let shifts = |x: &[u8; LANES]| _mm512_cvtepu8_epi32(must_cast(*x));
    let (acc, _) = acc.as_chunks::<LANES>();
    let bound = _mm512_set1_epi32(1 << 29);
    if acc
        .iter()
        .any(|a| _mm512_cmpge_epu32_mask(_mm512_abs_epi32(lanes(a)), bound) != 0)
    {
        return false;
    }
    let (high_limit, low_limit) = (_mm512_set1_epi32(p.limit), _mm512_set1_epi32(-p.limit));
    let turns = [Turn::new(row), Turn::new(col)];
    let params = p
        .bias
        .as_chunks::<LANES>()
        .0
        .iter()
        .zip(p.mult.as_chunks::<LANES>().0)
        .zip(
            p.round
                .as_chunks::<LANES>()
                .0
                .iter()
                .zip(p.pre.as_chunks::<LANES>().0.iter().zip(p.post.as_chunks::<LANES>().0)),
        );
    let mut rotated = [_mm512_setzero_si512(); DIM / LANES];
    for (i, ((o, a), ((bias, mult), (round, (pre, post))))) in rotated.iter_mut().zip(acc).zip(params).enumerate() {
        // The requantisation: `((acc + bias) << e)` times `mult`, high word, rounded shift.
        let x = _mm512_sllv_epi32(_mm512_add_epi32(lanes(a), lanes(bias)), shifts(pre));
        let mult = lanes(mult);
        let even = _mm512_mul_epi32(x, mult);
        let odd = _mm512_mul_epi32(_mm512_srli_epi64::<32>(x), _mm512_srli_epi64::<32>(mult));
        let high = _mm512_mask_blend_epi32(0xAAAA, _mm512_srli_epi64::<32>(even), odd);
        let shifted = _mm512_srav_epi32(_mm512_add_epi32(high, lanes(round)), shifts(post));
        let v = _mm512_max_epi32(_mm512_min_epi32(shifted, high_limit), low_limit);
        // Half heads alternate: the row's angles, then the column's.
        *o = turns[i % 2].rotate(v);
    }
    // To bytes, saturated, four vectors at a time: two `vpackssdw` and a `vpacksswb`
    // interleave their 128-bit lanes, one `vpermd` restores the order (`vpmovsdb` to memory, a
    // vector at a time, was the loop's slowest instruction).
    let unlane = _mm512_set_epi32(15, 11, 7, 3, 14, 10, 6, 2, 13, 9, 5, 1, 12, 8, 4, 0);
    let (out, _) = out.as_chunks_mut::<{ 4 * LANES }>();
    for (o, r) in out.iter_mut().zip(rotated.chunks_exact(4)) {
        let (r01, r23) = (_mm512_packs_epi32(r[0], r[1]), _mm512_packs_epi32(r[2], r[3]));
        *o = must_cast(_mm512_permutexvar_epi32(unlane, _mm512_packs_epi16(r01, r23)));
    }
    true
}

/// One position's cosines and sines across a half head's lanes.
struct Turn {
    /// `c | c`.
    cos: __m512i,
    /// `-s | s`.
    sin: __m512i,
}

impl Turn {
    #[inline]
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
    fn new(angles: &Angles) -> Self {
        let widen = |x: [i16; QUARTER]| _mm512_cvtepi16_epi32(must_cast([x, x]));
        let sin = widen(angles.sin);
        Turn {
            cos: widen(angles.cos),
            sin: _mm512_mask_sub_epi32(sin, 0x00FF, _mm512_setzero_si512(), sin),
        }
    }

    // `(a c - b s + 2^21) >> 22 | (b c + a s + 2^21) >> 22` for `v = a | b` (`|a|, |b| <= 2^24`),
    // as `((h c + h' s) + ((l c + l' s + 2^21) >> 12)) >> 10` on the split halves.
    #[inline]
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
    fn rotate(&self, v: __m512i) -> __m512i {
        // `b | a`: the two 256-bit halves swapped.
        let swapped = _mm512_shuffle_i64x2::<0b01_00_11_10>(v, v);
        let low_bits = _mm512_set1_epi32(0xFFF);
        let (h, l) = (_mm512_srai_epi32::<12>(v), _mm512_and_si512(v, low_bits));
        let (hs, ls) = (_mm512_srai_epi32::<12>(swapped), _mm512_and_si512(swapped, low_bits));
        let low = _mm512_add_epi32(
            _mm512_add_epi32(_mm512_mullo_epi32(l, self.cos), _mm512_mullo_epi32(ls, self.sin)),
            _mm512_set1_epi32(1 << 21),
        );
        let high = _mm512_add_epi32(_mm512_mullo_epi32(h, self.cos), _mm512_mullo_epi32(hs, self.sin));
        _mm512_srai_epi32::<10>(_mm512_add_epi32(high, _mm512_srai_epi32::<12>(low)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::arch::x86::tests::{check_rope_against_rope_token, check_rope_declines};

    // The kernel itself where the CPU has it (another test turns the switch off for a moment).
    fn on_this_cpu(p: &RopeParams<'_>, acc: &[i32; DIM], row: &Angles, col: &Angles, out: &mut [i8; DIM]) -> bool {
        // SAFETY: the callers checked `supported()`.
        #[allow(unsafe_code)]
        unsafe {
            token_avx512(p, acc, row, col, out)
        }
    }

    #[test]
    fn lanes_equal_the_portable_rotation_at_random_and_extreme_values() {
        // Elsewhere `token` declines (None): the portable loop runs (tested in dispatch::rope).
        if crate::kernels::arch::x86::vnni::supported() {
            check_rope_against_rope_token(on_this_cpu);
        }
    }

    #[test]
    fn accumulators_from_two_to_the_29_are_declined_untouched() {
        if crate::kernels::arch::x86::vnni::supported() {
            check_rope_declines(on_this_cpu);
        }
    }
}
