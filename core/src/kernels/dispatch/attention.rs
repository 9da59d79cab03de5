//! One query row of one attention head against the keys of its window: scores, integer
//! softmax, weighted sum of values. Memory is one score and one weight per key: attention is
//! never materialised as an N x N matrix.
//!
//! Softmax weights are `round(255 * exp(s_j - s_max))` (8 bits, the maximum is exactly 255),
//! and the output divides by their sum through one reciprocal per row, so diffuse attention
//! over hundreds of keys keeps its mass instead of rounding every probability to zero.

use super::epilogue::scaled_requant_lanes;
use super::matmul::{dot, dot4};
use crate::config::HEAD_DIM;
use crate::fixed::{round_shift, sat_i8_i64};
use crate::kernels::arch;
use crate::kernels::exp::{exp_neg_u8_u32, ExpQ32};
pub use crate::kernels::reference::attention::scores_block_reference;
use crate::kernels::reference::attention::scores_block_with;
pub use crate::kernels::reference::softmax::softmax_row;
pub use crate::kernels::types::attention::{paired_offset, AttentionQ, KeyLayout, AVG_FRAC_BITS, QUERY_BLOCK};

/// Most keys whose 8-bit weights a 32-bit sum holds exactly (`255 * MAX_KEYS < 2^32`; a band
/// has 960). [`attend`] ignores keys beyond it; [`attend_block`], the engine's kernel, sums with
/// wrapping adds instead (the same code as plain adds in release builds: a bound there cost
/// 13M instructions per encoder pass on Cortex-M55), so lengths beyond it give a wrong average
/// but never a panic.
pub const MAX_KEYS: usize = 1 << 24;

/// Attention of query `q` (`HEAD_DIM` codes) over `keys` and `values` (`n x HEAD_DIM` each).
/// `scores` and `weights` are scratch with room for `n` entries; the result goes to `out`.
pub fn attend(
    q: &[i8],
    keys: &[i8],
    values: &[i8],
    p: &AttentionQ,
    scores: &mut [i32],
    weights: &mut [u8],
    out: &mut [i8],
) {
    let n = (keys.len() / HEAD_DIM)
        .min(values.len() / HEAD_DIM)
        .min(scores.len())
        .min(weights.len())
        .min(MAX_KEYS);
    let (scores, weights) = (&mut scores[..n], &mut weights[..n]);
    let mut max = i32::MIN;
    for (s, k) in scores.iter_mut().zip(keys.chunks_exact(HEAD_DIM)) {
        *s = dot(q, k);
        max = max.max(*s);
    }
    let mut total: u32 = 0;
    for (w, &s) in weights.iter_mut().zip(scores.iter()) {
        *w = softmax_weight(max, s, p);
        total += *w as u32;
    }
    let mut acc = [0i32; HEAD_DIM];
    for (&w, v) in weights.iter().zip(values.chunks_exact(HEAD_DIM)) {
        let w = w as i32;
        for (a, &x) in acc.iter_mut().zip(v) {
            *a = a.wrapping_add(w * x as i32);
        }
    }
    normalise_exact(&acc, total, p, out);
}

/// Per-channel sums of transposed values (`HEAD_DIM x n`, one row per channel): the
/// correction [`attend_block`] needs for its signed softmax weights. Once per head and pass.
pub fn value_sums(values_t: &[i8], n: usize) -> [i32; HEAD_DIM] {
    let mut sums = [0i32; HEAD_DIM];
    if n == 0 {
        return sums;
    }
    for (sum, channel) in sums.iter_mut().zip(values_t.chunks_exact(n)) {
        *sum = channel.iter().fold(0i32, |a, &v| a.wrapping_add(v as i32));
    }
    sums
}

/// [`attend`] for [`QUERY_BLOCK`] queries at once, bit-identical to it query by query, with the
/// values transposed: `values_t` is `HEAD_DIM x n` (one row per value channel), so the weighted
/// sum is a dot product of each query's weights with each channel row. `sums` are the
/// channels' [`value_sums`].
///
/// The weights are stored as `w - 128` (int8), so both operands of the weighted sum are int8
/// (one `vmladav.s8` per 16 products on MVE); `128 * sums[d]` restores the sum exactly.
///
/// `scores` and `weights` need `QUERY_BLOCK * n` entries. Unused query slots are computed like
/// the others; the caller ignores their outputs.
#[allow(clippy::too_many_arguments)]
pub fn attend_block(
    queries: &[[i8; HEAD_DIM]; QUERY_BLOCK],
    keys: &[i8],
    values_t: &[i8],
    sums: &[i32; HEAD_DIM],
    p: &AttentionQ,
    scores: &mut [i32],
    weights: &mut [u8],
    out: &mut [[i8; HEAD_DIM]; QUERY_BLOCK],
) {
    crate::kernels::arch::vectorised(
        #[inline(always)]
        || {
            attend_block_with(scores_block, queries, keys, values_t, sums, p, scores, weights, out);
        },
    )
}

