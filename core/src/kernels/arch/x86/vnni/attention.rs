//! The attention products on VNNI: scores of four queries against a window's keys, and the
//! softmax weights' sums over its value channels.

use core::arch::x86_64::{
    __m256i, _mm256_add_epi32, _mm256_dpbusd_epi32, _mm256_permute2x128_si256, _mm256_set1_epi32, _mm256_set1_epi8,
    _mm256_setzero_si256, _mm256_sub_epi32, _mm256_unpackhi_epi32, _mm256_unpackhi_epi64, _mm256_unpacklo_epi32,
    _mm256_unpacklo_epi64, _mm256_xor_si256, _mm_set1_epi32, _mm_sub_epi32,
};

use bytemuck::must_cast;

use super::{available, load, store, HEAD, STEP};
use crate::kernels::arch::x86::avx2::sum4;

/// Keys a half step: the weighted sums take windows of a multiple of it.
const HALF: usize = STEP / 2;

/// Scores of four queries against `n` keys (`n x HEAD_DIM`): row `q` of `scores` (`4 x n`)
/// gets `queries[q] . key_j`. `false` where the kernels do not run or the slices do not fit.
pub fn scores4(queries: &[[i8; HEAD]; 4], keys: &[i8], n: usize, scores: &mut [i32]) -> bool {
    let (Some(key_bytes), Some(score_len)) = (n.checked_mul(HEAD), n.checked_mul(4)) else {
        return false;
    };
    if HEAD != STEP || keys.len() < key_bytes || scores.len() < score_len || !available() {
        return false;
    }
    // SAFETY: as in `matmul_i32`.
    #[allow(unsafe_code)]
    unsafe {
        scores4_vnni(queries, &keys[..key_bytes], n, &mut scores[..score_len], false)
    };
    true
}

/// Whether a band of `tokens` keeps its attention keys transposed (`attention::KeyLayout`, for
/// [`scores4_transposed`]): the kernels run and the tokens fill blocks of eight.
pub fn keys_transposed(tokens: usize) -> bool {
    tokens > 0 && tokens.is_multiple_of(8) && available()
}

/// [`scores4`] on keys stored in `attention::KeyLayout::Transposed` (`n` a multiple of eight): the
/// eight group vectors of a block loaded as they are. `false` where the kernels do not run or
/// the slices do not fit.
pub fn scores4_transposed(queries: &[[i8; HEAD]; 4], keys_t: &[i8], n: usize, scores: &mut [i32]) -> bool {
    let (Some(key_bytes), Some(score_len)) = (n.checked_mul(HEAD), n.checked_mul(4)) else {
        return false;
    };
    if !n.is_multiple_of(8) || keys_t.len() < key_bytes || scores.len() < score_len || !available() {
        return false;
    }
    // SAFETY: as in `matmul_i32`.
    #[allow(unsafe_code)]
    unsafe {
        scores4_vnni(queries, &keys_t[..key_bytes], n, &mut scores[..score_len], true)
    };
    true
}

/// Weighted sums of attention, `acc[q][d] = weights_q . values_t_d` for four weight rows
/// (`4 x n`) and the `HEAD_DIM` value channels (`HEAD_DIM x n`), given the channels' wrapping
/// sums `sums` (`attention::value_sums`). `false` where the kernels do not run, `n` is not a
/// multiple of `HALF` or the slices do not fit.
pub fn weighted_sums4(
    weights: &[i8],
    values_t: &[i8],
    n: usize,
    sums: &[i32; HEAD],
    acc: &mut [[i32; HEAD]; 4],
) -> bool {
    let (Some(weight_len), Some(value_len)) = (n.checked_mul(4), n.checked_mul(HEAD)) else {
        return false;
    };
    let fits = weights.len() >= weight_len && values_t.len() >= value_len;
    if n == 0 || !n.is_multiple_of(HALF) || !fits || !available() {
        return false;
    }
    // SAFETY: as in `matmul_i32`.
    #[allow(unsafe_code)]
    unsafe {
        weighted_sums4_vnni(&weights[..weight_len], &values_t[..value_len], n, sums, acc)
    };
    true
}

