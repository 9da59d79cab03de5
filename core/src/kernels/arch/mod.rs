//! Assembly kernels for the Cortex-M cores (GEMM tiles, attention's scores and softmax rows,
//! and on Cortex-M55 LayerNorm's, the residual add's and the rotary embedding's lanes), behind
//! safe wrappers.
//!
//! The only module of `bino-core` that may use `unsafe`, and only for `core::arch::asm!`.
//! Each kernel computes a small tile of dot products in registers. On Cortex-M7 (`dsp`: 4 rows
//! x 1 column with `sxtb16` + `smlad`) one kernel call runs a block of four rows against every
//! column with the `Epilogue`'s store (a plain `i32`, or bias, per-channel requantisation, zero
//! point and the int8 store: `Fused`); partial row blocks go through a Rust driver that hands
//! each finished tile to the epilogue. On Cortex-M55 (`mve`: 2 rows x 3 columns with `vmladava.s8`) one
//! kernel call runs a pair of rows against every column triple, the store or the fused
//! requantisation (in vector lanes) included. The portable kernels (`matmul::matmul_i8_reference`,
//! `epilogue::requant_rows`) stay the specification; the wrappers return `false` for shapes
//! or parameters they do not handle, and the caller then runs the reference.
//!
//! Selected by cfgs from `core/build.rs`: `bino_dsp` (thumbv7em) and `bino_mve`
//! (thumbv8m.main built with `-C target-cpu=cortex-m55`). The drivers and the epilogues are
//! also compiled for host tests, with portable tile kernels computing the same sums.
#![allow(unsafe_code)]
// Host builds without tests use none of the drivers.
#![cfg_attr(not(any(bino_dsp, bino_mve, test)), allow(dead_code))]

#[cfg(any(bino_dsp, test))]
pub(crate) mod dsp;
mod fused;
#[cfg(any(bino_mve, test))]
pub(crate) mod mve;
#[cfg(target_arch = "x86_64")]
pub mod x86;

pub use fused::{matmul_requant, matmul_requant_prepared, PreparedRequant};

use crate::config::HEAD_DIM;
use crate::kernels::types::exp::ExpQ32;

/// `f()` with its inlined loops compiled for the widest vector unit the CPU has (x86-64: AVX2
/// where present), else `f()` as built. Integer code only, so the result is the same either
/// way: only the time changes.
#[inline(always)]
pub(crate) fn vectorised<R>(f: impl FnOnce() -> R) -> R {
    #[cfg(target_arch = "x86_64")]
    return x86::widened(f);
    #[cfg(not(target_arch = "x86_64"))]
    f()
}

/// Longest dot product the kernels take (their stack scratch and the accumulator bound:
/// `1024 * 128 * 128 < 2^24`; a band of 960 tokens is one attention dot product).
pub const MAX_K: usize = 1024;

/// What happens to each finished accumulator of a tile. Per-column values are looked up by
/// the epilogue itself (not passed around: copies of them spill, the asm blocks leave the
/// compiler no free registers).
pub(crate) trait Epilogue {
    /// The value an accumulator of column `j` starts from (the bias, or 0).
    #[cfg_attr(not(any(bino_dsp, test)), allow(dead_code))]
    fn init(&self, j: usize) -> i32;
    /// Output `(row, j)` from its finished accumulator (`init` plus the dot product).
    fn put(&mut self, row: usize, j: usize, acc: i32);
    /// Outputs `(row0 + i, j)` for the first `rows` of `acc` (the DSP tile's column: the
    /// epilogue looks its channel up once).
    #[cfg_attr(not(any(bino_dsp, test)), allow(dead_code))]
    #[inline(always)]
    fn put_col<const R: usize>(&mut self, row0: usize, j: usize, acc: [i32; R], rows: usize) {
        for (i, v) in acc.into_iter().enumerate().take(rows) {
            self.put(row0 + i, j, v);
        }
    }
    /// Rows `row0..row0 + 4` against every row of `w` in one assembly call, from the DSP
    /// tile's widened rows `x` (Cortex-M7), where this epilogue has such a kernel; `false`
    /// (nothing written) otherwise, and the driver goes column by column.
    #[cfg_attr(not(any(bino_dsp, test)), allow(dead_code))]
    #[inline(always)]
    fn block_of_rows(&mut self, row0: usize, x: &[u32], w: &[i8], k: usize) -> bool {
        let _ = (row0, x, w, k);
        false
    }
}

