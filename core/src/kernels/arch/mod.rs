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

/// One row of a residual-add chunk on Cortex-M55 (`epilogue::residual_lanes`): `x <-
/// sat8(carry(x) + delta(acc) + zero)` with the chunk's parameters interleaved by groups of four
/// channels (ten vectors a group).
#[cfg(bino_mve)]
#[inline]
pub(crate) fn residual_add_row(x: &mut [i8], acc: &[i32], params: &[i32]) -> bool {
    mve::residual_add_row(x, acc, params)
}

/// The residual add of a chunk of channels over a block of eight rows of 128 on Cortex-M7
/// (`epilogue::residual_lanes`), with per-channel parameters (`dsp::RESIDUAL_WORDS` each).
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
mod tests {
    use super::fused::{matmul_prepared_with, matmul_requant_with, Col};
    use super::*;
    use crate::kernels::reference::gemm::matmul_requant_reference;
    use crate::kernels::reference::matmul::matmul_i8_reference;
    use crate::kernels::types::requant::ChannelRequant;
    use crate::testutil::Rng;

    type Driver = fn(&[i8], &[i8], usize, usize, &mut fused::Fused<'_>) -> bool;
    type StoreDriver = fn(&[i8], &[i8], usize, usize, &mut Store<'_>) -> bool;
    const DRIVERS: [(&str, StoreDriver, Driver); 2] = [
        (
            "dsp",
            |a, w, k, m, e| dsp::gemm(a, w, k, m, e),
            |a, w, k, m, e| dsp::gemm(a, w, k, m, e),
        ),
        // The Helium row drivers: whole rows of column triples per kernel call.
        (
            "mve",
            |a, w, k, m, e| mve::gemm_i32(a, w, k, m, e.n, e.out),
            mve::gemm_fused,
        ),
    ];

    #[test]
    fn drivers_with_portable_tiles_match_the_reference() {
        // The drivers' blocking, leftover rows and columns and the DSP scratch layout, on the
        // host (the firmware's kernel-tests check the assembly tiles themselves).
        let mut rng = Rng::new(21);
        let mut a = [0i8; 5 * 132];
        let mut w = [0i8; 131 * 132];
        for (m, n, k) in [
            (1, 1, 4),
            (2, 3, 8),
            (3, 4, 12),
            (4, 5, 20),
            (5, 7, 132),
            (5, 131, 36),
            (4, 2, 17),
        ] {
            rng.fill_i8(&mut a[..m * k]);
            rng.fill_i8(&mut w[..n * k]);
            let (a, w) = (&a[..m * k], &w[..n * k]);
            let mut want = [0i32; 5 * 131];
            matmul_i8_reference(a, w, k, &mut want[..m * n]);
            let bias: [i32; 131] = core::array::from_fn(|_| rng.range(-1 << 20, 1 << 20) as i32);
            let mult: [i32; 131] = core::array::from_fn(|_| rng.range(1 << 30, i32::MAX as i64) as i32);
            let shift: [u8; 131] = core::array::from_fn(|_| rng.range(33, 40) as u8);
            let zero: [i32; 131] = core::array::from_fn(|_| rng.range(-128, 127) as i32);
            let rq = ChannelRequant {
                bias: &bias[..n],
                mult: &mult[..n],
                shift: &shift[..n],
            };
            let mut want8 = [0i8; 5 * 131];
            matmul_requant_reference(a, w, k, &rq, &zero[..n], &mut want8[..m * n]);
            for (name, store, fused) in DRIVERS {
                let takes = name == "mve" || k % 4 == 0;
                let mut got = [0i32; 5 * 131];
                let took = store(a, w, k, m, &mut Store { out: &mut got, n });
                assert_eq!(took, takes, "{name} m={m} n={n} k={k}");
                if took {
                    assert_eq!(got[..m * n], want[..m * n], "{name} m={m} n={n} k={k}");
                }
                let mut got8 = [0i8; 5 * 131];
                let took = matmul_requant_with(a, w, k, &rq, &zero[..n], &mut got8[..m * n], fused);
                assert_eq!(took, takes, "{name} fused m={m} n={n} k={k}");
                if took {
                    assert_eq!(got8[..m * n], want8[..m * n], "{name} fused m={m} n={n} k={k}");
                }
                // The same columns prepared once.
                let mut storage = [0i32; 4 * 131];
                let prepared = PreparedRequant::new(&rq, &zero[..n], &mut storage).expect("columns in range");
                let mut got8 = [0i8; 5 * 131];
                let took = matmul_prepared_with(a, w, k, &prepared, &mut got8[..m * n], fused);
                assert_eq!(took, takes, "{name} prepared m={m} n={n} k={k}");
                if took {
                    assert_eq!(got8[..m * n], want8[..m * n], "{name} prepared m={m} n={n} k={k}");
                }
                if name == "mve" {
                    // The Cortex-M55's prepared path: every accumulator, then two rows at a time.
                    let (mut got8, mut acc) = ([0i8; 5 * 131], [0i32; 5 * 131]);
                    let took = mve::gemm_prepared(a, w, k, prepared.records(), &mut acc, &mut got8[..m * n]);
                    assert!(took, "mve gemm_prepared m={m} n={n} k={k}");
                    assert_eq!(got8[..m * n], want8[..m * n], "mve gemm_prepared m={m} n={n} k={k}");
                    let short =
                        mve::gemm_prepared(a, w, k, prepared.records(), &mut acc[..m * n - 1], &mut got8[..m * n]);
                    assert!(!short, "an accumulator scratch shorter than the output is declined");
                }
            }
        }
    }

    #[test]
    fn dsp_rows_with_a_lent_scratch_match_the_reference() {
        let mut rng = Rng::new(36);
        let mut scratch = [0u32; 2 * 960];
        for (m, n, k) in [(1usize, 1usize, 4usize), (3, 5, 36), (4, 32, 960), (4, 3, 128)] {
            let mut a = [0i8; 4 * 960];
            let mut w = [0i8; 32 * 960];
            rng.fill_i8(&mut a[..m * k]);
            rng.fill_i8(&mut w[..n * k]);
            let (mut got, mut want) = ([0i32; 4 * 32], [0i32; 4 * 32]);
            let took = dsp::gemm_rows_in(
                &a[..m * k],
                &w[..n * k],
                k,
                m,
                &mut Store { out: &mut got, n },
                &mut scratch,
            );
            assert!(took, "m={m} n={n} k={k}");
            matmul_i8_reference(&a[..m * k], &w[..n * k], k, &mut want[..m * n]);
            assert_eq!(got[..m * n], want[..m * n], "m={m} n={n} k={k}");
        }
        // Five rows, or a scratch short of k / 2 words, are declined.
        let (a, w) = ([1i8; 5 * 8], [1i8; 8]);
        assert!(!dsp::gemm_rows_in(
            &a,
            &w,
            8,
            5,
            &mut Store { out: &mut [0; 5], n: 1 },
            &mut scratch
        ));
        assert!(!dsp::gemm_rows_in(
            &a[..8],
            &w,
            8,
            1,
            &mut Store { out: &mut [0; 1], n: 1 },
            &mut [0u32; 3]
        ));
    }

    #[test]
    fn dsp_scores_layout_matches_the_reference() {
        // The Cortex-M7 scores kernel's widening and row-strided stores, through its portable
        // twin (the kernel test firmware checks the assembly on 1 to 960 keys).
        let mut rng = Rng::new(34);
        for (n, extreme) in [(1usize, false), (2, true), (7, false), (33, false), (33, true)] {
            let mut queries = [[0i8; HEAD_DIM]; 4];
            let mut keys = [0i8; 33 * HEAD_DIM];
            if extreme {
                queries = [[-128; HEAD_DIM]; 4];
                keys.fill(-128);
                keys[..HEAD_DIM].fill(127);
            } else {
                queries.iter_mut().for_each(|q| rng.fill_i8(q));
                rng.fill_i8(&mut keys);
            }
            let keys = &keys[..n * HEAD_DIM];
            let (mut got, mut want) = ([0i32; 4 * 33], [0i32; 4 * 33]);
            assert!(dsp::attention_scores(&queries, keys, &mut got[..4 * n]));
            crate::kernels::reference::attention::scores_block_reference(&queries, keys, &mut want[..4 * n]);
            assert_eq!(got[..4 * n], want[..4 * n], "n {n}");
        }
        assert!(!dsp::attention_scores(&[[0; HEAD_DIM]; 4], &[0; HEAD_DIM], &mut [0; 3]));
    }

    #[test]
    fn dsp_softmax_shortcuts_match_the_specification() {
        use crate::fixed::Requant;
        use crate::kernels::reference::softmax::softmax_row as specification;
        let mut rng = Rng::new(35);
        let mut taken = 0;
        for trial in 0..3000 {
            let shift = rng.range(22, 40) as u32;
            let mult = if trial % 4 == 0 {
                rng.range(1, 1 << 20) as i32
            } else {
                rng.range(1 << 29, i32::MAX as i64) as i32
            };
            let Some(e) = ExpQ32::new(Requant { mult, shift }) else {
                continue;
            };
            let n = rng.range(1, 40) as usize;
            let mut scores = [0i32; 40];
            for s in scores[..n].iter_mut() {
                *s = rng.range(-(1 << 19), 1 << 19) as i32;
            }
            // Mostly the row's true maximum; sometimes one below a score (wrapped gaps) or
            // far above every score (gaps past the clamp).
            let top = scores[..n].iter().copied().max().unwrap_or(0);
            let max = match trial % 5 {
                0 => top - 1,
                1 => top + (1 << 21),
                _ => top,
            };
            let (mut got, mut want) = ([0u8; 40], [0u8; 40]);
            let want_sum = specification(&e, max, &scores[..n], &mut want[..n]);
            if let Some(sum) = dsp::softmax_row(&e, max, &scores[..n], &mut got[..n]) {
                taken += 1;
                assert_eq!((got, sum), (want, want_sum), "mult {mult} shift {shift} max {max}");
            } else {
                assert_eq!(got, [0; 40], "declined rows are not written");
            }
        }
        assert!(taken > 1000, "{taken} rows taken");
    }

    #[test]
    fn dsp_softmax_into_the_widened_rows_matches_the_specification() {
        use crate::fixed::Requant;
        use crate::kernels::reference::softmax::softmax_row as specification;
        let mut rng = Rng::new(36);
        let mut taken = 0;
        for trial in 0..600 {
            let shift = rng.range(22, 40) as u32;
            let mult = rng.range(1 << 29, i32::MAX as i64) as i32;
            let Some(e) = ExpQ32::new(Requant { mult, shift }) else {
                continue;
            };
            let n = 8 * rng.range(16, 32) as usize;
            let mut scores = [0i32; 4 * 256];
            // Attention's range, and every fifth block the extremes of i32 (gaps past 2^31,
            // which the kernel saturates).
            let span = if trial % 5 == 0 { i32::MAX as i64 } else { 1 << 19 };
            for s in scores[..4 * n].iter_mut() {
                *s = rng.range(-span, span) as i32;
            }
            if trial % 5 == 0 {
                scores[0] = i32::MIN;
                scores[1] = i32::MAX;
            }
            let mut values_t = [0i8; HEAD_DIM * 256];
            for v in values_t[..HEAD_DIM * n].iter_mut() {
                *v = rng.range(-128, 127) as i8;
            }
            let mut want_acc = [[0i32; HEAD_DIM]; 4];
            let mut want_total = [0u32; 4];
            for (q, row) in scores[..4 * n].chunks_exact(n).enumerate() {
                let max = row.iter().copied().max().unwrap_or(0);
                let mut w = [0u8; 256];
                want_total[q] = specification(&e, max, row, &mut w[..n]);
                for (d, channel) in values_t[..HEAD_DIM * n].chunks_exact(n).enumerate() {
                    // The specification stores `w ^ 0x80`.
                    want_acc[q][d] = channel
                        .iter()
                        .zip(&w[..n])
                        .map(|(&v, &w)| v as i32 * (w ^ 0x80) as i32)
                        .sum();
                }
            }
            let mut scratch = [0u32; 256];
            let scratch: &mut [u8] = bytemuck::cast_slice_mut(&mut scratch[..]);
            let before = scores;
            match dsp::softmax_weighted_sums(
                &e,
                &mut scores[..4 * n],
                &mut scratch[..4 * n],
                &values_t[..HEAD_DIM * n],
            ) {
                Some((total, acc)) => {
                    taken += 1;
                    assert_eq!((total, *acc), (want_total, want_acc), "mult {mult} shift {shift} n {n}");
                }
                None => assert_eq!(scores, before, "declined blocks are not written"),
            }
        }
        assert!(taken > 200, "{taken} blocks taken");
        // Rows of a length the four-row kernel does not take are declined.
        let e = ExpQ32::new(Requant {
            mult: 1 << 30,
            shift: 34,
        })
        .unwrap();
        assert!(dsp::softmax_weighted_sums(&e, &mut [0; 16], &mut [0; 16], &[0; HEAD_DIM * 4]).is_none());
        // And rows too short to hold the sums in the softmax bytes (fewer than 128 keys).
        assert!(dsp::softmax_weighted_sums(&e, &mut [0; 4 * 120], &mut [0; 4 * 120], &[0; HEAD_DIM * 120]).is_none());
    }

    #[test]
    fn dsp_softmax_row_into_the_widened_layout_matches_the_specification() {
        use crate::fixed::Requant;
        use crate::kernels::reference::softmax::softmax_row as specification;
        let mut rng = Rng::new(37);
        let e = ExpQ32::new(Requant {
            mult: 1_431_142_052,
            shift: 34,
        })
        .unwrap();
        for n in [4usize, 8, 36, 960] {
            let scores: [i32; 960] = core::array::from_fn(|_| rng.range(-(1 << 19), 1 << 19) as i32);
            let (scores, mut x) = (&scores[..n], [0u32; 2 * 960]);
            let max = scores.iter().copied().max().unwrap_or(0);
            let mut want = [0u8; 960];
            let want_sum = specification(&e, max, scores, &mut want[..n]);
            assert_eq!(dsp::softmax_row_widened(&e, scores, &mut x), Some(want_sum), "n {n}");
            for (j, &w) in want[..n].iter().enumerate() {
                let word = x[8 * (j / 4) + (j & 1)];
                let got = if j % 4 < 2 { word & 0xFFFF } else { word >> 16 };
                assert_eq!(got, (w ^ 0x80) as u32, "n {n} score {j}");
            }
        }
        assert_eq!(dsp::softmax_row_widened(&e, &[0; 6], &mut [0; 16]), None);
    }

    #[test]
    fn fused_epilogue_equals_the_64_bit_formula_in_its_range() {
        let mut rng = Rng::new(5);
        for _ in 0..20_000 {
            let shift = rng.range(33, 62) as u8;
            let (mult, zero) = (
                rng.range(i32::MIN as i64, i32::MAX as i64) as i32,
                rng.range(-300, 300) as i32,
            );
            let bias = rng.range(-(1 << 30) + 1, (1 << 30) - 1) as i32;
            let Some(col) = Col::new(bias, mult, shift, zero) else {
                continue;
            };
            let acc = rng.range(-(1 << 29), 1 << 29) as i32;
            let rq = ChannelRequant {
                bias: &[bias][..],
                mult: &[mult][..],
                shift: &[shift][..],
            };
            let want = crate::fixed::sat_i8_i64(rq.apply(0, acc) + zero as i64);
            assert_eq!(
                col.apply(acc + bias),
                want,
                "acc {acc} bias {bias} mult {mult} shift {shift} zero {zero}"
            );
        }
        // Outside the range the kernels decline.
        assert!(Col::new(1 << 30, 1, 40, 0).is_none());
        assert!(Col::new(0, 1, 32, 0).is_none());
        assert!(Col::new(0, 1, 62, 1).is_none());
    }

    #[test]
    fn shapes_outside_the_kernels_are_declined() {
        assert_eq!(shape(&[0; 8], &[0; 8], 0, 4), None);
        assert_eq!(shape(&[0; 8], &[0; 8], MAX_K + 1, 4), None);
        assert_eq!(shape(&[0; 8], &[0; 8], 4, 3), None);
        assert_eq!(shape(&[0; 3], &[0; 8], 4, 4), None);
        assert_eq!(shape(&[0; 8], &[0; 8], 4, 4), Some((2, 2)));
    }
}
