//! AVX2 kernels of x86-64 hosts, chosen at run time where the CPU has AVX2 ([`super::avx2()`]),
//! whatever `-C target-cpu` the build names: the four-row dot product, the matrix multiply and the two products of attention. LLVM does not
//! turn the portable loops into `vpmaddwd` (it widens to 32 bits and uses `vpmulld`, 8 MACs per
//! slow instruction); here each `vpmaddwd` does 16 MACs, and each operand is widened once per
//! tile rather than once per product.
//!
//! Results are bit-identical to the portable kernels: every product fits 16 bits, every sum is
//! taken modulo 2^32 like their wrapping adds, and such sums do not depend on their order.
//! Each entry point returns `false` (computing nothing) for shapes it does not take; the
//! caller then runs the portable kernel.

pub mod layernorm;
mod requant;
pub(crate) mod residual;
pub mod rope;
mod scores;
mod softmax;

pub(crate) use requant::{requant_prepared, requant_row_narrow};
pub use scores::{keys_paired, scores4_paired};
pub use softmax::softmax_row;

use bytemuck::must_cast;
use core::arch::x86_64::{
    __m128i, __m256i, _mm256_add_epi32, _mm256_castsi256_si128, _mm256_cvtepi8_epi16, _mm256_cvtepu8_epi16,
    _mm256_extracti128_si256, _mm256_hadd_epi32, _mm256_madd_epi16, _mm256_setzero_si256, _mm_add_epi32,
    _mm_unpackhi_epi32, _mm_unpackhi_epi64, _mm_unpacklo_epi32, _mm_unpacklo_epi64,
};

use crate::kernels::reference::matmul::dot;
use crate::kernels::types::code::Code;

/// Elements per step: 16 int8 values widened to one 256-bit vector of int16.
pub const LANES: usize = 16;
/// Longest dot product [`matmul_i32`] takes (its widened rows live on the stack: 4 x 480 x 2 B).
pub const MAX_GEMM_K: usize = 512;
/// The head size the attention kernels take.
const HEAD: usize = crate::config::HEAD_DIM;

/// Four dot products against `w` over the first `k - k % LANES` elements (the caller adds the
/// tail), where the CPU has AVX2; `None` elsewhere. Inputs shorter than `w` are treated as
/// ending there.
#[inline]
pub fn dot4<A: Code>(a0: &[A], a1: &[A], a2: &[A], a3: &[A], w: &[i8]) -> Option<[i32; 4]> {
    if !super::avx2() {
        return None;
    }
    // SAFETY: `avx2()` saw AVX2 on this CPU (cpuid, and the OS saving the YMM registers). The
    // function itself only reads through safe slices.
    #[allow(unsafe_code)]
    Some(unsafe { dot4_avx2(a0, a1, a2, a3, w) })
}

/// `out` (`m x n`) = `a` (`m x k`) times the transpose of `w` (`n x k`), as
/// `matmul::matmul_i8_reference` computes it, when `k` is a multiple of [`LANES`] up to
/// [`MAX_GEMM_K`] and `out` holds exactly `m * n` values; otherwise `false`.
pub fn matmul_i32(a: &[i8], w: &[i8], k: usize, out: &mut [i32]) -> bool {
    if k == 0 || !k.is_multiple_of(LANES) || k > MAX_GEMM_K || !super::avx2() {
        return false;
    }
    let (m, n) = (a.len() / k, w.len() / k);
    // No rows on either side: nothing to compute (and the tiles' chunking needs some).
    if m == 0 || n == 0 || m.checked_mul(n) != Some(out.len()) {
        return false;
    }
    // SAFETY: as in `dot4`, `avx2()` saw AVX2 on this CPU. The widened rows live on the stack,
    // sized for the model's widths (zeroing them for the longest `k` was 1 % of a pass).
    #[allow(unsafe_code)]
    unsafe {
        match k / LANES {
            0..=8 => matmul_avx2::<8>(&a[..m * k], &w[..n * k], k, out),
            9..=30 => matmul_avx2::<30>(&a[..m * k], &w[..n * k], k, out),
            _ => matmul_avx2::<{ MAX_GEMM_K / LANES }>(&a[..m * k], &w[..n * k], k, out),
        }
    };
    true
}