/// Stores accumulators as they are: `out[row * n + j]`.
#[cfg_attr(not(any(bino_dsp, test)), allow(dead_code))]
pub(crate) struct Store<'o> {
    pub out: &'o mut [i32],
    pub n: usize,
}

impl Epilogue for Store<'_> {
    #[inline(always)]
    fn init(&self, _: usize) -> i32 {
        0
    }
    #[inline(always)]
    fn put(&mut self, row: usize, j: usize, acc: i32) {
        if let Some(o) = self.out.get_mut(row * self.n + j) {
            *o = acc;
        }
    }
    #[cfg(bino_dsp)]
    #[inline(always)]
    fn block_of_rows(&mut self, row0: usize, x: &[u32], w: &[i8], k: usize) -> bool {
        let n = self.n;
        self.out
            .get_mut(row0 * n..(row0 + dsp::ROWS) * n)
            .is_some_and(|out| dsp::rows_i32(x, w, k, out))
    }
}

/// Shapes every kernel takes: `m` rows of `a` and `n` rows of `w`, both `k` long, and an
/// output of at least `m * n` values. `None` for anything else.
#[cfg_attr(not(any(bino_dsp, bino_mve)), allow(dead_code))]
pub(crate) fn shape(a: &[i8], w: &[i8], k: usize, out_len: usize) -> Option<(usize, usize)> {
    if k == 0 || k > MAX_K {
        return None;
    }
    let (m, n) = (a.len() / k, w.len() / k);
    (m > 0 && n > 0 && m.checked_mul(n)? <= out_len).then_some((m, n))
}

/// `out` (`m x n`) = `a` (`m x k`) times the transpose of `w` (`n x k`) on this core's
/// assembly kernel; `false` (nothing written) where there is none or the shape is not taken.
#[inline]
pub fn matmul_i32(a: &[i8], w: &[i8], k: usize, out: &mut [i32]) -> bool {
    #[cfg(bino_dsp)]
    if let Some((m, n)) = shape(a, w, k, out.len()) {
        return run(a, w, k, m, &mut Store { out, n });
    }
    // Whole rows of column triples per Helium kernel call.
    #[cfg(bino_mve)]
    if let Some((m, n)) = shape(a, w, k, out.len()) {
        return mve::gemm_i32(a, w, k, m, n, out);
    }
    let _ = (a, w, k, out);
    false
}

/// [`matmul_i32`] for at most four rows of `a` with the Cortex-M7 tile's widened rows in the
/// caller's `scratch` (`k / 2` words at least) instead of a zeroed stack scratch; `false`
/// (nothing written) on other cores or shapes.
#[inline]
pub fn matmul_i32_rows_in(a: &[i8], w: &[i8], k: usize, out: &mut [i32], scratch: &mut [u32]) -> bool {
    #[cfg(bino_dsp)]
    if let Some((m, n)) = shape(a, w, k, out.len()) {
        return dsp::gemm_rows_in(a, w, k, m, &mut Store { out, n }, scratch);
    }
    let _ = (a, w, k, out, scratch);
    false
}

