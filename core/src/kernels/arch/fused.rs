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
use crate::kernels::epilogue::ChannelRequant;
use crate::kernels::I32s;

/// Channels whose parameters are prepared at once (2 KiB of stack).
pub const CHUNK: usize = 128;

/// One channel's prepared parameters. `repr(C)`: the Helium row kernel gathers them by byte
/// offset (`bias` at 0, `mult` at 4, `addend` at 8, `s` at 12).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(C)]
pub(crate) struct Col {
    bias: i32,
    mult: i32,
    /// `2^(s-1) + zero * 2^s`.
    addend: i32,
    /// `shift - 32`, in `1..=30`.
    s: u32,
}

impl Col {
    const ZERO: Col = Col {
        bias: 0,
        mult: 0,
        addend: 0,
        s: 1,
    };

    /// The channel's parameters, or `None` outside the 32-bit range (see the module).
    pub(crate) fn new(bias: i32, mult: i32, shift: u8, zero: i32) -> Option<Col> {
        if bias.unsigned_abs() >= 1 << 30 || !(33..=62).contains(&shift) {
            return None;
        }
        let s = shift as u32 - 32;
        let addend = (1i64 << (s - 1)) + ((zero as i64) << s);
        if !(-(1i64 << 30)..1i64 << 30).contains(&addend) {
            return None;
        }
        Some(Col {
            bias,
            mult,
            addend: addend as i32,
            s,
        })
    }

    /// The bias, the accumulators' start.
    #[cfg(test)]
    pub(crate) fn bias(&self) -> i32 {
        self.bias
    }

    /// The four words a [`PreparedRequant`] keeps: bias, multiplier, addend, shift.
    fn to_words(self) -> [i32; 4] {
        [self.bias, self.mult, self.addend, self.s as i32]
    }

    /// The column [`Col::to_words`] kept (checked by [`Col::new`] when it was prepared).
    #[inline(always)]
    fn from_words(w: &[i32; 4]) -> Col {
        Col {
            bias: w[0],
            mult: w[1],
            addend: w[2],
            s: w[3] as u32 & 31,
        }
    }

    /// The int8 output of an accumulator that already holds the bias (`|acc| < 2^31`).
    #[inline(always)]
    pub(crate) fn apply(&self, acc: i32) -> i8 {
        // High half of the product (`smmla` with the addend): |high| <= 2^30 and
        // |addend| < 2^30, so the sum cannot wrap.
        let high = ((acc as i64 * self.mult as i64) >> 32) as i32;
        (high.wrapping_add(self.addend) >> (self.s & 31)).clamp(-128, 127) as i8
    }
}

/// Column parameters as the Helium requantisation reads them: `count()` records of 16 bytes
/// from `base()`, each `bias`, `mult`, `addend`, `s` ([`Col`]'s layout), checked by
/// [`Col::new`] when they were made.
#[cfg(any(bino_mve, test))]
pub(crate) trait ColRecords {
    /// Records held.
    fn count(&self) -> usize;
    /// The first record's first word.
    #[cfg_attr(not(bino_mve), allow(dead_code))]
    fn base(&self) -> *const i32;
    /// Column `j` (the portable kernels).
    #[cfg_attr(bino_mve, allow(dead_code))]
    fn col(&self, j: usize) -> Option<Col>;
}

const _: () = assert!(core::mem::size_of::<Col>() == 16 && core::mem::align_of::<Col>() == 4);

#[cfg(any(bino_mve, test))]
impl ColRecords for [Col] {
    fn count(&self) -> usize {
        self.len()
    }
    fn base(&self) -> *const i32 {
        self.as_ptr().cast()
    }
    fn col(&self, j: usize) -> Option<Col> {
        self.get(j).copied()
    }
}

#[cfg(any(bino_mve, test))]
impl ColRecords for [[i32; 4]] {
    fn count(&self) -> usize {
        self.len()
    }
    fn base(&self) -> *const i32 {
        self.as_ptr().cast()
    }
    fn col(&self, j: usize) -> Option<Col> {
        self.get(j).map(Col::from_words)
    }
}

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

/// A requantisation's columns prepared once (every channel checked for the fused range, see the
/// module), for the
/// calls of a pass that share it: each call then copies four words a column instead of reading
/// and checking its parameters (the engine's values and MLP-up GEMMs run once per token block).
/// The words live in storage the caller lends (four per channel).
pub struct PreparedRequant<'a> {
    words: &'a [[i32; 4]],
}

impl<'a> PreparedRequant<'a> {
    /// `rq` with output zero points `zero`, in `storage`; `None` where a channel is outside the
    /// fused kernels' range or `storage` holds fewer than four words a channel.
    pub fn new<B, M, Z>(rq: &ChannelRequant<'_, B, M>, zero: &Z, storage: &'a mut [i32]) -> Option<Self>
    where
        B: I32s + ?Sized,
        M: I32s + ?Sized,
        Z: I32s + ?Sized,
    {
        let n = rq.channels();
        let (words, _) = storage.as_chunks_mut::<4>();
        let words = words.get_mut(..n)?;
        for (c, slot) in words.iter_mut().enumerate() {
            *slot = requant_col(rq, zero, c)?.to_words();
        }
        Some(PreparedRequant { words })
    }

    /// Channels prepared.
    pub fn channels(&self) -> usize {
        self.words.len()
    }

    /// The prepared columns, one 16-byte record each.
    #[cfg_attr(not(any(bino_mve, test)), allow(dead_code))]
    pub(crate) fn records(&self) -> &[[i32; 4]] {
        self.words
    }
}

/// Column `c` of `rq` and `zero` (see [`Col::new`]).
#[inline(always)]
fn requant_col<B, M, Z>(rq: &ChannelRequant<'_, B, M>, zero: &Z, c: usize) -> Option<Col>
where
    B: I32s + ?Sized,
    M: I32s + ?Sized,
    Z: I32s + ?Sized,
{
    Col::new(
        rq.bias.at(c),
        rq.mult.at(c),
        rq.shift.get(c).copied().unwrap_or(0),
        zero.at(c),
    )
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
    #[cfg(not(any(bino_dsp, bino_mve)))]
    {
        let _ = (a, w, k, prepared, acc, out);
        false
    }
}