/// Scores of four queries (`HEAD_DIM` codes each) against `n` keys (`n x HEAD_DIM`): row `q`
/// of `scores` (`4 x n`) gets `queries[q] . key_j`. `false` if the slices do not hold that.
pub fn scores4(queries: &[[i8; HEAD]; 4], keys: &[i8], n: usize, scores: &mut [i32]) -> bool {
    let (Some(key_bytes), Some(score_len)) = (n.checked_mul(HEAD), n.checked_mul(4)) else {
        return false;
    };
    if !HEAD.is_multiple_of(LANES) || keys.len() < key_bytes || scores.len() < score_len || !super::avx2() {
        return false;
    }
    // SAFETY: as in `dot4`, `avx2()` saw AVX2 on this CPU.
    #[allow(unsafe_code)]
    unsafe {
        scores4_avx2(queries, &keys[..key_bytes], n, &mut scores[..score_len])
    };
    true
}

/// Weighted sums of attention: `acc[q][d] = weights_q . values_t_d` for the four weight rows
/// (`4 x n`, consecutive) and the `HEAD_DIM` value channels (`HEAD_DIM x n`, one row per
/// channel). `scratch` (at least `2 n` values, overwritten) holds the weights widened to 16
/// bits. `false` if `n` is not a multiple of [`LANES`] or the slices do not hold that.
pub fn weighted_sums4(
    weights: &[i8],
    values_t: &[i8],
    n: usize,
    scratch: &mut [i32],
    acc: &mut [[i32; HEAD]; 4],
) -> bool {
    let (Some(weight_len), Some(value_len)) = (n.checked_mul(4), n.checked_mul(HEAD)) else {
        return false;
    };
    let fits = weights.len() >= weight_len && values_t.len() >= value_len && scratch.len() >= weight_len / 2;
    if n == 0 || !n.is_multiple_of(LANES) || !fits || !super::avx2() {
        return false;
    }
    let wide: &mut [i16] = bytemuck::cast_slice_mut(&mut scratch[..weight_len / 2]);
    // SAFETY: as in `dot4`, `avx2()` saw AVX2 on this CPU.
    #[allow(unsafe_code)]
    unsafe {
        weighted_sums4_avx2(&weights[..weight_len], &values_t[..value_len], n, wide, acc)
    };
    true
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
    must_cast(sum4(acc))
}