/// Attention scores of four queries against `keys.len() / HEAD_DIM` keys (`scores[q * n + j]`,
/// `scores` exactly `4 * n` long), bit for bit
/// [`attention::scores_block_reference`](crate::kernels::reference::attention::scores_block_reference), on
/// this core's assembly kernel (Cortex-M55: two queries in vector registers; Cortex-M7: the
/// DSP tile's widened queries against every key in one loop); `false` (nothing written) where
/// there is none.
#[inline]
pub fn attention_scores(queries: &[[i8; HEAD_DIM]; 4], keys: &[i8], scores: &mut [i32]) -> bool {
    #[cfg(bino_mve)]
    return mve::attention_scores(queries, keys, scores);
    #[cfg(bino_dsp)]
    return dsp::attention_scores(queries, keys, scores);
    #[cfg(not(any(bino_mve, bino_dsp)))]
    {
        let _ = (queries, keys, scores);
        false
    }
}

/// LayerNorm's first lane pass on Cortex-M55 (`layernorm::NarrowParams::row_in_lanes`):
/// `v = (q - zero) * rel`, and the 64-bit sum, minimum and maximum of `v`. All four slices
/// have the row's length.
#[cfg(bino_mve)]
#[inline]
pub(crate) fn layernorm_values(row: &[i8], zero: &[i32], rel: &[i32], v: &mut [i32]) -> Option<(i64, i32, i32)> {
    mve::layernorm_values(row, zero, rel, v)
}

/// LayerNorm's second lane pass: `n = ((v << left) + add) >> right` and the sum of squares.
#[cfg(bino_mve)]
#[inline]
pub(crate) fn layernorm_normalise(v: &[i32], left: u32, add: i32, right: u32, n: &mut [i32]) -> Option<i64> {
    mve::layernorm_normalise(v, left, add, right, n)
}

/// LayerNorm's output pass and attention's normalised average:
/// `sat8((vmulh(vrmulh(n, recip_q), mult) + round) >> post)`.
#[cfg(bino_mve)]
#[inline]
pub(crate) fn scaled_requant_lanes(n: &[i32], recip_q: i32, mult: i32, round: i32, post: u32, out: &mut [i8]) -> bool {
    mve::scaled_requant_lanes(n, recip_q, mult, round, post, out)
}

/// One row of a residual-add chunk on Cortex-M55 (`dispatch::residual::residual_lanes`): `x <-
/// sat8(carry(x) + delta(acc) + zero)` with the chunk's parameters interleaved by groups of four
/// channels (ten vectors a group).
#[cfg(bino_mve)]
#[inline]
pub(crate) fn residual_add_row(x: &mut [i8], acc: &[i32], params: &[i32]) -> bool {
    mve::residual_add_row(x, acc, params)
}

/// The residual add of a chunk of channels over a block of eight rows of 128 on Cortex-M7
/// (`dispatch::residual::residual_lanes`), with per-channel parameters (`dsp::RESIDUAL_WORDS` each).
#[cfg(bino_dsp)]
#[inline]
pub(crate) fn residual_rows8(x: &mut [i8], acc: &[i32], params: &[i32], len: usize) -> bool {
    dsp::residual_rows8(x, acc, params, len)
}

/// The largest score of a row on this core's assembly kernel (Cortex-M7, rows of a multiple of 4
/// scores; Cortex-M55, a multiple of 16); `None` (nothing read) where there is none.
#[inline]
pub fn row_max(scores: &[i32]) -> Option<i32> {
    #[cfg(bino_dsp)]
    return dsp::row_max(scores);
    #[cfg(bino_mve)]
    return mve::row_max(scores);
    #[cfg(not(any(bino_dsp, bino_mve)))]
    {
        let _ = scores;
        None
    }
}

/// `store[c * tokens + t] = token[c]` for every channel `c` (a token's values written
/// channel-major) on this core's assembly kernel (Cortex-M55: multiples of eight channels,
/// `7 * tokens` below 2^16); `false` (nothing written) where there is none or the shape is not
/// taken.
#[inline]
pub fn scatter_channels(token: &[i8], store: &mut [i8], tokens: usize, t: usize) -> bool {
    #[cfg(bino_mve)]
    return mve::scatter_channels(token, store, tokens, t);
    #[cfg(not(bino_mve))]
    {
        let _ = (token, store, tokens, t);
        false
    }
}

