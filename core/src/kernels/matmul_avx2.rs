//! AVX2 form of the four-row dot product, for host builds with AVX2 enabled (`.cargo/config.toml`
//! sets `x86-64-v3`). LLVM does not turn the portable loop into `vpmaddwd` (it widens to 32 bits
//! and uses `vpmulld`, 8 MACs per slow instruction); here each `vpmaddwd` does 16 MACs.
//! Results are bit-identical to the portable kernel: every product and sum is exact in 32 bits.

use bytemuck::must_cast;
use core::arch::x86_64::{
    __m128i, __m256i, _mm256_add_epi32, _mm256_castsi256_si128, _mm256_cvtepi8_epi16, _mm256_cvtepu8_epi16,
    _mm256_extracti128_si256, _mm256_hadd_epi32, _mm256_madd_epi16, _mm256_setzero_si256, _mm_add_epi32,
};

use super::matmul::Code;

/// Elements per step: 16 int8 values widened to one 256-bit vector of int16.
pub const LANES: usize = 16;

/// Four dot products against `w` over the first `k - k % LANES` elements (the caller adds the
/// tail). Inputs shorter than `w` are treated as ending there.
#[inline]
pub fn dot4<A: Code>(a0: &[A], a1: &[A], a2: &[A], a3: &[A], w: &[i8]) -> [i32; 4] {
    // SAFETY: this module is compiled only when the build enables AVX2
    // (`cfg(target_feature = "avx2")` in kernels/mod.rs), so every CPU the binary is allowed to
    // run on has it. The function itself only reads through safe slices.
    #[allow(unsafe_code)]
    unsafe {
        dot4_avx2(a0, a1, a2, a3, w)
    }
}

#[inline]
#[target_feature(enable = "avx2")]
fn dot4_avx2<A: Code>(a0: &[A], a1: &[A], a2: &[A], a3: &[A], w: &[i8]) -> [i32; 4] {
    fn lanes<T>(x: &[T]) -> core::slice::ChunksExact<'_, T> {
        x.chunks_exact(LANES)
    }
    let mut acc = [_mm256_setzero_si256(); 4];
    for ((((x0, x1), x2), x3), wc) in lanes(a0).zip(lanes(a1)).zip(lanes(a2)).zip(lanes(a3)).zip(lanes(w)) {
        let wv = widen(wc);
        acc[0] = _mm256_add_epi32(acc[0], _mm256_madd_epi16(widen(x0), wv));
        acc[1] = _mm256_add_epi32(acc[1], _mm256_madd_epi16(widen(x1), wv));
        acc[2] = _mm256_add_epi32(acc[2], _mm256_madd_epi16(widen(x2), wv));
        acc[3] = _mm256_add_epi32(acc[3], _mm256_madd_epi16(widen(x3), wv));
    }
    // Lanes [a0 a1 a2 a3] of each 128-bit half after two rounds of pairwise adds.
    let halves = _mm256_hadd_epi32(_mm256_hadd_epi32(acc[0], acc[1]), _mm256_hadd_epi32(acc[2], acc[3]));
    let sums = _mm_add_epi32(_mm256_castsi256_si128(halves), _mm256_extracti128_si256::<1>(halves));
    must_cast(sums)
}

#[inline]
#[target_feature(enable = "avx2")]
fn widen<T: Code>(chunk: &[T]) -> __m256i {
    let bytes: [T; LANES] = chunk.try_into().unwrap_or([T::ZERO; LANES]);
    let bytes: __m128i = bytemuck::cast(bytes);
    if T::SIGNED {
        _mm256_cvtepi8_epi16(bytes)
    } else {
        _mm256_cvtepu8_epi16(bytes)
    }
}