/// [`attend_block`] on keys stored in `layout`: [`KeyLayout::Transposed`] (x86 hosts with
/// AVX-512 VNNI) or [`KeyLayout::Paired`] (x86 hosts with AVX2); [`KeyLayout::Rows`] is
/// [`attend_block`] itself.
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
pub fn attend_block_keys(
    layout: KeyLayout,
    queries: &[[i8; HEAD_DIM]; QUERY_BLOCK],
    keys: &[i8],
    values_t: &[i8],
    sums: &[i32; HEAD_DIM],
    p: &AttentionQ,
    scores: &mut [i32],
    weights: &mut [u8],
    out: &mut [[i8; HEAD_DIM]; QUERY_BLOCK],
) {
    // Each layout's scores inlined into the block (a function pointer would not be).
    crate::kernels::arch::vectorised(
        #[inline(always)]
        || match layout {
            KeyLayout::Rows => attend_block_with(scores_block, queries, keys, values_t, sums, p, scores, weights, out),
            KeyLayout::Transposed => attend_block_with(
                scores_block_transposed,
                queries,
                keys,
                values_t,
                sums,
                p,
                scores,
                weights,
                out,
            ),
            KeyLayout::Paired => attend_block_with(
                scores_block_paired,
                queries,
                keys,
                values_t,
                sums,
                p,
                scores,
                weights,
                out,
            ),
        },
    )
}

/// The key layout of a band of `tokens` on this machine: [`KeyLayout::Transposed`] where the
/// x86 VNNI scores run and the tokens fill blocks of eight, [`KeyLayout::Paired`] where AVX2
/// runs (without VNNI) and they fill blocks of sixteen, else [`KeyLayout::Rows`].
pub fn key_layout(tokens: usize) -> KeyLayout {
    #[cfg(target_arch = "x86_64")]
    if crate::kernels::arch::x86::vnni::keys_transposed(tokens) {
        return KeyLayout::Transposed;
    }
    #[cfg(target_arch = "x86_64")]
    if crate::kernels::arch::x86::avx2::keys_paired(tokens) {
        return KeyLayout::Paired;
    }
    let _ = tokens;
    KeyLayout::Rows
}

/// Token `t`'s key (`HEAD_DIM` codes) into a head's store of `layout`.
pub fn store_key(layout: KeyLayout, key: &[i8], store: &mut [i8], t: usize) {
    match layout {
        KeyLayout::Rows => {
            if let (Some(dst), Some(key)) = (store.get_mut(t * HEAD_DIM..(t + 1) * HEAD_DIM), key.get(..HEAD_DIM)) {
                dst.copy_from_slice(key);
            }
        }
        KeyLayout::Transposed => {
            let base = t / 8 * 8 * HEAD_DIM + t % 8 * 4;
            for (g, group) in key.chunks_exact(4).take(HEAD_DIM / 4).enumerate() {
                if let Some(dst) = store.get_mut(base + 32 * g..base + 32 * g + 4) {
                    for (d, &c) in dst.iter_mut().zip(group) {
                        *d = c ^ i8::MIN;
                    }
                }
            }
        }
        KeyLayout::Paired => {
            for (d, &c) in key.iter().enumerate().take(HEAD_DIM) {
                if let Some(dst) = store.get_mut(paired_offset(t, d)) {
                    *dst = c;
                }
            }
        }
    }
}