// Tiles of 4 rows of `a` (widened once into `wide`) x 2 rows of `w`: 8 accumulators, and per
// 16 elements 2 widenings and 8 `vpmaddwd`. Rows past the last full four use `dot`.
#[target_feature(enable = "avx2")]
fn matmul_avx2<const S: usize>(a: &[i8], w: &[i8], k: usize, out: &mut [i32]) {
    let (steps, n) = (k / LANES, w.len() / k);
    if steps > S {
        return;
    }
    let mut wide = [[_mm256_setzero_si256(); S]; 4];
    let mut a_quads = a.chunks_exact(4 * k);
    let mut out_quads = out.chunks_exact_mut(4 * n);
    for (a4, o4) in (&mut a_quads).zip(&mut out_quads) {
        for (row, wide_row) in a4.chunks_exact(k).zip(wide.iter_mut()) {
            for (v, chunk) in wide_row.iter_mut().zip(row.chunks_exact(LANES)) {
                *v = widen(chunk);
            }
        }
        let [r0, r1, r2, r3] = wide.each_ref().map(|r| &r[..steps]);
        let mut w_pairs = w.chunks_exact(2 * k);
        let mut j = 0;
        for pair in &mut w_pairs {
            let (c0, c1) = pair.split_at(k);
            let mut acc = [[_mm256_setzero_si256(); 4]; 2];
            for ((((x0, x1), x2), x3), (w0, w1)) in r0
                .iter()
                .zip(r1)
                .zip(r2)
                .zip(r3)
                .zip(c0.chunks_exact(LANES).zip(c1.chunks_exact(LANES)))
            {
                let (w0, w1) = (widen(w0), widen(w1));
                for (acc_c, wv) in acc.iter_mut().zip([w0, w1]) {
                    acc_c[0] = _mm256_add_epi32(acc_c[0], _mm256_madd_epi16(*x0, wv));
                    acc_c[1] = _mm256_add_epi32(acc_c[1], _mm256_madd_epi16(*x1, wv));
                    acc_c[2] = _mm256_add_epi32(acc_c[2], _mm256_madd_epi16(*x2, wv));
                    acc_c[3] = _mm256_add_epi32(acc_c[3], _mm256_madd_epi16(*x3, wv));
                }
            }
            for (c, acc_c) in acc.into_iter().enumerate() {
                let sums: [i32; 4] = must_cast(sum4(acc_c));
                for (r, s) in sums.into_iter().enumerate() {
                    if let Some(o) = o4.get_mut(r * n + j + c) {
                        *o = s;
                    }
                }
            }
            j += 2;
        }
        if let Some(c0) = w_pairs.remainder().get(..k) {
            let mut acc = [_mm256_setzero_si256(); 4];
            for ((((x0, x1), x2), x3), w0) in r0.iter().zip(r1).zip(r2).zip(r3).zip(c0.chunks_exact(LANES)) {
                let wv = widen(w0);
                acc[0] = _mm256_add_epi32(acc[0], _mm256_madd_epi16(*x0, wv));
                acc[1] = _mm256_add_epi32(acc[1], _mm256_madd_epi16(*x1, wv));
                acc[2] = _mm256_add_epi32(acc[2], _mm256_madd_epi16(*x2, wv));
                acc[3] = _mm256_add_epi32(acc[3], _mm256_madd_epi16(*x3, wv));
            }
            let sums: [i32; 4] = must_cast(sum4(acc));
            for (r, s) in sums.into_iter().enumerate() {
                if let Some(o) = o4.get_mut(r * n + j) {
                    *o = s;
                }
            }
        }
    }
    for (row, out_row) in a_quads
        .remainder()
        .chunks_exact(k)
        .zip(out_quads.into_remainder().chunks_exact_mut(n))
    {
        for (o, w_row) in out_row.iter_mut().zip(w.chunks_exact(k)) {
            *o = dot(row, w_row);
        }
    }
}

// The four queries widened once (8 vectors); per key 2 widenings and 8 `vpmaddwd`, the four
// sums of a key reduced to one 128-bit vector, and four keys' vectors transposed so each
// query's four scores are stored together.
#[target_feature(enable = "avx2")]
fn scores4_avx2(queries: &[[i8; HEAD]; 4], keys: &[i8], n: usize, scores: &mut [i32]) {
    let q: [[__m256i; HEAD / LANES]; 4] =
        core::array::from_fn(|r| core::array::from_fn(|c| widen(&queries[r][c * LANES..(c + 1) * LANES])));
    let key_scores = |key: &[i8]| -> __m128i {
        let mut acc = [_mm256_setzero_si256(); 4];
        for (c, chunk) in key.chunks_exact(LANES).enumerate() {
            let kv = widen(chunk);
            for (a, qr) in acc.iter_mut().zip(&q) {
                *a = _mm256_add_epi32(*a, _mm256_madd_epi16(qr[c], kv));
            }
        }
        sum4(acc)
    };
    let (s0, rest) = scores.split_at_mut(n);
    let (s1, rest) = rest.split_at_mut(n);
    let (s2, s3) = rest.split_at_mut(n);
    let mut key_quads = keys.chunks_exact(4 * HEAD);
    let mut j = 0;
    for quad in &mut key_quads {
        let keys4: [__m128i; 4] = core::array::from_fn(|i| key_scores(&quad[i * HEAD..(i + 1) * HEAD]));
        // Key-major [q0 q1 q2 q3] x 4 to query-major [k0 k1 k2 k3] x 4.
        let rows = transpose4(keys4);
        for (s, row) in [&mut *s0, &mut *s1, &mut *s2, &mut *s3].into_iter().zip(rows) {
            if let Some(slot) = s.get_mut(j..j + 4) {
                slot.copy_from_slice(&row);
            }
        }
        j += 4;
    }
    for key in key_quads.remainder().chunks_exact(HEAD) {
        let sums: [i32; 4] = must_cast(key_scores(key));
        for (s, v) in [&mut *s0, &mut *s1, &mut *s2, &mut *s3].into_iter().zip(sums) {
            if let Some(slot) = s.get_mut(j) {
                *slot = v;
            }
        }
        j += 1;
    }
}