// Keys as the unsigned operand (`k ^ 0x80`), eight at a time: their 8 x 8 grid of 4-byte groups
// transposed, so that vector `g` holds group `g` of each of the eight keys, and each query's
// group `g` broadcast against it. Eight scores per query come out in one vector, no horizontal
// sums; each query then loses `128 * sum(q)`. Keys past the last full eight run as a zero-padded
// block whose extra scores are not stored. With `transposed` the keys are stored that way
// already (`attention::store_key`, flipped too; `n` a multiple of eight): eight loads a block
// instead of eight loads, eight flips and the 24-shuffle transpose.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
fn scores4_vnni(queries: &[[i8; HEAD]; 4], keys: &[i8], n: usize, scores: &mut [i32], transposed: bool) {
    let flip = _mm256_set1_epi8(-128);
    let zero = _mm256_setzero_si256();
    let groups: [[i32; 8]; 4] = queries.map(bytemuck::cast);
    let corrections: [__m256i; 4] = core::array::from_fn(|q| {
        let lanes: [i32; 8] = must_cast(_mm256_dpbusd_epi32(zero, flip, load(&queries[q])));
        _mm256_set1_epi32(lanes.iter().fold(0i32, |s, &v| s.wrapping_add(v)))
    });
    for (b, block) in keys.chunks(8 * HEAD).enumerate() {
        let g: [__m256i; 8] = if transposed {
            let mut vectors = block.chunks_exact(STEP).map(load);
            core::array::from_fn(|_| vectors.next().unwrap_or(zero))
        } else {
            transpose8(core::array::from_fn(|i| {
                _mm256_xor_si256(load(block.get(i * HEAD..(i + 1) * HEAD).unwrap_or(&[])), flip)
            }))
        };
        for (q, q_groups) in groups.iter().enumerate() {
            // Even and odd groups into two accumulators: two dependency chains of four
            // `vpdpbusd` instead of one of eight (the chain's latency, not the multiplier's
            // throughput, bounded this loop).
            let (mut even, mut odd) = (zero, zero);
            for (gv, qg) in g.chunks_exact(2).zip(q_groups.chunks_exact(2)) {
                even = _mm256_dpbusd_epi32(even, gv[0], _mm256_set1_epi32(qg[0]));
                odd = _mm256_dpbusd_epi32(odd, gv[1], _mm256_set1_epi32(qg[1]));
            }
            let lanes: [i32; 8] = must_cast(_mm256_sub_epi32(_mm256_add_epi32(even, odd), corrections[q]));
            store(scores, q * n + b * 8, &lanes, block.len() / HEAD);
        }
    }
}

/// 8 x 8 transpose of 32-bit elements: `out[g]` lane `i` = `rows[i]` lane `g`.
#[inline]
#[target_feature(enable = "avx2")]
fn transpose8(r: [__m256i; 8]) -> [__m256i; 8] {
    let t0 = _mm256_unpacklo_epi32(r[0], r[1]);
    let t1 = _mm256_unpackhi_epi32(r[0], r[1]);
    let t2 = _mm256_unpacklo_epi32(r[2], r[3]);
    let t3 = _mm256_unpackhi_epi32(r[2], r[3]);
    let t4 = _mm256_unpacklo_epi32(r[4], r[5]);
    let t5 = _mm256_unpackhi_epi32(r[4], r[5]);
    let t6 = _mm256_unpacklo_epi32(r[6], r[7]);
    let t7 = _mm256_unpackhi_epi32(r[6], r[7]);
    let u0 = _mm256_unpacklo_epi64(t0, t2);
    let u1 = _mm256_unpackhi_epi64(t0, t2);
    let u2 = _mm256_unpacklo_epi64(t1, t3);
    let u3 = _mm256_unpackhi_epi64(t1, t3);
    let u4 = _mm256_unpacklo_epi64(t4, t6);
    let u5 = _mm256_unpackhi_epi64(t4, t6);
    let u6 = _mm256_unpacklo_epi64(t5, t7);
    let u7 = _mm256_unpackhi_epi64(t5, t7);
    [
        _mm256_permute2x128_si256::<0x20>(u0, u4),
        _mm256_permute2x128_si256::<0x20>(u1, u5),
        _mm256_permute2x128_si256::<0x20>(u2, u6),
        _mm256_permute2x128_si256::<0x20>(u3, u7),
        _mm256_permute2x128_si256::<0x31>(u0, u4),
        _mm256_permute2x128_si256::<0x31>(u1, u5),
        _mm256_permute2x128_si256::<0x31>(u2, u6),
        _mm256_permute2x128_si256::<0x31>(u3, u7),
    ]
}

