//! One query row of one attention head against all keys of the band: scores, integer
//! softmax, weighted sum of values. Memory is one score and one weight per key: attention is
//! never materialised as an N x N matrix.
//!
//! Softmax weights are `round(255 * exp(s_j - s_max))` (8 bits, the maximum is exactly 255),
//! and the output divides by their sum through one reciprocal per row, so diffuse attention
//! over hundreds of keys keeps its mass instead of rounding every probability to zero.

use super::arch;
use super::epilogue::scaled_requant_lanes;
use super::exp::{exp_neg_u8_u32, ExpQ32};
use super::matmul::{dot, dot4};
pub use super::reference::softmax::softmax_row;
use crate::config::HEAD_DIM;
use crate::fixed::{round_shift, sat_i8_i64, Requant};

/// Fraction bits of the normalised weighted average before the output factor.
pub const AVG_FRAC_BITS: u32 = 16;
/// Most keys whose 8-bit weights a 32-bit sum holds exactly (`255 * MAX_KEYS < 2^32`; a band
/// has 960). [`attend`] ignores keys beyond it; [`attend_block`], the engine's kernel, sums with
/// wrapping adds instead (the same code as plain adds in release builds: a bound there cost
/// 13M instructions per encoder pass on Cortex-M55), so lengths beyond it give a wrong average
/// but never a panic.
pub const MAX_KEYS: usize = 1 << 24;

/// Quantisation parameters of one head's attention.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AttentionQ {
    /// Score gap (int32 units of `q . k`) to Q8 base-2 units: folds the q and k scales,
    /// `1/sqrt(head_dim)` and `log2(e)`.
    pub to_log2_q8: Requant,
    /// Q16 weighted average of value codes to output codes (`value scale / output scale / 2^16`).
    pub out: Requant,
}

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

/// Queries attended together by [`attend_block`]: each key and value is read once per block.
pub const QUERY_BLOCK: usize = 4;

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
    crate::kernels::dispatch::vectorised(
        #[inline(always)]
        || {
            attend_block_with(scores_block, queries, keys, values_t, sums, p, scores, weights, out);
        },
    )
}

/// [`attend_block`] on keys stored in [`KeyLayout::Transposed`] (x86 hosts with AVX-512 VNNI).
#[cfg(target_arch = "x86_64")]
#[allow(clippy::too_many_arguments)]
pub fn attend_block_keys_transposed(
    queries: &[[i8; HEAD_DIM]; QUERY_BLOCK],
    keys: &[i8],
    values_t: &[i8],
    sums: &[i32; HEAD_DIM],
    p: &AttentionQ,
    scores: &mut [i32],
    weights: &mut [u8],
    out: &mut [[i8; HEAD_DIM]; QUERY_BLOCK],
) {
    crate::kernels::dispatch::vectorised(
        #[inline(always)]
        || {
            attend_block_with(
                scores_block_transposed,
                queries,
                keys,
                values_t,
                sums,
                p,
                scores,
                weights,
                out,
            );
        },
    )
}

/// How a head's keys are stored: as rows for [`attend_block`] (every core), transposed for the
/// x86 VNNI `attend_block_keys_transposed`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KeyLayout {
    /// Token by token, `HEAD_DIM` codes each (every core).
    Rows,
    /// Blocks of eight tokens transposed into groups of four codes, flipped to unsigned
    /// ([`store_key`]; x86 hosts with AVX-512 VNNI, where [`key_layout`] picks it).
    Transposed,
}

/// The key layout of a band of `tokens` on this machine: [`KeyLayout::Transposed`] where the
/// x86 VNNI scores run and the tokens fill blocks of eight, else [`KeyLayout::Rows`].
pub fn key_layout(tokens: usize) -> KeyLayout {
    #[cfg(target_arch = "x86_64")]
    if super::arch::x86::vnni::keys_transposed(tokens) {
        return KeyLayout::Transposed;
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
    let (Some(scores), Some(weights)) = (scores.get_mut(..QUERY_BLOCK * n), weights.get_mut(..QUERY_BLOCK * n)) else {
        return;
    };
    block_scores(queries, keys, n, scores);
    let fast = ExpQ32::new(p.to_log2_q8);
    let values_n = values_t.get(..HEAD_DIM * n).unwrap_or(&[]);
    // Cortex-M7: the softmax written straight into the GEMM tile's widened rows.
    if let Some((total, acc)) = fast.and_then(|e| arch::softmax_weighted_sums(&e, scores, weights, values_n)) {
        for ((out_q, acc_q), &t) in out.iter_mut().zip(acc).zip(&total) {
            normalise(acc_q, t, p, out_q);
        }
        return;
    }
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
        scores_block_reference(queries, keys_n, scores);
    }
}