// The four weight rows widened once into `wide` (`4 x n` int16); per pair of value channels
// and 16 keys 2 widenings and 8 `vpmaddwd` with the widened weights as memory operands.
#[target_feature(enable = "avx2")]
fn weighted_sums4_avx2(weights: &[i8], values_t: &[i8], n: usize, wide: &mut [i16], acc: &mut [[i32; HEAD]; 4]) {
    for (chunk, out) in weights.chunks_exact(LANES).zip(wide.chunks_exact_mut(LANES)) {
        out.copy_from_slice(&must_cast::<__m256i, [i16; LANES]>(widen(chunk)));
    }
    let rows: [&[i16]; 4] = core::array::from_fn(|r| wide.get(r * n..(r + 1) * n).unwrap_or(&[]));
    let [r0, r1, r2, r3] = rows.map(|r| r.chunks_exact(LANES));
    for (d, pair) in values_t.chunks_exact(2 * n).enumerate() {
        let (c0, c1) = pair.split_at(n);
        let mut sums = [[_mm256_setzero_si256(); 4]; 2];
        for ((((x0, x1), x2), x3), (v0, v1)) in r0
            .clone()
            .zip(r1.clone())
            .zip(r2.clone())
            .zip(r3.clone())
            .zip(c0.chunks_exact(LANES).zip(c1.chunks_exact(LANES)))
        {
            let [x0, x1, x2, x3] = [x0, x1, x2, x3].map(load_i16);
            let (v0, v1) = (widen(v0), widen(v1));
            for (s, vv) in sums.iter_mut().zip([v0, v1]) {
                s[0] = _mm256_add_epi32(s[0], _mm256_madd_epi16(x0, vv));
                s[1] = _mm256_add_epi32(s[1], _mm256_madd_epi16(x1, vv));
                s[2] = _mm256_add_epi32(s[2], _mm256_madd_epi16(x2, vv));
                s[3] = _mm256_add_epi32(s[3], _mm256_madd_epi16(x3, vv));
            }
        }
        for (c, s) in sums.into_iter().enumerate() {
            let per_query: [i32; 4] = must_cast(sum4(s));
            for (acc_q, v) in acc.iter_mut().zip(per_query) {
                if let Some(slot) = acc_q.get_mut(2 * d + c) {
                    *slot = v;
                }
            }
        }
    }
}

#[inline(always)]
fn load_i16(chunk: &[i16]) -> __m256i {
    must_cast::<[i16; LANES], __m256i>(chunk.try_into().unwrap_or([0; LANES]))
}

/// `[sum of v[0]'s lanes, ..., sum of v[3]'s lanes]` (also the VNNI kernels' reduction).
#[inline]
#[target_feature(enable = "avx2")]
pub(super) fn sum4(v: [__m256i; 4]) -> __m128i {
    // Lanes [v0 v1 v2 v3] of each 128-bit half after two rounds of pairwise adds.
    let halves = _mm256_hadd_epi32(_mm256_hadd_epi32(v[0], v[1]), _mm256_hadd_epi32(v[2], v[3]));
    _mm_add_epi32(_mm256_castsi256_si128(halves), _mm256_extracti128_si256::<1>(halves))
}

