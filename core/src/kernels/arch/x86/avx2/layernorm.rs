//! LayerNorm of up to eight token rows in AVX2 lanes, for hosts without AVX-512: the
//! `vnni::layernorm` kernel eight channels a vector (`NarrowParams::row_in_lanes`' passes), the
//! rows' integer square roots in two vectors of four 64-bit lanes. Bit for bit `row_in_lanes`;
//! a row it declines is left to the caller.

use bytemuck::must_cast;
use core::arch::x86_64::{
    __m256i, _mm256_add_epi32, _mm256_add_epi64, _mm256_andnot_si256, _mm256_blend_epi32, _mm256_blendv_epi8,
    _mm256_castsi256_si128, _mm256_cmpgt_epi64, _mm256_cvtepi32_epi64, _mm256_cvtepi8_epi32, _mm256_extracti128_si256,
    _mm256_max_epi32, _mm256_min_epi32, _mm256_mul_epi32, _mm256_mullo_epi32, _mm256_packs_epi16, _mm256_packs_epi32,
    _mm256_permutevar8x32_epi32, _mm256_set1_epi32, _mm256_set1_epi64x, _mm256_setr_epi32, _mm256_setzero_si256,
    _mm256_shuffle_epi32, _mm256_sll_epi32, _mm256_sra_epi32, _mm256_srli_epi64, _mm256_sub_epi32, _mm256_sub_epi64,
    _mm_cvtsi32_si128, _mm_cvtsi64_si128,
};

use crate::fixed::MAX_SHIFT;
use crate::kernels::arch::x86::vnni::layernorm::{NormLanes, DIM, ROWS};
use crate::kernels::reference::layernorm::{narrow_shift, reciprocal_of_root, variance_radicand, NarrowShift};

const LANES: usize = 8;
const STEPS: usize = DIM / LANES;

/// `vnni::layernorm::rows` for CPUs with AVX2: the same contract.
pub fn rows(p: &NormLanes<'_>, x: &[i8], out: &mut [i8]) -> Option<u8> {
    if !crate::kernels::arch::x86::avx2() || x.len() != out.len() || !x.len().is_multiple_of(DIM) {
        return None;
    }
    if x.len() > ROWS * DIM || !(33..=MAX_SHIFT).contains(&p.shift) {
        return None;
    }
    // SAFETY: `avx2()` saw AVX2 on this CPU. The kernel reads and writes through safe slices.
    #[allow(unsafe_code)]
    Some(unsafe { rows_avx2(p, x, out) })
}

/// The wrapping sum of four 64-bit lanes.
#[inline]
#[target_feature(enable = "avx2")]
fn sum64(v: __m256i) -> i64 {
    let lanes: [i64; 4] = must_cast(v);
    lanes.iter().fold(0i64, |a, &x| a.wrapping_add(x))
}

/// The odd 32-bit lanes moved down over the even ones (`vpmuldq` reads each quadword's low
/// dword; a 64-bit shift there made LLVM emit unsigned products plus fixups).
#[inline]
#[target_feature(enable = "avx2")]
fn odd_down(a: __m256i) -> __m256i {
    _mm256_shuffle_epi32::<0xF5>(a)
}

#[target_feature(enable = "avx2")]
fn rows_avx2(p: &NormLanes<'_>, x: &[i8], out: &mut [i8]) -> u8 {
    let (zero, _) = p.zero.as_chunks::<LANES>();
    let (rel, _) = p.rel.as_chunks::<LANES>();
    let mut normalised = [[_mm256_setzero_si256(); STEPS]; ROWS];
    let mut radicands = [0u64; ROWS];
    let mut left_rows = 0u8;
    let d = DIM as i64;
    for (r, (row, n)) in x.chunks_exact(DIM).zip(normalised.iter_mut()).enumerate() {
        let (codes, _) = row.as_chunks::<LANES>();
        let mut v = [_mm256_setzero_si256(); STEPS];
        let (mut sum, mut lo, mut hi) = (
            _mm256_setzero_si256(),
            _mm256_set1_epi32(i32::MAX),
            _mm256_set1_epi32(i32::MIN),
        );
        for (((v, q), z), rl) in v.iter_mut().zip(codes).zip(zero).zip(rel) {
            let q = _mm256_cvtepi8_epi32(_mm_cvtsi64_si128(i64::from_le_bytes(q.map(|c| c as u8))));
            *v = _mm256_mullo_epi32(_mm256_sub_epi32(q, must_cast(*z)), must_cast(*rl));
            let wide = _mm256_add_epi64(
                _mm256_cvtepi32_epi64(_mm256_castsi256_si128(*v)),
                _mm256_cvtepi32_epi64(_mm256_extracti128_si256::<1>(*v)),
            );
            sum = _mm256_add_epi64(sum, wide);
            (lo, hi) = (_mm256_min_epi32(lo, *v), _mm256_max_epi32(hi, *v));
        }
        let sum = sum64(sum);
        let lo = must_cast::<__m256i, [i32; LANES]>(lo)
            .into_iter()
            .fold(i32::MAX, i32::min);
        let hi = must_cast::<__m256i, [i32; LANES]>(hi)
            .into_iter()
            .fold(i32::MIN, i32::max);
        // `row_in_lanes`' shift cases.
        let Some(NarrowShift {
            shift,
            left,
            add,
            right,
        }) = narrow_shift(sum, lo, hi, d)
        else {
            left_rows |= 1 << r;
            continue;
        };
        let (left, right) = (_mm_cvtsi32_si128(left as i32), _mm_cvtsi32_si128(right as i32));
        let add = _mm256_set1_epi32(add);
        let mut squares = _mm256_setzero_si256();
        for (n, &v) in n.iter_mut().zip(&v) {
            *n = _mm256_sra_epi32(_mm256_add_epi32(_mm256_sll_epi32(v, left), add), right);
            let odd = odd_down(*n);
            let both = _mm256_add_epi64(_mm256_mul_epi32(*n, *n), _mm256_mul_epi32(odd, odd));
            squares = _mm256_add_epi64(squares, both);
        }
        radicands[r] = variance_radicand(sum64(squares) >> 7, p.eps, d, shift);
    }
    let (low, high) = radicands.split_at(4);
    let roots = [isqrt4(low), isqrt4(high)];
    let post = p.shift - 32;
    for (r, ((o, n), root)) in out
        .chunks_exact_mut(DIM)
        .zip(&normalised)
        .zip(roots.as_flattened())
        .enumerate()
    {
        let recip = reciprocal_of_root(*root).min(i32::MAX as i64);
        if left_rows & (1 << r) != 0 || recip >= 1 << 23 {
            left_rows |= 1 << r;
            continue;
        }
        if let Ok(o) = <&mut [i8; DIM]>::try_from(o) {
            output(n, (recip << 8) as i32, p.mult, 1 << (post - 1), post, o);
        }
    }
    left_rows
}