/// One softmax row and their sum, bit for bit
/// [`attention::softmax_row`](crate::kernels::reference::softmax::softmax_row), on this core's assembly
/// kernel (Cortex-M55; Cortex-M7 where the row's parameters allow its shortcuts); `None`
/// (nothing written) where there is none.
#[inline]
pub fn softmax_row(e: &ExpQ32, max: i32, scores: &[i32], weights: &mut [u8]) -> Option<u32> {
    #[cfg(bino_mve)]
    return Some(mve::softmax_row(e, max, scores, weights));
    #[cfg(bino_dsp)]
    return dsp::softmax_row(e, max, scores, weights);
    #[cfg(not(any(bino_mve, bino_dsp)))]
    {
        let _ = (e, max, scores, weights);
        None
    }
}

/// Attention's softmax and weighted sums for four queries (`scores`: four rows of `n`), bit for
/// bit [`attention::attend_block`](crate::kernels::dispatch::attention::attend_block)'s general path: the
/// rows' weight totals, and `acc[q][d]` the sum over keys of weight times value channel `d`
/// (`values_t`: `HEAD_DIM` rows of `n`; `acc` lives in `scratch`), on this core's assembly path
/// (Cortex-M7: the softmax written straight into the DSP tile's widened layout, `scores` and
/// `scratch` overwritten);
/// `None` (nothing written) where there is none or it declines the shape or parameters.
#[inline]
pub fn softmax_weighted_sums<'s>(
    e: &ExpQ32,
    scores: &mut [i32],
    scratch: &'s mut [u8],
    values_t: &[i8],
) -> Option<([u32; 4], &'s [[i32; HEAD_DIM]; 4])> {
    #[cfg(bino_dsp)]
    return dsp::softmax_weighted_sums(e, scores, scratch, values_t);
    #[cfg(not(bino_dsp))]
    {
        let _ = (e, scores, scratch, values_t);
        None
    }
}

/// One softmax row as the Cortex-M7's attention computes it (its maximum, then the weights
/// into the DSP tile's widened layout: weight `4g + e` in word `8g + (e & 1)` of `x`, low
/// halfword for `e < 2`), returning the sum of the weights; `None` (nothing written) on other
/// cores and where the row's length or parameters are outside the kernel. For the kernel
/// bench.
#[inline]
pub fn softmax_row_widened(e: &ExpQ32, scores: &[i32], x: &mut [u32]) -> Option<u32> {
    #[cfg(bino_dsp)]
    return dsp::softmax_row_widened(e, scores, x);
    #[cfg(not(bino_dsp))]
    {
        let _ = (e, scores, x);
        None
    }
}

/// Attention's weighted sums as the Cortex-M7 computes them: four rows already in the DSP
/// tile's widened layout (`x`, `2 n` words) against the `HEAD_DIM` value channels (`n` codes
/// each), the four-row block kernel; `false` (nothing written) on other cores and for shapes
/// it declines. For the kernel bench.
#[inline]
pub fn weighted_sums_widened(x: &[u32], values_t: &[i8], n: usize, acc: &mut [[i32; HEAD_DIM]; 4]) -> bool {
    #[cfg(bino_dsp)]
    return dsp::rows_i32(x, values_t, n, acc.as_flattened_mut());
    #[cfg(not(bino_dsp))]
    {
        let _ = (x, values_t, n, acc);
        false
    }
}

/// The tile driver of the Cortex-M7 (the Cortex-M55's drivers are `mve::gemm_i32` and
/// `mve::gemm_fused`).
#[cfg(bino_dsp)]
#[inline(always)]
pub(crate) fn run<E: Epilogue>(a: &[i8], w: &[i8], k: usize, m: usize, epi: &mut E) -> bool {
    dsp::gemm(a, w, k, m, epi)
}

#[cfg(test)]
mod tests;