/// Rows of a 4 x 4 matrix of int32 given as its columns (and the other way round).
#[inline]
#[target_feature(enable = "avx2")]
pub(super) fn transpose4(c: [__m128i; 4]) -> [[i32; 4]; 4] {
    let (t0, t1) = (_mm_unpacklo_epi32(c[0], c[1]), _mm_unpacklo_epi32(c[2], c[3]));
    let (t2, t3) = (_mm_unpackhi_epi32(c[0], c[1]), _mm_unpackhi_epi32(c[2], c[3]));
    [
        must_cast(_mm_unpacklo_epi64(t0, t1)),
        must_cast(_mm_unpackhi_epi64(t0, t1)),
        must_cast(_mm_unpacklo_epi64(t2, t3)),
        must_cast(_mm_unpackhi_epi64(t2, t3)),
    ]
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::Rng;

    fn plain(a: &[i8], w: &[i8], k: usize) -> [i32; 9 * 7] {
        let (m, n) = (a.len() / k, w.len() / k);
        let mut out = [0i32; 9 * 7];
        for i in 0..m {
            for j in 0..n {
                out[i * n + j] = dot(&a[i * k..(i + 1) * k], &w[j * k..(j + 1) * k]);
            }
        }
        out
    }

    #[test]
    fn matmul_matches_plain_dots_on_every_tile_edge() {
        let mut rng = Rng::new(31);
        let mut a = [0i8; 9 * 480];
        let mut w = [0i8; 7 * 480];
        for (m, n, k) in [(4, 2, 16), (9, 7, 32), (5, 3, 128), (8, 7, 480), (1, 1, 16), (3, 5, 48)] {
            rng.fill_i8(&mut a[..m * k]);
            rng.fill_i8(&mut w[..n * k]);
            if k == 480 {
                a[..m * k].fill(-128);
                w[..n * k].fill(-128);
            }
            let mut out = [i32::MIN; 9 * 7];
            assert!(matmul_i32(&a[..m * k], &w[..n * k], k, &mut out[..m * n]));
            assert_eq!(
                out[..m * n],
                plain(&a[..m * k], &w[..n * k], k)[..m * n],
                "m={m} n={n} k={k}"
            );
        }
    }

    #[test]
    fn matmul_declines_what_it_does_not_take() {
        let mut out = [0i32; 4];
        assert!(!matmul_i32(&[1; 34], &[1; 34], 17, &mut out));
        assert!(!matmul_i32(&[1; 32], &[1; 32], 16, &mut out[..3]));
        assert!(!matmul_i32(&[1; 2 * 528], &[1; 2 * 528], 528, &mut out));
        assert!(!matmul_i32(&[], &[], 0, &mut out));
    }

    #[test]
    fn attention_products_match_plain_dots() {
        let mut rng = Rng::new(37);
        for n in [16, 37, 64, 960] {
            let mut keys = [0i8; 960 * HEAD];
            let mut values_t = [0i8; 960 * HEAD];
            let mut weights = [0i8; 4 * 960];
            let mut queries = [[0i8; HEAD]; 4];
            rng.fill_i8(&mut keys[..n * HEAD]);
            rng.fill_i8(&mut values_t[..n * HEAD]);
            rng.fill_i8(&mut weights[..4 * n]);
            queries.iter_mut().for_each(|q| rng.fill_i8(q));
            if n == 960 {
                keys.fill(-128);
                queries = [[-128; HEAD]; 4];
                weights.fill(-128);
                values_t.fill(-128);
            }
            let mut scores = [0i32; 4 * 960];
            assert!(scores4(&queries, &keys[..n * HEAD], n, &mut scores[..4 * n]));
            for (q, row) in queries.iter().zip(scores.chunks_exact(n)) {
                for (j, &s) in row.iter().enumerate() {
                    assert_eq!(s, dot(q, &keys[j * HEAD..(j + 1) * HEAD]), "n={n} key {j}");
                }
            }
            let mut acc = [[0i32; HEAD]; 4];
            let mut scratch = [0i32; 2 * 960];
            let taken = weighted_sums4(&weights[..4 * n], &values_t[..HEAD * n], n, &mut scratch, &mut acc);
            assert_eq!(taken, n % LANES == 0, "n={n}");
            if taken {
                for (q, acc_q) in acc.iter().enumerate() {
                    for (d, &s) in acc_q.iter().enumerate() {
                        let want = dot(&weights[q * n..(q + 1) * n], &values_t[d * n..(d + 1) * n]);
                        assert_eq!(s, want, "n={n} query {q} channel {d}");
                    }
                }
            }
        }
    }
}
