//! The residual add in AVX2 lanes, eight channels a vector: `dispatch::residual`'s 32-bit lane
//! form (`residual_lanes::add_row`, whose identities the residual tests prove) on the
//! parameters a pass prepared (`PreparedResidual`: groups of four channels, ten four-lane
//! vectors each). On x86 the adds otherwise decoded their parameters per call and ran in
//! 64-bit arithmetic (about a tenth of a VNNI pass, with the decoding).

use bytemuck::must_cast;
use core::arch::x86_64::{
    __m128i, __m256i, _mm256_add_epi32, _mm256_and_si256, _mm256_blend_epi32, _mm256_cvtepi8_epi32, _mm256_mul_epi32,
    _mm256_packs_epi16, _mm256_packs_epi32, _mm256_permutevar8x32_epi32, _mm256_set1_epi32, _mm256_set_m128i,
    _mm256_setr_epi32, _mm256_setzero_si256, _mm256_shuffle_epi32, _mm256_sllv_epi32, _mm256_srav_epi32,
    _mm256_srli_epi64, _mm256_sub_epi32, _mm_cvtsi64_si128,
};

/// Words of a group's parameters: ten vectors of four lanes.
const GROUP_WORDS: usize = 40;
/// Channels a vector: two groups.
const LANES: usize = 8;

/// `x <- sat8(carry(x) + delta(acc) + zero)` for the `rows` rows of `n` channels in `x` and
/// `acc`, on prepared `params` (`n / 4` groups); `false` (nothing written) where the CPU lacks
/// AVX2, `n` is not a multiple of eight, a slice is short, or an accumulator reaches `2^30`
/// in magnitude (the delta's bound: the caller's 64-bit path then).
pub(crate) fn residual_rows(x: &mut [i8], acc: &[i32], n: usize, rows: usize, params: &[i32]) -> bool {
    let Some(cells) = rows.checked_mul(n) else {
        return false;
    };
    if n == 0 || !n.is_multiple_of(LANES) || params.len() < n / 4 * GROUP_WORDS || !crate::kernels::arch::x86::avx2() {
        return false;
    }
    let (Some(x), Some(acc)) = (x.get_mut(..cells), acc.get(..cells)) else {
        return false;
    };
    if acc.iter().fold(0u32, |m, &a| m.max(a.unsigned_abs())) >= 1 << 30 {
        return false;
    }
    // SAFETY: `avx2()` saw AVX2 on this CPU. The kernel reads and writes through safe slices.
    #[allow(unsafe_code)]
    unsafe {
        rows_avx2(x, acc, n, &params[..n / 4 * GROUP_WORDS])
    };
    true
}

/// One vector of two groups' parameters.
#[inline]
#[target_feature(enable = "avx2")]
fn pair(first: &[i32], second: &[i32], v: usize) -> __m256i {
    let part = |g: &[i32]| -> __m128i {
        must_cast(<[i32; 4]>::try_from(g.get(4 * v..4 * v + 4).unwrap_or(&[0; 4])).unwrap_or([0; 4]))
    };
    _mm256_set_m128i(part(second), part(first))
}

/// `hi32(a * b)` per lane (signed).
#[inline]
#[target_feature(enable = "avx2")]
fn high(a: __m256i, b: __m256i) -> __m256i {
    // The odd lanes moved down by a dword shuffle (`vpmuldq` reads the low dword of each
    // quadword): with 64-bit shifts LLVM turned the products into unsigned ones plus fixups.
    let even = _mm256_srli_epi64::<32>(_mm256_mul_epi32(a, b));
    let odd = _mm256_mul_epi32(_mm256_shuffle_epi32::<0xF5>(a), _mm256_shuffle_epi32::<0xF5>(b));
    _mm256_blend_epi32::<0b1010_1010>(even, odd)
}

// Eight channels at a time, their parameters loaded once for every row.
#[target_feature(enable = "avx2")]
fn rows_avx2(x: &mut [i8], acc: &[i32], n: usize, params: &[i32]) {
    let low_five = _mm256_set1_epi32(31);
    let zero = _mm256_setzero_si256();
    // Bytes 0-3 and 16-19 after the packs: lanes 0 and 4 side by side.
    let join = _mm256_setr_epi32(0, 4, 0, 0, 0, 0, 0, 0);
    for (p, groups) in params.chunks_exact(2 * GROUP_WORDS).enumerate() {
        let (first, second) = groups.split_at(GROUP_WORDS);
        let v: [__m256i; 10] = [
            pair(first, second, 0),
            pair(first, second, 1),
            pair(first, second, 2),
            pair(first, second, 3),
            pair(first, second, 4),
            pair(first, second, 5),
            pair(first, second, 6),
            pair(first, second, 7),
            pair(first, second, 8),
            pair(first, second, 9),
        ];
        // `add_row`'s words: carry zero, left shift, multiplier, rounding, negated shift; delta
        // bias, multiplier, rounding, negated shift; the new zero point.
        let carry_pre = _mm256_and_si256(v[1], low_five);
        let carry_shift = _mm256_and_si256(_mm256_sub_epi32(zero, v[4]), low_five);
        let delta_shift = _mm256_and_si256(_mm256_sub_epi32(zero, v[8]), low_five);
        let at = p * LANES;
        for (x_row, acc_row) in x.chunks_exact_mut(n).zip(acc.chunks_exact(n)) {
            let (Some(xs), Some(accs)) = (x_row.get_mut(at..at + LANES), acc_row.get(at..at + LANES)) else {
                continue;
            };
            let codes: [i8; LANES] = (&*xs).try_into().unwrap_or([0; LANES]);
            let q = _mm256_cvtepi8_epi32(_mm_cvtsi64_si128(i64::from_le_bytes(codes.map(|c| c as u8))));
            let a: __m256i = must_cast(<[i32; LANES]>::try_from(accs).unwrap_or([0; LANES]));
            let centred = _mm256_sllv_epi32(_mm256_sub_epi32(q, v[0]), carry_pre);
            let carry = _mm256_srav_epi32(_mm256_add_epi32(high(centred, v[2]), v[3]), carry_shift);
            let delta = _mm256_srav_epi32(
                _mm256_add_epi32(high(_mm256_add_epi32(a, v[5]), v[6]), v[7]),
                delta_shift,
            );
            let sum = _mm256_add_epi32(_mm256_add_epi32(carry, delta), v[9]);
            // Saturating packs (the clamp to -128..=127), then lanes 0-3 and 4-7 together.
            let words = _mm256_packs_epi32(sum, sum);
            let bytes = _mm256_permutevar8x32_epi32(_mm256_packs_epi16(words, words), join);
            let out: [[i8; LANES]; 4] = must_cast(bytes);
            xs.copy_from_slice(&out[0]);
        }
    }
}