/// [`attend_block`] with its scores from `block_scores` (the keys' layout decides which).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn attend_block_with(
    block_scores: impl FnOnce(&[[i8; HEAD_DIM]; QUERY_BLOCK], &[i8], usize, &mut [i32]),
    queries: &[[i8; HEAD_DIM]; QUERY_BLOCK],
    keys: &[i8],
    values_t: &[i8],
    sums: &[i32; HEAD_DIM],
    p: &AttentionQ,
    scores: &mut [i32],
    weights: &mut [u8],
    out: &mut [[i8; HEAD_DIM]; QUERY_BLOCK],
) {
    let n = (keys.len() / HEAD_DIM)
        .min(values_t.len() / HEAD_DIM)
        .min(scores.len() / QUERY_BLOCK)
        .min(weights.len() / QUERY_BLOCK);
    if n == 0 {
        *out = [[0; HEAD_DIM]; QUERY_BLOCK];
        return;
    }
    // One row of n scores and one of n weights per query.
    let Some(scores) = scores.get_mut(..QUERY_BLOCK * n) else {
        return;
    };
    block_scores(queries, keys, n, scores);
    let fast = ExpQ32::new(p.to_log2_q8);
    let values_n = values_t.get(..HEAD_DIM * n).unwrap_or(&[]);
    // Cortex-M7: the softmax written straight into the GEMM tile's widened rows; its sums in
    // the whole of the weights' room, which short rows (attention within a token row) need.
    if let Some((total, acc)) = fast.and_then(|e| arch::softmax_weighted_sums(&e, scores, weights, values_n)) {
        for ((out_q, acc_q), &t) in out.iter_mut().zip(acc).zip(&total) {
            normalise(acc_q, t, p, out_q);
        }
        return;
    }
    let Some(weights) = weights.get_mut(..QUERY_BLOCK * n) else {
        return;
    };
    let mut acc = [[0i32; HEAD_DIM]; QUERY_BLOCK];
    let mut score_rows = scores.chunks_exact(n);
    let mut weight_rows = weights.chunks_exact_mut(n);
    let (Some(s0), Some(s1), Some(s2), Some(s3)) = (
        score_rows.next(),
        score_rows.next(),
        score_rows.next(),
        score_rows.next(),
    ) else {
        return;
    };
    let (Some(w0), Some(w1), Some(w2), Some(w3)) = (
        weight_rows.next(),
        weight_rows.next(),
        weight_rows.next(),
        weight_rows.next(),
    ) else {
        return;
    };
    let mut total = [0u32; QUERY_BLOCK];
    let rows = [(s0, &mut *w0), (s1, &mut *w1), (s2, &mut *w2), (s3, &mut *w3)];
    for ((s_row, w_row), t) in rows.into_iter().zip(total.iter_mut()) {
        let m = row_max(s_row);
        let mut sum = 0u32;
        match fast {
            Some(e) => sum = softmax_row_fastest(&e, m, s_row, w_row),
            None => {
                for (w, &s) in w_row.iter_mut().zip(s_row.iter()) {
                    let x = softmax_weight(m, s, p);
                    *w = x ^ 0x80;
                    sum = sum.wrapping_add(x as u32);
                }
            }
        }
        *t = sum;
    }
    // Cortex-M7 and M55: the four weight rows (consecutive) against every value channel on the
    // assembly GEMM tile, then the offset; elsewhere, and where it declines, as below.
    let weights_i8: &[i8] = bytemuck::cast_slice(&*weights);
    // AVX2 hosts: the weights widened once into the scores' room (no longer needed).
    // Cortex-M55 too: the 2 x 3 Helium tile (12 instructions per 96 MACs) beats the four-row
    // loop, which reloads every weight row for each value channel.
    // Cortex-M7: the weight rows widened into the scores' room as well.
    let tile = arch::matmul_i32_rows_in(
        weights_i8,
        values_n,
        n,
        acc.as_flattened_mut(),
        bytemuck::cast_slice_mut(&mut *scores),
    ) || arch::matmul_i32(weights_i8, values_n, n, acc.as_flattened_mut());
    if tile || avx2_weighted_sums(weights_i8, values_n, n, sums, scores, &mut acc) {
        for acc_q in acc.iter_mut() {
            for (a, &sum) in acc_q.iter_mut().zip(sums) {
                *a = a.wrapping_add(sum.wrapping_mul(128));
            }
        }
    } else {
        let mut rows = weights_i8.chunks_exact(n);
        let (Some(w0), Some(w1), Some(w2), Some(w3)) = (rows.next(), rows.next(), rows.next(), rows.next()) else {
            return;
        };
        for (d, (channel, &sum)) in values_t.chunks_exact(n).zip(sums).enumerate() {
            let offset = sum.wrapping_mul(128);
            for (acc_q, s) in acc.iter_mut().zip(dot4(w0, w1, w2, w3, channel)) {
                acc_q[d] = s.wrapping_add(offset);
            }
        }
    }
    for ((out_q, acc_q), &t) in out.iter_mut().zip(&acc).zip(&total) {
        normalise(acc_q, t, p, out_q);
    }
}