/// [`scores_block`] on keys in [`KeyLayout::Transposed`] (`n` a multiple of eight): the x86
/// VNNI kernel, else the same sums read through the layout.
#[cfg(any(test, target_arch = "x86_64"))]
#[inline(always)]
fn scores_block_transposed(queries: &[[i8; HEAD_DIM]; QUERY_BLOCK], keys_t: &[i8], n: usize, scores: &mut [i32]) {
    #[cfg(target_arch = "x86_64")]
    if super::arch::x86::vnni::scores4_transposed(queries, keys_t, n, scores) {
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

/// [`scores_block`] in portable Rust: the specification of its kernels.
#[inline(always)]
pub fn scores_block_reference(queries: &[[i8; HEAD_DIM]; QUERY_BLOCK], keys: &[i8], scores: &mut [i32]) {
    let n = (keys.len() / HEAD_DIM).min(scores.len() / QUERY_BLOCK);
    if n == 0 {
        return;
    }
    // The head size as an opaque run-time value: with a constant 32, LLVM unrolls each dot
    // product and vectorises it over 32-bit lanes; a loop of unknown length becomes a
    // tail-predicated 16-lane `vmladav.s8` loop on MVE, as in the matrix multiply.
    // On Cortex-M7 (`bino_dsp`, no vector unit) the constant size is the better one: the
    // unrolled two-row products address keys and queries by constant offsets.
    let hd = if cfg!(bino_dsp) {
        HEAD_DIM
    } else {
        core::hint::black_box(HEAD_DIM)
    };
    let mut score_rows = scores.chunks_exact_mut(n);
    let (Some(s0), Some(s1), Some(s2), Some(s3)) = (
        score_rows.next(),
        score_rows.next(),
        score_rows.next(),
        score_rows.next(),
    ) else {
        return;
    };
    let [q0, q1, q2, q3] = queries.each_ref().map(|q| q.get(..hd).unwrap_or(&[]));
    let score_slots = s0.iter_mut().zip(s1.iter_mut()).zip(s2.iter_mut()).zip(s3.iter_mut());
    for ((((x0, x1), x2), x3), k) in score_slots.zip(keys.chunks_exact(hd)) {
        let s = dot4(q0, q1, q2, q3, k);
        (*x0, *x1, *x2, *x3) = (s[0], s[1], s[2], s[3]);
    }
}

// The x86 kernels of host builds (`arch::x86::vnni` where the CPU has AVX-512 VNNI, else
// `arch::x86::avx2`, each chosen at run time); `false` elsewhere, or where they decline the shape.
#[inline(always)]
fn avx2_scores(queries: &[[i8; HEAD_DIM]; QUERY_BLOCK], keys: &[i8], n: usize, scores: &mut [i32]) -> bool {
    #[cfg(target_arch = "x86_64")]
    return super::arch::x86::vnni::scores4(queries, keys, n, scores)
        || super::arch::x86::avx2::scores4(queries, keys, n, scores);
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
    return super::arch::x86::vnni::weighted_sums4(weights, values_t, n, sums, acc)
        || super::arch::x86::avx2::weighted_sums4(weights, values_t, n, scratch, acc);
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

/// [`softmax_row`] on this core's fastest path, bit for bit the same: AVX-512 on x86 hosts that
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

// [`softmax_row`] compiled for AVX-512 where the CPU has it (`arch::x86::vnni`).
#[inline(always)]
fn x86_softmax_row(e: &ExpQ32, max: i32, scores: &[i32], weights: &mut [u8]) -> Option<u32> {
    #[cfg(target_arch = "x86_64")]
    return super::arch::x86::vnni::softmax_row(e, max, scores, weights);
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
mod tests {
    use super::*;
    use crate::testutil::{requant_of, Rng};

    fn exp(x: f64) -> f64 {
        // exp for tests without std: (1 + x/2^20)^(2^20) by squaring.
        let mut r = 1.0 + x / 1048576.0;
        for _ in 0..20 {
            r *= r;
        }
        r
    }

    /// Float attention on the dequantised codes.
    fn reference(q: &[i8], keys: &[i8], values: &[i8], score_scale: f64, out: &mut [f64; HEAD_DIM]) {
        let n = keys.len() / HEAD_DIM;
        let mut s = [0f64; 64];
        for j in 0..n {
            s[j] = dot(q, &keys[j * HEAD_DIM..(j + 1) * HEAD_DIM]) as f64 * score_scale;
        }
        let max = s[..n].iter().cloned().fold(f64::MIN, f64::max);
        let w: [f64; 64] = core::array::from_fn(|j| if j < n { exp(s[j] - max) } else { 0.0 });
        let total: f64 = w.iter().sum();
        for d in 0..HEAD_DIM {
            out[d] = (0..n).map(|j| w[j] * values[j * HEAD_DIM + d] as f64).sum::<f64>() / total;
        }
    }

    #[test]
    fn normalise_takes_the_lanes_for_real_averages_and_matches_the_specification() {
        let mut rng = Rng::new(81);
        let edges = [
            2u32,
            3,
            255,
            256,
            (1 << 17) - 1,
            1 << 17,
            (1 << 17) + 1,
            255 * 960,
            u32::MAX,
        ];
        let mut in_lanes = 0;
        for trial in 0..6000 {
            let total = match trial % 3 {
                0 => edges[trial / 3 % edges.len()],
                1 => rng.range(255, 255 * 960) as u32,
                _ => rng.range(2, 1 << 31) as u32,
            };
            let shift = rng.range(33, 62) as u32;
            let mult = rng.range(i32::MIN as i64, i32::MAX as i64) as i32;
            let p = AttentionQ {
                to_log2_q8: Requant { mult: 1, shift: 1 },
                out: Requant { mult, shift },
            };
            // An average of int8 values under weights summing to `total`: |a| <= 128 total.
            let bound = (128 * total as i64).min(i32::MAX as i64);
            let acc: [i32; HEAD_DIM] = core::array::from_fn(|d| match d {
                0 => bound as i32,
                1 => -(bound as i32),
                _ => rng.range(-bound, bound + 1) as i32,
            });
            let recip = reciprocal(total);
            let (mut lanes, mut want) = ([0i8; HEAD_DIM], [0i8; HEAD_DIM]);
            normalise_reference(&acc, recip, &p, &mut want);
            if normalise_in_lanes(&acc, recip, &p, &mut lanes) {
                in_lanes += 1;
                assert_eq!(lanes, want, "total {total} mult {mult} shift {shift}");
            } else {
                // Only where 128 total no longer fits beside the reciprocal (totals from 2^24).
                assert!(total >= 1 << 24, "declined total {total} shift {shift}");
            }
            let mut fast = [0i8; HEAD_DIM];
            normalise(&acc, total, &p, &mut fast);
            assert_eq!(fast, want, "total {total} mult {mult} shift {shift}");
        }
        assert!(in_lanes > 4000, "{in_lanes} of 6000 in lanes");
    }

    #[test]
    fn normalise_equals_its_saturating_formula() {
        let mut rng = Rng::new(8);
        let extremes = [i32::MIN, i32::MIN + 1, -1, 0, 1, i32::MAX, 1 << 25, -(1 << 25)];
        for trial in 0..4000 {
            let total = match trial % 4 {
                0 => rng.range(1, 300) as u32,
                1 => rng.range(255, 1 << 20) as u32,
                2 => rng.range(1, u32::MAX as i64) as u32,
                _ => [1, 2, 255, u32::MAX][trial / 4 % 4],
            };
            let shift = if trial % 7 == 0 {
                rng.range(0, 64) as u32
            } else {
                rng.range(20, 62) as u32
            };
            let mult = if trial % 5 == 0 {
                [i32::MIN, i32::MAX, 1, -1][trial / 5 % 4]
            } else {
                rng.range(i32::MIN as i64, i32::MAX as i64) as i32
            };
            let p = AttentionQ {
                to_log2_q8: Requant { mult: 1, shift: 1 },
                out: Requant { mult, shift },
            };
            let acc: [i32; HEAD_DIM] = core::array::from_fn(|d| {
                if d < extremes.len() {
                    extremes[d]
                } else {
                    rng.range(-(1 << 26), 1 << 26) as i32
                }
            });
            let (mut fast, mut want) = ([0i8; HEAD_DIM], [0i8; HEAD_DIM]);
            normalise(&acc, total, &p, &mut fast);
            let recip = ((1u64 << 31) + total as u64 / 2) / total as u64;
            normalise_reference(&acc, recip, &p, &mut want);
            assert_eq!(fast, want, "total {total} mult {mult} shift {shift}");
        }
    }

    #[test]
    fn matches_float_softmax_attention() {
        let mut rng = Rng::new(21);
        const N: usize = 64;
        let mut keys = [0i8; N * HEAD_DIM];
        let mut values = [0i8; N * HEAD_DIM];
        let mut q = [0i8; HEAD_DIM];
        for score_scale in [1e-4, 1e-3, 4e-3] {
            rng.fill_i8(&mut keys);
            rng.fill_i8(&mut values);
            rng.fill_i8(&mut q);
            // gap * score_scale * log2(e) * 256 as mult / 2^shift.
            let p = AttentionQ {
                to_log2_q8: requant_of(score_scale * core::f64::consts::LOG2_E * 256.0),
                out: Requant {
                    mult: 1 << 30,
                    shift: 31 + AVG_FRAC_BITS - 1,
                },
            };
            let mut scores = [0i32; N];
            let mut weights = [0u8; N];
            let mut out = [0i8; HEAD_DIM];
            attend(&q, &keys, &values, &p, &mut scores, &mut weights, &mut out);
            let mut want = [0f64; HEAD_DIM];
            reference(&q, &keys, &values, score_scale, &mut want);
            for d in 0..HEAD_DIM {
                // 8-bit weights: a fraction of an output code on average, at most ~1.5.
                assert!(
                    (out[d] as f64 - want[d]).abs() <= 1.5,
                    "scale {score_scale} d {d}: {} vs {}",
                    out[d],
                    want[d]
                );
            }
        }
    }

    #[test]
    fn block_is_bit_identical_to_single_queries() {
        let mut rng = Rng::new(5);
        const N: usize = 37;
        let mut keys = [0i8; N * HEAD_DIM];
        let mut values = [0i8; N * HEAD_DIM];
        let mut queries = [[0i8; HEAD_DIM]; QUERY_BLOCK];
        for score_scale in [1e-4, 2e-3, 3e-2, 300.0] {
            rng.fill_i8(&mut keys);
            rng.fill_i8(&mut values);
            queries.iter_mut().for_each(|q| rng.fill_i8(q));
            let p = AttentionQ {
                to_log2_q8: requant_of(score_scale * core::f64::consts::LOG2_E * 256.0),
                out: requant_of(1.0 / 65536.0),
            };
            let (mut scores, mut weights) = ([0i32; QUERY_BLOCK * N], [0u8; QUERY_BLOCK * N]);
            let mut out = [[0i8; HEAD_DIM]; QUERY_BLOCK];
            let values_t: [i8; N * HEAD_DIM] = core::array::from_fn(|i| values[(i % N) * HEAD_DIM + i / N]);
            let sums = value_sums(&values_t, N);
            attend_block(
                &queries,
                &keys,
                &values_t,
                &sums,
                &p,
                &mut scores,
                &mut weights,
                &mut out,
            );
            for (q, got) in queries.iter().zip(&out) {
                let mut want = [0i8; HEAD_DIM];
                attend(q, &keys, &values, &p, &mut scores[..N], &mut weights[..N], &mut want);
                assert_eq!(*got, want, "scale {score_scale}");
            }
        }
    }

    #[test]
    fn every_softmax_path_equals_the_specification() {
        let mut rng = Rng::new(29);
        for (case, n) in [1usize, 3, 4, 5, 17, 64, 960, 80, 127]
            .into_iter()
            .cycle()
            .take(36)
            .enumerate()
        {
            let spread = [6u32, 14, 20, 31][case % 4];
            let scores: [i32; 960] = core::array::from_fn(|_| match rng.next_u64() % 16 {
                0 => i32::MIN,
                1 => i32::MAX,
                r => ((rng.next_u64() as i64 % (1i64 << spread)) as i32).wrapping_mul(r as i32 % 2 * 2 - 1),
            });
            let scores = &scores[..n];
            let max = scores
                .iter()
                .fold(i32::MIN, |m, &v| m.max(v))
                .wrapping_sub((case % 3) as i32 * 77);
            let shift = 22 + (case as u32 * 5) % 41;
            let e = ExpQ32::new(Requant {
                mult: (rng.next_u64() >> 33) as i32,
                shift,
            })
            .expect("shift >= 22");
            let (mut want, mut by_table, mut fastest) = ([0u8; 960], [0u8; 960], [0u8; 960]);
            let sum = softmax_row(&e, max, scores, &mut want[..n]);
            assert_eq!(softmax_row_by_table(&e, max, scores, &mut by_table[..n]), sum, "{case}");
            assert_eq!(softmax_row_fastest(&e, max, scores, &mut fastest[..n]), sum, "{case}");
            assert_eq!(by_table, want, "{case}");
            assert_eq!(fastest, want, "{case}");
        }
    }

    #[test]
    fn diffuse_attention_keeps_its_mass() {
        // 512 equal keys: every float weight is 1/512, far below an 8-bit probability step.
        const N: usize = 512;
        let keys = [0i8; N * HEAD_DIM];
        let values: [i8; N * HEAD_DIM] =
            core::array::from_fn(|i| if (i / HEAD_DIM).is_multiple_of(2) { 100 } else { 50 });
        let p = AttentionQ {
            to_log2_q8: Requant {
                mult: 1 << 30,
                shift: 31,
            },
            out: Requant {
                mult: 1 << 30,
                shift: 31 + AVG_FRAC_BITS - 1,
            },
        };
        let (mut scores, mut weights, mut out) = ([0i32; N], [0u8; N], [0i8; HEAD_DIM]);
        attend(&[3; HEAD_DIM], &keys, &values, &p, &mut scores, &mut weights, &mut out);
        assert_eq!(out, [75; HEAD_DIM]);
    }

    #[test]
    fn transposed_keys_score_as_the_rows() {
        let mut rng = Rng::new(64);
        for n in [8usize, 16, 120, 960] {
            let mut keys = [0i8; 960 * HEAD_DIM];
            rng.fill_i8(&mut keys[..n * HEAD_DIM]);
            let mut queries = [[0i8; HEAD_DIM]; QUERY_BLOCK];
            queries.iter_mut().for_each(|q| rng.fill_i8(q));
            if n == 960 {
                keys.fill(-128);
                queries[0] = [-128; HEAD_DIM];
            }
            let mut keys_t = [0i8; 960 * HEAD_DIM];
            for (t, key) in keys[..n * HEAD_DIM].chunks_exact(HEAD_DIM).enumerate() {
                store_key(KeyLayout::Transposed, key, &mut keys_t[..n * HEAD_DIM], t);
            }
            let mut want = [0i32; QUERY_BLOCK * 960];
            scores_block_reference(&queries, &keys[..n * HEAD_DIM], &mut want[..QUERY_BLOCK * n]);
            for fast in [false, true] {
                let mut got = [i32::MIN; QUERY_BLOCK * 960];
                if fast {
                    scores_block_transposed(&queries, &keys_t[..n * HEAD_DIM], n, &mut got[..QUERY_BLOCK * n]);
                } else {
                    scores_block_transposed_reference(
                        &queries,
                        &keys_t[..n * HEAD_DIM],
                        n,
                        &mut got[..QUERY_BLOCK * n],
                    );
                }
                assert_eq!(got[..QUERY_BLOCK * n], want[..QUERY_BLOCK * n], "n={n} fast={fast}");
            }
            // The rows layout stores the key as it is.
            let mut rows = [0i8; 2 * HEAD_DIM];
            store_key(KeyLayout::Rows, &keys[..HEAD_DIM], &mut rows, 1);
            assert_eq!(rows[HEAD_DIM..], keys[..HEAD_DIM]);
        }
    }

    #[test]
    fn empty_and_short_inputs_do_not_panic() {
        let p = AttentionQ {
            to_log2_q8: Requant { mult: 1, shift: 1 },
            out: Requant { mult: 1, shift: 1 },
        };
        let mut out = [7i8; HEAD_DIM];
        attend(&[1; HEAD_DIM], &[], &[], &p, &mut [], &mut [], &mut out);
        assert_eq!(out, [0; HEAD_DIM]);
        attend(&[1; 3], &[1; 100], &[1; 10], &p, &mut [0; 1], &mut [0; 0], &mut out);
        let mut block_out = [[7i8; HEAD_DIM]; QUERY_BLOCK];
        let queries = [[1i8; HEAD_DIM]; QUERY_BLOCK];
        attend_block(
            &queries,
            &[1; 100],
            &[1; 10],
            &[0; HEAD_DIM],
            &p,
            &mut [0; 3],
            &mut [0; 9],
            &mut block_out,
        );
        assert_eq!(block_out, [[0; HEAD_DIM]; QUERY_BLOCK]);
    }
}
