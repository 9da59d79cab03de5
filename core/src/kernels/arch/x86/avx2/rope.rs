//! RoPE of one token in AVX2 lanes, for hosts without AVX-512: `vnni::rope`'s requantisation
//! eight channels a vector, and each half head's rotation on its `a` and `b` vectors in the
//! 32-bit split of `rotate_half_in_lanes` (`x = 2^12 (x >> 12) + (x & 0xFFF)`). Bit for bit
//! `RopeLanes::token`.

use bytemuck::must_cast;
use core::arch::x86_64::{
    __m256i, _mm256_abs_epi32, _mm256_add_epi32, _mm256_and_si256, _mm256_blend_epi32, _mm256_cmpgt_epi32,
    _mm256_cvtepi16_epi32, _mm256_cvtepu8_epi32, _mm256_max_epi32, _mm256_min_epi32, _mm256_movemask_epi8,
    _mm256_mul_epi32, _mm256_mullo_epi32, _mm256_or_si256, _mm256_packs_epi16, _mm256_packs_epi32,
    _mm256_permutevar8x32_epi32, _mm256_set1_epi32, _mm256_setr_epi32, _mm256_setzero_si256, _mm256_shuffle_epi32,
    _mm256_sllv_epi32, _mm256_srai_epi32, _mm256_srav_epi32, _mm256_srli_epi64, _mm256_sub_epi32, _mm_cvtsi64_si128,
};

use crate::config::DIM;
use crate::kernels::arch::x86::vnni::rope::RopeParams;
use crate::kernels::types::rope::{Angles, QUARTER};

/// Channels a vector: one half of a half head (`a` or `b`).
const LANES: usize = 8;
const _: () = assert!(QUARTER == LANES && DIM.is_multiple_of(4 * LANES));

/// `vnni::rope::token` for CPUs with AVX2: the same contract.
pub fn token(p: &RopeParams<'_>, acc: &[i32; DIM], row: &Angles, col: &Angles, out: &mut [i8; DIM]) -> Option<bool> {
    if !crate::kernels::arch::x86::avx2() {
        return None;
    }
    // SAFETY: `avx2()` saw AVX2 on this CPU. The kernel reads and writes through safe slices.
    #[allow(unsafe_code)]
    Some(unsafe { token_avx2(p, acc, row, col, out) })
}

#[target_feature(enable = "avx2")]
fn token_avx2(p: &RopeParams<'_>, acc: &[i32; DIM], row: &Angles, col: &Angles, out: &mut [i8; DIM]) -> bool {
    let lanes = |x: &[i32; LANES]| -> __m256i { must_cast(*x) };
    let shifts = |x: &[u8; LANES]| _mm256_cvtepu8_epi32(_mm_cvtsi64_si128(i64::from_le_bytes(*x)));
    let (acc, _) = acc.as_chunks::<LANES>();
    // Every accumulator below 2^29 in magnitude (`i32::MIN`'s magnitude reads as negative).
    let (bound, zero) = (_mm256_set1_epi32((1 << 29) - 1), _mm256_setzero_si256());
    let outside = acc.iter().fold(zero, |m, a| {
        let magnitude = _mm256_abs_epi32(lanes(a));
        let bad = _mm256_or_si256(
            _mm256_cmpgt_epi32(magnitude, bound),
            _mm256_cmpgt_epi32(zero, magnitude),
        );
        _mm256_or_si256(m, bad)
    });
    if _mm256_movemask_epi8(outside) != 0 {
        return false;
    }
    let (high_limit, low_limit) = (_mm256_set1_epi32(p.limit), _mm256_set1_epi32(-p.limit));
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
    let mut v = [_mm256_setzero_si256(); DIM / LANES];
    for ((v, a), ((bias, mult), (round, (pre, post)))) in v.iter_mut().zip(acc).zip(params) {
        let x = _mm256_sllv_epi32(_mm256_add_epi32(lanes(a), lanes(bias)), shifts(pre));
        let mult = lanes(mult);
        let even = _mm256_srli_epi64::<32>(_mm256_mul_epi32(x, mult));
        let odd = _mm256_mul_epi32(_mm256_shuffle_epi32::<0xF5>(x), _mm256_shuffle_epi32::<0xF5>(mult));
        let high = _mm256_blend_epi32::<0b1010_1010>(even, odd);
        let shifted = _mm256_srav_epi32(_mm256_add_epi32(high, lanes(round)), shifts(post));
        *v = _mm256_max_epi32(_mm256_min_epi32(shifted, high_limit), low_limit);
    }
    // Half heads alternate: the row's angles, then the column's.
    let mut rotated = [_mm256_setzero_si256(); DIM / LANES];
    for (i, (r, ab)) in rotated.chunks_exact_mut(2).zip(v.chunks_exact(2)).enumerate() {
        if let ([ra, rb], [a, b]) = (r, ab) {
            (*ra, *rb) = turns[i % 2].rotate(*a, *b);
        }
    }
    // To bytes, saturated, four vectors at a time (the packs interleave 128-bit halves).
    let unlane = _mm256_setr_epi32(0, 4, 1, 5, 2, 6, 3, 7);
    let (out, _) = out.as_chunks_mut::<{ 4 * LANES }>();
    for (o, r) in out.iter_mut().zip(rotated.chunks_exact(4)) {
        let words = (_mm256_packs_epi32(r[0], r[1]), _mm256_packs_epi32(r[2], r[3]));
        *o = must_cast(_mm256_permutevar8x32_epi32(
            _mm256_packs_epi16(words.0, words.1),
            unlane,
        ));
    }
    true
}