/// The scores of the [`QUERY_BLOCK`] queries against the first `n` keys: `scores[q * n + j] =
/// queries[q] . keys[j]`, on this core's fastest kernel (the DSP scores kernel on Cortex-M7, the
/// Helium score kernel on Cortex-M55, AVX-512 VNNI or AVX2 on x86 hosts), else
/// [`scores_block_reference`]. `keys` needs `n * HEAD_DIM` codes and `scores` `QUERY_BLOCK * n`
/// entries; with less, what fits is computed.
#[inline(always)]
pub fn scores_block(queries: &[[i8; HEAD_DIM]; QUERY_BLOCK], keys: &[i8], n: usize, scores: &mut [i32]) {
    let n = n.min(keys.len() / HEAD_DIM).min(scores.len() / QUERY_BLOCK);
    let keys_n = keys.get(..n * HEAD_DIM).unwrap_or(&[]);
    let Some(scores) = scores.get_mut(..QUERY_BLOCK * n) else {
        return;
    };
    let taken = arch::attention_scores(queries, keys_n, scores) || avx2_scores(queries, keys_n, n, scores);
    if !taken {
        // The head size as an opaque run-time value (`loop_len`): a loop of unknown length
        // becomes a tail-predicated 16-lane `vmladav.s8` loop on MVE; Cortex-M7 keeps the
        // constant, whose unrolled two-row products address by constant offsets.
        scores_block_with(queries, keys_n, scores, super::loop_len(HEAD_DIM), dot4::<i8>);
    }
}

/// [`scores_block`] on keys in [`KeyLayout::Transposed`] (`n` a multiple of eight): the x86
/// VNNI kernel, else the same sums read through the layout.
#[cfg(any(test, target_arch = "x86_64"))]
#[inline(always)]
fn scores_block_transposed(queries: &[[i8; HEAD_DIM]; QUERY_BLOCK], keys_t: &[i8], n: usize, scores: &mut [i32]) {
    #[cfg(target_arch = "x86_64")]
    if crate::kernels::arch::x86::vnni::scores4_transposed(queries, keys_t, n, scores) {
        return;
    }
    scores_block_transposed_reference(queries, keys_t, n, scores);
}

/// [`scores_block_transposed`] in portable Rust (where the kernel declines).
#[cfg(any(test, target_arch = "x86_64"))]
fn scores_block_transposed_reference(
    queries: &[[i8; HEAD_DIM]; QUERY_BLOCK],
    keys_t: &[i8],
    n: usize,
    scores: &mut [i32],
) {
    for (q, row) in queries.iter().zip(scores.chunks_exact_mut(n.max(1))) {
        for (t, s) in row.iter_mut().enumerate().take(n) {
            let base = t / 8 * 8 * HEAD_DIM + t % 8 * 4;
            let mut sum = 0i32;
            for (g, qg) in q.chunks_exact(4).enumerate() {
                for (j, &qc) in qg.iter().enumerate() {
                    let k = keys_t.get(base + 32 * g + j).copied().unwrap_or(i8::MIN) ^ i8::MIN;
                    sum = sum.wrapping_add(i32::from(qc) * i32::from(k));
                }
            }
            *s = sum;
        }
    }
}

/// [`scores_block`] on keys in [`KeyLayout::Paired`] (`n` a multiple of sixteen): the x86 AVX2
/// kernel, else the same sums read through the layout.
#[cfg(any(test, target_arch = "x86_64"))]
#[inline(always)]
fn scores_block_paired(queries: &[[i8; HEAD_DIM]; QUERY_BLOCK], keys_p: &[i8], n: usize, scores: &mut [i32]) {
    #[cfg(target_arch = "x86_64")]
    if crate::kernels::arch::x86::avx2::scores4_paired(queries, keys_p, n, scores) {
        return;
    }
    scores_block_paired_reference(queries, keys_p, n, scores);
}

/// [`scores_block_paired`] in portable Rust (where the kernel declines).
#[cfg(any(test, target_arch = "x86_64"))]
fn scores_block_paired_reference(queries: &[[i8; HEAD_DIM]; QUERY_BLOCK], keys_p: &[i8], n: usize, scores: &mut [i32]) {
    for (q, row) in queries.iter().zip(scores.chunks_exact_mut(n.max(1))) {
        for (t, s) in row.iter_mut().enumerate().take(n) {
            let key = (0..HEAD_DIM).map(|d| keys_p.get(paired_offset(t, d)).copied().unwrap_or(0));
            *s = q
                .iter()
                .zip(key)
                .fold(0i32, |acc, (&a, b)| acc.wrapping_add(i32::from(a) * i32::from(b)));
        }
    }
}

