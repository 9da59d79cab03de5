//! The fused epilogue: bias, per-channel requantisation, zero point and int8 store applied to
//! each accumulator as its tile finishes, bit for bit what `epilogue::requant_rows` computes.
//!
//! `requant_rows` gives `sat8(((acc + bias) * mult + 2^(shift-1)) >> shift) + zero)` in 64
//! bits. For `shift = 32 + s` with `s >= 1`, `|acc| < 2^30` and `|bias| < 2^30` the product
//! is below `2^62` in magnitude and, since `2^(31+s)` is a multiple of `2^32`,
//! `floor((p + 2^(31+s)) / 2^(32+s)) = floor((floor(p / 2^32) + 2^(s-1)) / 2^s)`; adding
//! `zero * 2^s` before the last shift adds `zero` exactly. So each output is one high-half
//! multiply-accumulate, one shift and one saturation in 32 bits (`smmla`, `asr`, `ssat` on
//! both cores). Channels outside that range make the wrapper decline the whole call.

use super::{shape, Epilogue};
use crate::kernels::types::params::I32s;
#[cfg(any(bino_mve, test))]
pub(crate) use crate::kernels::types::prepared::ColRecords;
pub use crate::kernels::types::prepared::PreparedRequant;
pub(crate) use crate::kernels::types::prepared::{requant_col, Col};
use crate::kernels::types::requant::ChannelRequant;

/// Channels whose parameters are prepared at once (2 KiB of stack).
pub const CHUNK: usize = 128;

/// [`Epilogue`] of the fused kernels: one chunk of output channels starting at `j0`.
pub(crate) struct Fused<'o> {
    params: [Col; CHUNK],
    /// Where an unpaired last row's second outputs go (zeroed once per chunk, not per row).
    spare: [i8; CHUNK],
    out: &'o mut [i8],
    n: usize,
    j0: usize,
}

impl Fused<'_> {
    /// Hands `kernel` the chunk's first `len` channels' parameters and the outputs of those
    /// channels in row `row0` and, if `pair`, row `row0 + 1` (else a scratch that is dropped).
    /// `false` if the rows lie outside the output or `kernel` declines.
    #[cfg_attr(not(any(bino_mve, test)), allow(dead_code))]
    #[inline(always)]
    pub(crate) fn rows(
        &mut self,
        row0: usize,
        pair: bool,
        len: usize,
        kernel: impl FnOnce(&[Col], &mut [i8], &mut [i8]) -> bool,
    ) -> bool {
        let at = row0 * self.n + self.j0;
        let (first, second) = self.out.split_at_mut((at + self.n).min(self.out.len()));
        let (Some(params), Some(out0)) = (self.params.get(..len), first.get_mut(at..at + len)) else {
            return false;
        };
        let out1 = match (pair, second.get_mut(..len), self.spare.get_mut(..len)) {
            (true, Some(o), _) | (false, _, Some(o)) => o,
            _ => return false,
        };
        kernel(params, out0, out1)
    }
}

impl Epilogue for Fused<'_> {
    #[inline(always)]
    fn init(&self, j: usize) -> i32 {
        self.params.get(j).map_or(0, |c| c.bias)
    }
    #[inline(always)]
    fn put(&mut self, row: usize, j: usize, acc: i32) {
        if let (Some(o), Some(c)) = (self.out.get_mut(row * self.n + self.j0 + j), self.params.get(j)) {
            *o = c.apply(acc);
        }
    }
    #[cfg(bino_dsp)]
    #[inline(always)]
    fn block_of_rows(&mut self, row0: usize, x: &[u32], w: &[i8], k: usize) -> bool {
        let len = w.len() / k.max(1);
        let at = row0 * self.n + self.j0;
        match (self.params.get(..len), self.out.get_mut(at..)) {
            (Some(params), Some(out)) => super::dsp::rows_requant(x, w, k, params, out, self.n),
            _ => false,
        }
    }
    #[inline(always)]
    fn put_col<const R: usize>(&mut self, row0: usize, j: usize, acc: [i32; R], rows: usize) {
        let Some(&c) = self.params.get(j) else {
            return;
        };
        let base = row0 * self.n + self.j0 + j;
        for (i, v) in acc.into_iter().enumerate().take(rows) {
            if let Some(o) = self.out.get_mut(base + i * self.n) {
                *o = c.apply(v);
            }
        }
    }
}