// Weights as the unsigned operand (`w ^ 0x80`, the softmax weights themselves), four value
// channels at a time as memory operands: 16 accumulators, 16 `vpdpbusd` per 32 keys. Channel
// `d` then loses `128 * sums[d]`.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
fn weighted_sums4_vnni(weights: &[i8], values_t: &[i8], n: usize, sums: &[i32; HEAD], acc: &mut [[i32; HEAD]; 4]) {
    let flip = _mm256_set1_epi8(-128);
    let Some([w0, w1, w2, w3]) = four_rows(weights, n) else {
        return;
    };
    for (d4, channels) in values_t.chunks_exact(4 * n).enumerate() {
        let mut lanes = [[_mm256_setzero_si256(); 4]; 4];
        let Some([c0, c1, c2, c3]) = four_rows(channels, n) else {
            return;
        };
        // Every row walked by exact chunks, so the loop carries no bounds checks.
        let rows = w0.clone().zip(w1.clone()).zip(w2.clone()).zip(w3.clone());
        for (((((((x0, x1), x2), x3), v0), v1), v2), v3) in rows.zip(c0).zip(c1).zip(c2).zip(c3) {
            let x = [x0, x1, x2, x3].map(|r| _mm256_xor_si256(load(r), flip));
            for (lanes_c, v) in lanes.iter_mut().zip([v0, v1, v2, v3]) {
                let v = load(v);
                for (l, xq) in lanes_c.iter_mut().zip(x) {
                    *l = _mm256_dpbusd_epi32(*l, xq, v);
                }
            }
        }
        // A last half step (a row attention window of 80 keys): zero values past it, so
        // whatever the padded weights, they add nothing.
        if n % STEP == HALF {
            let tail = |row: &[i8], r: usize| load_half(row.get(r * n + n - HALF..(r + 1) * n).unwrap_or(&[]));
            let x: [__m256i; 4] = core::array::from_fn(|q| _mm256_xor_si256(tail(weights, q), flip));
            for (c, lanes_c) in lanes.iter_mut().enumerate() {
                let v = tail(channels, c);
                for (l, xq) in lanes_c.iter_mut().zip(x) {
                    *l = _mm256_dpbusd_epi32(*l, xq, v);
                }
            }
        }
        for (c, lanes_c) in lanes.into_iter().enumerate() {
            let d = 4 * d4 + c;
            let fix = _mm_set1_epi32(sums.get(d).copied().unwrap_or(0).wrapping_mul(128));
            let per_query: [i32; 4] = must_cast(_mm_sub_epi32(sum4(lanes_c), fix));
            for (acc_q, v) in acc.iter_mut().zip(per_query) {
                if let Some(slot) = acc_q.get_mut(d) {
                    *slot = v;
                }
            }
        }
    }
}

/// Sixteen codes in the low half of a vector, zeros above.
#[inline(always)]
fn load_half(chunk: &[i8]) -> __m256i {
    let mut bytes = [0i8; STEP];
    if let (Some(low), Ok(codes)) = (bytes.get_mut(..HALF), <[i8; HALF]>::try_from(chunk)) {
        low.copy_from_slice(&codes);
    }
    must_cast(bytes)
}

/// The first four rows of `n` codes in `rows`, each as its steps of [`STEP`] codes.
fn four_rows(rows: &[i8], n: usize) -> Option<[core::slice::ChunksExact<'_, i8>; 4]> {
    let mut it = rows.chunks_exact(n.max(1)).map(|r| r.chunks_exact(STEP));
    Some([it.next()?, it.next()?, it.next()?, it.next()?])
}