// The x86 kernels of host builds (`arch::x86::vnni` where the CPU has AVX-512 VNNI, else
// `arch::x86::avx2`, each chosen at run time); `false` elsewhere, or where they decline the shape.
#[inline(always)]
fn avx2_scores(queries: &[[i8; HEAD_DIM]; QUERY_BLOCK], keys: &[i8], n: usize, scores: &mut [i32]) -> bool {
    #[cfg(target_arch = "x86_64")]
    return crate::kernels::arch::x86::vnni::scores4(queries, keys, n, scores)
        || crate::kernels::arch::x86::avx2::scores4(queries, keys, n, scores);
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (queries, keys, n, scores);
        false
    }
}

#[inline(always)]
fn avx2_weighted_sums(
    weights: &[i8],
    values_t: &[i8],
    n: usize,
    sums: &[i32; HEAD_DIM],
    scratch: &mut [i32],
    acc: &mut [[i32; HEAD_DIM]; QUERY_BLOCK],
) -> bool {
    #[cfg(target_arch = "x86_64")]
    return crate::kernels::arch::x86::vnni::weighted_sums4(weights, values_t, n, sums, acc)
        || crate::kernels::arch::x86::avx2::weighted_sums4(weights, values_t, n, scratch, acc);
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (weights, values_t, n, sums, scratch, acc);
        false
    }
}

/// The largest of `scores` (`i32::MIN` for none): the Cortex-M7's assembly loop where it takes
/// the length, else a fold (which other cores vectorise).
#[inline(always)]
pub fn row_max(scores: &[i32]) -> i32 {
    arch::row_max(scores).unwrap_or_else(|| scores.iter().fold(i32::MIN, |m, &v| m.max(v)))
}

/// [`softmax_row`] on this core's fastest path, bit for bit the same: AVX-512 or AVX2 on x86 hosts that
/// have it, the Helium assembly on Cortex-M55, the DSP row (or, for rows it declines, the byte
/// table) on Cortex-M7.
#[inline(always)]
pub fn softmax_row_fastest(e: &ExpQ32, max: i32, scores: &[i32], weights: &mut [u8]) -> u32 {
    if let Some(sum) = x86_softmax_row(e, max, scores, weights) {
        return sum;
    }
    if let Some(sum) = arch::softmax_row(e, max, scores, weights) {
        return sum;
    }
    if cfg!(bino_dsp) {
        return softmax_row_by_table(e, max, scores, weights);
    }
    softmax_row(e, max, scores, weights)
}

/// [`softmax_row`] with [`ExpQ32::weight_by_table`] (equal weights, see `exp`'s tests): on a
/// scalar core one `umull` and one byte load replace the cubic's four multiplies.
#[inline(always)]
pub fn softmax_row_by_table(e: &ExpQ32, max: i32, scores: &[i32], weights: &mut [u8]) -> u32 {
    let mut sum = 0u32;
    for (w, &s) in weights.iter_mut().zip(scores) {
        let x = e.weight_by_table(max.wrapping_sub(s) as u32);
        *w = x ^ 0x80;
        sum = sum.wrapping_add(x as u32);
    }
    sum
}

// [`softmax_row`] in AVX-512 where the CPU has it (`arch::x86::vnni`), else in AVX2.
#[inline(always)]
fn x86_softmax_row(e: &ExpQ32, max: i32, scores: &[i32], weights: &mut [u8]) -> Option<u32> {
    #[cfg(target_arch = "x86_64")]
    return crate::kernels::arch::x86::vnni::softmax_row(e, max, scores, weights)
        .or_else(|| crate::kernels::arch::x86::avx2::softmax_row(e, max, scores, weights));
    #[cfg(not(target_arch = "x86_64"))]
    {
        let _ = (e, max, scores, weights);
        None
    }
}

/// The softmax weight of `score` under the row maximum `max`. Scores are dot products of
/// `HEAD_DIM` int8 pairs (`|s| <= HEAD_DIM * 2^14`), so the gap never wraps and is
/// non-negative; 32-bit gaps let the row loop vectorise.
#[inline(always)]
fn softmax_weight(max: i32, score: i32, p: &AttentionQ) -> u8 {
    exp_neg_u8_u32(max.wrapping_sub(score) as u32, p.to_log2_q8)
}