/// `out = sat8(rq(a * w^T) + zero)` through `driver` (a tile driver: `a`, one chunk of `w`,
/// `k`, `m`, the epilogue), chunk by chunk of [`CHUNK`] channels, each chunk's parameters
/// checked as they are prepared (one pass: the engine calls this per token block). `false`
/// for shapes [`shape`] declines, `rq` not of `n` channels, or parameters outside
/// [`Col::new`]'s range; chunks before the one declined may have been written.
#[inline(always)]
pub(crate) fn matmul_requant_with<B, M, Z>(
    a: &[i8],
    w: &[i8],
    k: usize,
    rq: &ChannelRequant<'_, B, M>,
    zero: &Z,
    out: &mut [i8],
    driver: impl FnMut(&[i8], &[i8], usize, usize, &mut Fused<'_>) -> bool,
) -> bool
where
    B: I32s + ?Sized,
    M: I32s + ?Sized,
    Z: I32s + ?Sized,
{
    if rq.channels() != w.len() / k.max(1) {
        return false;
    }
    matmul_cols_with(a, w, k, |c| requant_col(rq, zero, c), out, driver)
}

/// [`matmul_requant_with`] on prepared columns (`false` unless there is one per row of `w`).
#[cfg_attr(not(any(bino_dsp, test)), allow(dead_code))]
#[inline(always)]
pub(crate) fn matmul_prepared_with(
    a: &[i8],
    w: &[i8],
    k: usize,
    prepared: &PreparedRequant<'_>,
    out: &mut [i8],
    driver: impl FnMut(&[i8], &[i8], usize, usize, &mut Fused<'_>) -> bool,
) -> bool {
    if prepared.channels() != w.len() / k.max(1) {
        return false;
    }
    let words = prepared.words;
    matmul_cols_with(a, w, k, |c| words.get(c).map(Col::from_words), out, driver)
}

/// The chunk loop of [`matmul_requant_with`] with column `c`'s parameters from `col`.
#[inline(always)]
fn matmul_cols_with(
    a: &[i8],
    w: &[i8],
    k: usize,
    col: impl Fn(usize) -> Option<Col>,
    out: &mut [i8],
    mut driver: impl FnMut(&[i8], &[i8], usize, usize, &mut Fused<'_>) -> bool,
) -> bool {
    let Some((m, n)) = shape(a, w, k, out.len()) else {
        return false;
    };
    let mut j0 = 0;
    while j0 < n {
        let len = (n - j0).min(CHUNK);
        let mut epi = Fused {
            params: [Col::ZERO; CHUNK],
            spare: [0; CHUNK],
            out: &mut *out,
            n,
            j0,
        };
        for (i, p) in epi.params[..len].iter_mut().enumerate() {
            let Some(c) = col(j0 + i) else {
                return false;
            };
            *p = c;
        }
        let w_chunk = w.get(j0 * k..(j0 + len) * k).unwrap_or(&[]);
        if !driver(a, w_chunk, k, m, &mut epi) {
            return false;
        }
        j0 += len;
    }
    true
}

/// `out` (`m x n` int8) = `sat8(rq(a * w^T) + zero[c])` on this core's assembly kernel, equal
/// to `matmul_i8` followed by `requant_rows`; `false` where there is no kernel or the shape
/// or parameters are not taken (then `out` may be partly written: run the reference over it).
#[inline]
pub fn matmul_requant<B, M, Z>(
    a: &[i8],
    w: &[i8],
    k: usize,
    rq: &ChannelRequant<'_, B, M>,
    zero: &Z,
    out: &mut [i8],
) -> bool
where
    B: I32s + ?Sized,
    M: I32s + ?Sized,
    Z: I32s + ?Sized,
{
    #[cfg(bino_dsp)]
    return matmul_requant_with(a, w, k, rq, zero, out, |a, w, k, m, epi| super::run(a, w, k, m, epi));
    // Whole rows of column triples with their epilogue in one Helium kernel.
    #[cfg(bino_mve)]
    return matmul_requant_with(a, w, k, rq, zero, out, super::mve::gemm_fused);
    #[cfg(not(any(bino_dsp, bino_mve)))]
    {
        let _ = (a, w, k, rq, zero, out);
        false
    }
}

/// [`matmul_requant`] on columns prepared once ([`PreparedRequant`]); `acc` (at least the
/// output's length) holds the Cortex-M55's accumulators between its two kernels.
#[inline]
pub fn matmul_requant_prepared(
    a: &[i8],
    w: &[i8],
    k: usize,
    prepared: &PreparedRequant<'_>,
    acc: &mut [i32],
    out: &mut [i8],
) -> bool {
    #[cfg(bino_dsp)]
    let _ = acc;
    #[cfg(bino_dsp)]
    return matmul_prepared_with(a, w, k, prepared, out, |a, w, k, m, epi| super::run(a, w, k, m, epi));
    // Every accumulator first, then the requantisation two rows at a time in vector lanes.
    #[cfg(bino_mve)]
    return super::mve::gemm_prepared(a, w, k, prepared.records(), acc, out);
    // The x86 matrix multiply, then the requantisation eight columns at a time.
    #[cfg(target_arch = "x86_64")]
    return super::x86::matmul_requant_prepared(a, w, k, prepared.records(), acc, out);
    #[cfg(not(any(bino_dsp, bino_mve, target_arch = "x86_64")))]
    {
        let _ = (a, w, k, prepared, acc, out);
        false
    }
}
