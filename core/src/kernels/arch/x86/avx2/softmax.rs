//! Attention's softmax row on AVX2: `reference::softmax::softmax_row` eight lanes a vector,
//! thirty-two scores a step. The AVX-512 row (`vnni`) with 256-bit vectors, and the cubic in
//! 32-bit lanes: AVX2 has no variable 16-bit shifts for the word cubic. LLVM vectorises the
//! portable row too, but it assembles the gap's high product word from 16-bit halves (four
//! multiplies where two `vpmuludq` do) and stores bytes one lane at a time.

use bytemuck::must_cast;
use core::arch::x86_64::{
    __m256i, _mm256_add_epi32, _mm256_add_epi64, _mm256_and_si256, _mm256_blend_epi32, _mm256_min_epu32,
    _mm256_mul_epu32, _mm256_mullo_epi32, _mm256_packus_epi16, _mm256_packus_epi32, _mm256_permutevar8x32_epi32,
    _mm256_sad_epu8, _mm256_set1_epi32, _mm256_set1_epi8, _mm256_setr_epi32, _mm256_setzero_si256, _mm256_sllv_epi32,
    _mm256_srli_epi32, _mm256_srli_epi64, _mm256_srlv_epi32, _mm256_sub_epi32, _mm256_xor_si256,
};

use crate::kernels::types::exp::{ExpQ32, C0, C1, C2, C3, EXP2_TABLE_LAST, EXP_Q32_MAX_GAP};

/// Scores per vector.
const LANES: usize = 8;
/// Scores per step: four vectors, packed to bytes together.
const STEP: usize = 4 * LANES;

/// One row's softmax weights `e.weight(max - s)`, stored as `w - 128`, and their sum, as
/// `reference::softmax::softmax_row` gives them, where the CPU has AVX2; `None` elsewhere.
pub fn softmax_row(e: &ExpQ32, max: i32, scores: &[i32], weights: &mut [u8]) -> Option<u32> {
    if !crate::kernels::arch::x86::avx2() {
        return None;
    }
    // SAFETY: `avx2()` saw AVX2 on this CPU (cpuid, and the OS saving the YMM registers). The
    // function itself only reads and writes through safe slices.
    #[allow(unsafe_code)]
    Some(unsafe { softmax_row_avx2(e, max, scores, weights) })
}

/// `ExpQ32::weight`'s constants for one row, broadcast once.
struct ExpLanes {
    row_max: __m256i,
    cap: __m256i,
    pre: __m256i,
    mult: __m256i,
    round: __m256i,
    post: __m256i,
    last: __m256i,
    low_byte: __m256i,
    half: __m256i,
    c: [__m256i; 4],
}

impl ExpLanes {
    #[inline]
    #[target_feature(enable = "avx2")]
    fn new(e: &ExpQ32, max: i32) -> Self {
        let (pre, round, post) = e.shifts();
        let v = |x: u32| _mm256_set1_epi32(x as i32);
        Self {
            row_max: _mm256_set1_epi32(max),
            cap: v(EXP_Q32_MAX_GAP),
            pre: v(pre),
            mult: v(e.mult()),
            round: v(round),
            post: v(post),
            last: v(EXP2_TABLE_LAST),
            low_byte: v(255),
            half: v(1 << 14),
            c: [v(C0), v(C1), v(C2), v(C3)],
        }
    }

    // `ExpQ32::weight` of eight scores: weights 0..=255 in 32-bit lanes.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn weights(&self, scores: &[i32]) -> __m256i {
        let s: __m256i = must_cast(<[i32; LANES]>::try_from(scores).unwrap_or([0; LANES]));
        self.cubic(self.exponent(s))
    }

    // The exponent (Q8 base 2, clamped at the table's last entry, where the cubic is 0): the
    // gap's high product word from two `vpmuludq` (even and odd lanes), the word the portable
    // code assembles from 16-bit halves.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn exponent(&self, s: __m256i) -> __m256i {
        let gap = _mm256_sub_epi32(self.row_max, s);
        let g = _mm256_sllv_epi32(_mm256_min_epu32(gap, self.cap), self.pre);
        let even = _mm256_mul_epu32(g, self.mult);
        let odd = _mm256_mul_epu32(_mm256_srli_epi64::<32>(g), self.mult);
        let high = _mm256_blend_epi32::<0b1010_1010>(_mm256_srli_epi64::<32>(even), odd);
        _mm256_min_epu32(
            _mm256_srlv_epi32(_mm256_add_epi32(high, self.round), self.post),
            self.last,
        )
    }

    // `exp2_neg_u8_q8(x)`: the cubic of the fraction, shifted by the whole part.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn cubic(&self, x: __m256i) -> __m256i {
        let [c0, c1, c2, c3] = self.c;
        let f = _mm256_and_si256(x, self.low_byte);
        let t = _mm256_srli_epi32::<8>(_mm256_mullo_epi32(c3, f));
        let t = _mm256_srli_epi32::<8>(_mm256_mullo_epi32(_mm256_sub_epi32(c2, t), f));
        let t = _mm256_srli_epi32::<8>(_mm256_mullo_epi32(_mm256_sub_epi32(c1, t), f));
        let scaled = _mm256_mullo_epi32(_mm256_sub_epi32(c0, t), self.low_byte);
        let shifted = _mm256_srlv_epi32(scaled, _mm256_srli_epi32::<8>(x));
        _mm256_srli_epi32::<15>(_mm256_add_epi32(shifted, self.half))
    }
}