/// One position's cosines and sines in lanes.
struct Turn {
    cos: __m256i,
    sin: __m256i,
}

impl Turn {
    #[inline]
    #[target_feature(enable = "avx2")]
    fn new(angles: &Angles) -> Self {
        Turn {
            cos: _mm256_cvtepi16_epi32(must_cast(angles.cos)),
            sin: _mm256_cvtepi16_epi32(must_cast(angles.sin)),
        }
    }

    // `((a c - b s + 2^21) >> 22, (b c + a s + 2^21) >> 22)` for `|a|, |b| <= 2^24`, as
    // `((h c - h' s) + ((l c - l' s + 2^21) >> 12)) >> 10` on the halves split at bit 12.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn rotate(&self, a: __m256i, b: __m256i) -> (__m256i, __m256i) {
        let low_bits = _mm256_set1_epi32(0xFFF);
        let half = _mm256_set1_epi32(1 << 21);
        let (ah, al) = (_mm256_srai_epi32::<12>(a), _mm256_and_si256(a, low_bits));
        let (bh, bl) = (_mm256_srai_epi32::<12>(b), _mm256_and_si256(b, low_bits));
        let (c, s) = (self.cos, self.sin);
        let low_a = _mm256_add_epi32(
            _mm256_sub_epi32(_mm256_mullo_epi32(al, c), _mm256_mullo_epi32(bl, s)),
            half,
        );
        let low_b = _mm256_add_epi32(
            _mm256_add_epi32(_mm256_mullo_epi32(bl, c), _mm256_mullo_epi32(al, s)),
            half,
        );
        let high_a = _mm256_sub_epi32(_mm256_mullo_epi32(ah, c), _mm256_mullo_epi32(bh, s));
        let high_b = _mm256_add_epi32(_mm256_mullo_epi32(bh, c), _mm256_mullo_epi32(ah, s));
        (
            _mm256_srai_epi32::<10>(_mm256_add_epi32(high_a, _mm256_srai_epi32::<12>(low_a))),
            _mm256_srai_epi32::<10>(_mm256_add_epi32(high_b, _mm256_srai_epi32::<12>(low_b))),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::arch::x86::tests::{check_rope_against_rope_token, check_rope_declines};

    fn on_this_cpu(p: &RopeParams<'_>, acc: &[i32; DIM], row: &Angles, col: &Angles, out: &mut [i8; DIM]) -> bool {
        token(p, acc, row, col, out).expect("AVX2 on this CPU")
    }

    #[test]
    fn lanes_equal_the_portable_rotation_and_decline_large_accumulators() {
        if crate::kernels::arch::x86::avx2() {
            check_rope_against_rope_token(on_this_cpu);
            check_rope_declines(on_this_cpu);
        }
    }
}
