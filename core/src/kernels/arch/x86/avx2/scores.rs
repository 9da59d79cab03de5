//! Attention scores on AVX2 over keys stored in code pairs (`attention::KeyLayout::Paired`):
//! blocks of sixteen tokens, each 32-byte group holding codes `2p, 2p + 1` of the block's
//! tokens in turn. One group widens to two vectors of eight tokens' pairs, and one `vpmaddwd`
//! against a query's broadcast pair adds that pair's products to eight tokens' scores at once:
//! no horizontal sums, no transposes (the row layout's kernel spends as many instructions on
//! reducing each key's lanes as on its products).

use bytemuck::must_cast;
use core::arch::x86_64::{_mm256_add_epi32, _mm256_madd_epi16, _mm256_set1_epi32, _mm256_setzero_si256};

const HEAD: usize = crate::config::HEAD_DIM;
use crate::kernels::types::attention::PAIR_BLOCK;
/// Bytes per group: one code pair of each of a block's tokens.
const GROUP: usize = 2 * PAIR_BLOCK;

/// Whether a band of `tokens` keeps its keys in code pairs (`attention::KeyLayout::Paired`, for
/// [`scores4_paired`]): AVX2 runs and the tokens fill blocks of sixteen.
pub fn keys_paired(tokens: usize) -> bool {
    tokens > 0 && tokens.is_multiple_of(PAIR_BLOCK) && crate::kernels::arch::x86::avx2()
}

/// Scores of four queries against `n` keys in the paired layout (`n` a multiple of
/// [`PAIR_BLOCK`]): row `q` of `scores` (`4 x n`) gets `queries[q] . key_j`. `false` (nothing
/// written) where AVX2 does not run or the slices do not hold that.
pub fn scores4_paired(queries: &[[i8; HEAD]; 4], keys_p: &[i8], n: usize, scores: &mut [i32]) -> bool {
    let (Some(key_bytes), Some(score_len)) = (n.checked_mul(HEAD), n.checked_mul(4)) else {
        return false;
    };
    let fits = keys_p.len() >= key_bytes && scores.len() >= score_len;
    if !n.is_multiple_of(PAIR_BLOCK) || !HEAD.is_multiple_of(2) || !fits || !crate::kernels::arch::x86::avx2() {
        return false;
    }
    // SAFETY: `avx2()` saw AVX2 on this CPU. The function only reads and writes through safe slices.
    #[allow(unsafe_code)]
    unsafe {
        scores4_paired_avx2(queries, &keys_p[..key_bytes], n, &mut scores[..score_len])
    };
    true
}

// Per block: 8 accumulators (4 queries x 2 halves of the block); per group 2 widenings and 8
// `vpmaddwd` with the queries' broadcast pairs as memory operands.
#[target_feature(enable = "avx2")]
fn scores4_paired_avx2(queries: &[[i8; HEAD]; 4], keys_p: &[i8], n: usize, scores: &mut [i32]) {
    let mut pairs = [[_mm256_setzero_si256(); HEAD / 2]; 4];
    for (row, q) in pairs.iter_mut().zip(queries) {
        for (v, c) in row.iter_mut().zip(q.chunks_exact(2)) {
            let word = |x: i8| u32::from(i16::from(x) as u16);
            *v = _mm256_set1_epi32((word(c[0]) | word(c[1]) << 16) as i32);
        }
    }
    let (rows, _) = scores.split_at_mut(4 * n);
    let mut out_rows = rows.chunks_exact_mut(n.max(1));
    let (Some(s0), Some(s1), Some(s2), Some(s3)) = (out_rows.next(), out_rows.next(), out_rows.next(), out_rows.next())
    else {
        return;
    };
    let mut out = [s0, s1, s2, s3];
    for (b, block) in keys_p.chunks_exact(PAIR_BLOCK * HEAD).enumerate() {
        let mut acc = [[_mm256_setzero_si256(); 2]; 4];
        for (group, p) in block.chunks_exact(GROUP).zip(0..HEAD / 2) {
            let (lo, hi) = group.split_at(PAIR_BLOCK);
            let (lo, hi) = (super::widen(lo), super::widen(hi));
            for (acc_q, pairs_q) in acc.iter_mut().zip(&pairs) {
                acc_q[0] = _mm256_add_epi32(acc_q[0], _mm256_madd_epi16(lo, pairs_q[p]));
                acc_q[1] = _mm256_add_epi32(acc_q[1], _mm256_madd_epi16(hi, pairs_q[p]));
            }
        }
        for (row, acc_q) in out.iter_mut().zip(acc) {
            if let Some(slot) = row.get_mut(b * PAIR_BLOCK..(b + 1) * PAIR_BLOCK) {
                let sums: [i32; PAIR_BLOCK] = must_cast(acc_q);
                slot.copy_from_slice(&sums);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::dispatch::attention::{store_key, KeyLayout};
    use crate::kernels::reference::matmul::dot;
    use crate::testutil::Rng;

    #[test]
    fn paired_scores_equal_plain_dots() {
        let mut rng = Rng::new(43);
        for n in [16, 48, 960] {
            let mut keys = [0i8; 960 * HEAD];
            let mut queries = [[0i8; HEAD]; 4];
            rng.fill_i8(&mut keys[..n * HEAD]);
            queries.iter_mut().for_each(|q| rng.fill_i8(q));
            if n == 960 {
                // The extremes: every product 2^14, every pair's sum 2^15 (a word would overflow).
                keys.fill(-128);
                queries = [[-128; HEAD]; 4];
            }
            let mut paired = [0i8; 960 * HEAD];
            for (t, key) in keys[..n * HEAD].chunks_exact(HEAD).enumerate() {
                store_key(KeyLayout::Paired, key, &mut paired[..n * HEAD], t);
            }
            let mut scores = [i32::MIN; 4 * 960];
            if !scores4_paired(&queries, &paired[..n * HEAD], n, &mut scores[..4 * n]) {
                assert!(!crate::kernels::arch::x86::avx2(), "declined on an AVX2 CPU");
                return;
            }
            for (q, row) in queries.iter().zip(scores.chunks_exact(n)) {
                for (j, &s) in row.iter().enumerate() {
                    assert_eq!(s, dot(q, &keys[j * HEAD..(j + 1) * HEAD]), "n={n} key {j}");
                }
            }
        }
    }

    #[test]
    fn shapes_it_does_not_take_are_declined() {
        let queries = [[1i8; HEAD]; 4];
        let mut scores = [0i32; 4 * 32];
        assert!(!scores4_paired(&queries, &[1; 17 * HEAD], 17, &mut scores));
        assert!(!scores4_paired(&queries, &[1; 16 * HEAD], 32, &mut scores));
        assert!(!scores4_paired(&queries, &[1; 32 * HEAD], 32, &mut scores[..4 * 16]));
        assert!(!keys_paired(0) && !keys_paired(24));
    }
}