// Thirty-two scores a step: four vectors of weights packed to bytes (two `vpackusdw`, one
// `vpackuswb`, one `vpermd` to undo the packs' 128-bit lanes), summed with one `vpsadbw`; the
// last `n % 32` by the portable row.
#[target_feature(enable = "avx2")]
fn softmax_row_avx2(e: &ExpQ32, max: i32, scores: &[i32], weights: &mut [u8]) -> u32 {
    let n = scores.len().min(weights.len());
    let lanes = ExpLanes::new(e, max);
    let flip = _mm256_set1_epi8(-128);
    let zero = _mm256_setzero_si256();
    // After the packs dword `l` of 128-bit lane `h` holds elements 4h..4h+3 of vector `l`.
    let unlane = _mm256_setr_epi32(0, 4, 1, 5, 2, 6, 3, 7);
    let mut byte_sums = zero;
    let whole = n / STEP * STEP;
    let (scores_whole, scores_tail) = scores.split_at(whole);
    let (weights_whole, weights_tail) = weights.split_at_mut(whole);
    for (w, s) in weights_whole
        .chunks_exact_mut(STEP)
        .zip(scores_whole.chunks_exact(STEP))
    {
        // Four plain calls: a closure would not inherit the target features.
        let (s01, s23) = s.split_at(2 * LANES);
        let (s0, s1) = s01.split_at(LANES);
        let (s2, s3) = s23.split_at(LANES);
        let (w0, w1, w2, w3) = (
            lanes.weights(s0),
            lanes.weights(s1),
            lanes.weights(s2),
            lanes.weights(s3),
        );
        // Weights <= 255 pack to words and bytes losslessly.
        let words = (_mm256_packus_epi32(w0, w1), _mm256_packus_epi32(w2, w3));
        let bytes = _mm256_permutevar8x32_epi32(_mm256_packus_epi16(words.0, words.1), unlane);
        byte_sums = _mm256_add_epi64(byte_sums, _mm256_sad_epu8(bytes, zero));
        let out: [u8; STEP] = must_cast(_mm256_xor_si256(bytes, flip));
        w.copy_from_slice(&out);
    }
    let tail = crate::kernels::reference::softmax::softmax_row(e, max, scores_tail, weights_tail);
    let sums: [u64; 4] = must_cast(byte_sums);
    (sums.iter().sum::<u64>() as u32).wrapping_add(tail)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixed::Requant;
    use crate::testutil::Rng;

    #[test]
    fn rows_equal_the_portable_row_for_every_length_and_gap() {
        let mut rng = Rng::new(41);
        let mut scores = [0i32; 131];
        for (case, (mult, shift)) in [
            (1 << 30, 30),
            (1_518_500_250, 33),
            (2_000_000_000, 40),
            (123_456_789, 22),
        ]
        .into_iter()
        .enumerate()
        {
            let e = ExpQ32::new(Requant { mult, shift }).expect("shift >= 22");
            for n in [0, 1, 31, 32, 33, 64, 96, 131] {
                // Gaps from 0 past the cap: close scores, spread ones, the largest int8 dot products.
                for (i, s) in scores.iter_mut().enumerate().take(n) {
                    *s = match (i + case) % 3 {
                        0 => rng.range(-2048, 2048) as i32,
                        1 => rng.range(-(1 << 20), 1 << 20) as i32,
                        _ => 32 * 128 * 128 * if i % 2 == 0 { 1 } else { -1 },
                    };
                }
                let max = scores[..n].iter().copied().max().unwrap_or(0);
                let (mut want, mut got) = ([0u8; 131], [0u8; 131]);
                let sum = crate::kernels::reference::softmax::softmax_row(&e, max, &scores[..n], &mut want[..n]);
                match softmax_row(&e, max, &scores[..n], &mut got[..n]) {
                    Some(got_sum) => {
                        assert_eq!(got_sum, sum, "case {case} n {n}");
                        assert_eq!(got[..n], want[..n], "case {case} n {n}");
                    }
                    None => assert!(!crate::kernels::arch::x86::avx2(), "declined on an AVX2 CPU"),
                }
            }
        }
    }

    #[test]
    fn the_cubic_equals_the_exp_table_for_every_exponent() {
        let Some(e) = ExpQ32::new(Requant {
            mult: 1 << 30,
            shift: 30,
        }) else {
            panic!("shift >= 22");
        };
        if !crate::kernels::arch::x86::avx2() {
            return; // the row never takes this path here
        }
        let exponents: [u32; 2312] = core::array::from_fn(|x| (x as u32).min(EXP2_TABLE_LAST));
        for chunk in exponents.chunks_exact(LANES) {
            let x: [u32; LANES] = chunk.try_into().expect("8 lanes");
            // SAFETY: `avx2()` saw AVX2 on this CPU.
            #[allow(unsafe_code)]
            let weights: [u32; LANES] = unsafe { must_cast(ExpLanes::new(&e, 0).cubic(must_cast(x))) };
            for (&x, &w) in x.iter().zip(&weights) {
                assert_eq!(
                    w,
                    u32::from(crate::kernels::types::exp::EXP2_NEG_U8_TABLE[x as usize]),
                    "x = {x}"
                );
            }
        }
    }
}