/// Weighted average `acc / total` requantised to output codes (0 when nothing attended).
#[inline(always)]
fn normalise(acc: &[i32; HEAD_DIM], total: u32, p: &AttentionQ, out: &mut [i8]) {
    if total == 0 {
        out.iter_mut().for_each(|o| *o = 0);
        return;
    }
    let recip = reciprocal(total);
    if normalise_in_lanes(acc, recip, p, out) {
        return;
    }
    let (Ok(recip32), true) = (i32::try_from(recip), (1..=62).contains(&p.out.shift)) else {
        normalise_reference(acc, recip, p, out);
        return;
    };
    let half = 1i64 << (p.out.shift - 1);
    for (o, &a) in out.iter_mut().zip(acc.iter()) {
        // `round_shift` and `apply_i64` without their saturation, which these operands cannot
        // reach: `|a * recip| < 2^62` leaves room for the rounding term, and so do an average
        // that fits in 32 bits times a 32-bit multiplier (`|product| <= 2^62`, `half <= 2^61`).
        let avg = (a as i64 * recip32 as i64 + (1 << (30 - AVG_FRAC_BITS))) >> (31 - AVG_FRAC_BITS);
        *o = match i32::try_from(avg) {
            Ok(avg) => sat_i8_i64((avg as i64 * p.out.mult as i64 + half) >> p.out.shift),
            Err(_) => sat_i8_i64(p.out.apply_i64(avg)),
        };
    }
}

/// `2^31 / total`, rounded: one division per query row. `total >= 255` (the maximum's own
/// weight) keeps at least 23 bits.
#[inline(always)]
fn reciprocal(total: u32) -> u64 {
    ((1u64 << 31) + total as u64 / 2) / total.max(1) as u64
}

/// Shift that turns `vrmulh`'s `>> 32` into the average's `>> (31 - AVG_FRAC_BITS)`.
const LANE_PRODUCT_SHIFT: u32 = 1 + AVG_FRAC_BITS;

/// [`normalise`] in 32-bit lanes (`epilogue::scaled_requant_lanes`: Helium on Cortex-M55,
/// `smmulr` / `smmul` on Cortex-M7), bit for bit; `false` (nothing written) where its
/// identities need more room.
///
/// The average `(a recip + 2^14) >> 15` is `vrmulh(a 2^x, recip 2^y)` for `x + y = 17`, exact
/// while both factors fit 31 bits: `y` is as large as `recip` allows (17 once `total >= 2^17`)
/// and `|a| <= 128 total` leaves `a` room for the rest. The output's `(avg mult + 2^(sh-1)) >>
/// sh` for `sh >= 33` is `(vmulh(avg, mult) + 2^(sh-33)) >> (sh - 32)`, as in the fused GEMM.
#[inline(always)]
fn normalise_in_lanes(acc: &[i32; HEAD_DIM], recip: u64, p: &AttentionQ, out: &mut [i8]) -> bool {
    let Ok(recip32) = u32::try_from(recip) else {
        return false;
    };
    if recip32 == 0 || recip32 >= 1 << 31 || !(33..=62).contains(&p.out.shift) {
        return false;
    }
    let y = LANE_PRODUCT_SHIFT.min(recip32.leading_zeros() - 1);
    let x = LANE_PRODUCT_SHIFT - y;
    if acc.iter().fold(0u32, |m, a| m.max(a.unsigned_abs())) >= 1 << (31 - x) {
        return false;
    }
    let scaled: [i32; HEAD_DIM] = core::array::from_fn(|d| acc[d] << x);
    let post = p.out.shift - 32;
    scaled_requant_lanes(&scaled, (recip32 << y) as i32, p.out.mult, 1 << (post - 1), post, out)
}

/// [`normalise`] by the saturating formulas only: [`attend`]'s, the specification.
fn normalise_exact(acc: &[i32; HEAD_DIM], total: u32, p: &AttentionQ, out: &mut [i8]) {
    if total == 0 {
        out.iter_mut().for_each(|o| *o = 0);
        return;
    }
    normalise_reference(acc, reciprocal(total), p, out);
}

/// [`normalise`] by the saturating formulas: its specification.
fn normalise_reference(acc: &[i32; HEAD_DIM], recip: u64, p: &AttentionQ, out: &mut [i8]) {
    for (o, &a) in out.iter_mut().zip(acc.iter()) {
        let avg = round_shift(a as i64 * recip as i64, 31 - AVG_FRAC_BITS);
        *o = sat_i8_i64(p.out.apply_i64(avg));
    }
}

#[cfg(test)]
mod tests;