/// `isqrt_u64` of four values below 2^63 at once (`vnni::layernorm`'s steps; the values and
/// every trial stay below 2^63, so signed comparisons order them).
#[inline]
#[target_feature(enable = "avx2")]
fn isqrt4(n: &[u64]) -> [u32; 4] {
    let mut rem: __m256i = must_cast(<[u64; 4]>::try_from(n).unwrap_or([0; 4]));
    let mut root = _mm256_setzero_si256();
    let mut bit = _mm256_set1_epi64x(1 << 62);
    for _ in 0..32 {
        let trial = _mm256_add_epi64(root, bit);
        // All ones where the trial does not fit (`trial > rem`).
        let over = _mm256_cmpgt_epi64(trial, rem);
        rem = _mm256_blendv_epi8(_mm256_sub_epi64(rem, trial), rem, over);
        root = _mm256_add_epi64(_mm256_srli_epi64::<1>(root), _mm256_andnot_si256(over, bit));
        bit = _mm256_srli_epi64::<2>(bit);
    }
    must_cast::<__m256i, [u64; 4]>(root).map(|r| r as u32)
}

/// `scaled_requant_lanes` eight lanes a vector, four vectors' bytes packed together.
#[inline]
#[target_feature(enable = "avx2")]
fn output(n: &[__m256i; STEPS], recip_q: i32, mult: i32, round: i32, post: u32, out: &mut [i8; DIM]) {
    let (recip_q, mult, round) = (
        _mm256_set1_epi32(recip_q),
        _mm256_set1_epi32(mult),
        _mm256_set1_epi32(round),
    );
    let (half, post) = (_mm256_set1_epi64x(1 << 31), _mm_cvtsi32_si128(post as i32));
    // After the packs, 128-bit half `h` holds lanes 4h..4h+3 of each of the four vectors.
    let unlane = _mm256_setr_epi32(0, 4, 1, 5, 2, 6, 3, 7);
    let (out, _) = out.as_chunks_mut::<{ 4 * LANES }>();
    for (o, n4) in out.iter_mut().zip(n.chunks_exact(4)) {
        let mut v = [_mm256_setzero_si256(); 4];
        for (v, &y) in v.iter_mut().zip(n4) {
            let even = _mm256_srli_epi64::<32>(_mm256_add_epi64(_mm256_mul_epi32(y, recip_q), half));
            let odd = _mm256_add_epi64(_mm256_mul_epi32(odd_down(y), recip_q), half);
            let z = _mm256_blend_epi32::<0b1010_1010>(even, odd);
            let even = _mm256_srli_epi64::<32>(_mm256_mul_epi32(z, mult));
            let odd = _mm256_mul_epi32(odd_down(z), mult);
            let high = _mm256_blend_epi32::<0b1010_1010>(even, odd);
            *v = _mm256_sra_epi32(_mm256_add_epi32(high, round), post);
        }
        let words = (_mm256_packs_epi32(v[0], v[1]), _mm256_packs_epi32(v[2], v[3]));
        *o = must_cast(_mm256_permutevar8x32_epi32(
            _mm256_packs_epi16(words.0, words.1),
            unlane,
        ));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixed::isqrt_u64;
    use crate::testutil::Rng;

    #[test]
    fn four_roots_at_once_equal_the_scalar_root() {
        if !crate::kernels::arch::x86::avx2() {
            return;
        }
        let mut rng = Rng::new(63);
        let edges = [0, 1, 2, 3, 4, i64::MAX as u64, (1 << 62) - 1, 1 << 62, 99_999_999_999];
        for trial in 0..2000 {
            let n: [u64; 4] = core::array::from_fn(|i| match (trial + i) % 4 {
                0 => edges[(trial + 3 * i) % edges.len()],
                1 => {
                    let r = rng.range(0, (1 << 31) - 1) as u64;
                    (r * r).wrapping_add(rng.range(-1, 1) as u64)
                }
                _ => rng.range(0, i64::MAX) as u64 >> rng.range(0, 62),
            });
            // SAFETY: `avx2()` saw AVX2 on this CPU.
            #[allow(unsafe_code)]
            let roots = unsafe { isqrt4(&n) };
            assert_eq!(roots, n.map(isqrt_u64), "{n:?}");
        }
    }

    #[test]
    fn rows_equal_the_reference_and_declined_rows_are_left_alone() {
        if crate::kernels::arch::x86::avx2() {
            crate::kernels::arch::x86::tests::check_layernorm_rows(rows);
        }
    }
}
