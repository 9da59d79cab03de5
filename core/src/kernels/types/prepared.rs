//! Requantisation columns prepared for the fused GEMM epilogue: per channel, the bias, the
//! multiplier, `addend = 2^(s-1) + zero * 2^s` and `s = shift - 32`, so that
//! `sat8(rq(acc) + zero) = sat8((hi32(acc * mult) + addend) >> s)` in 32 bits for
//! `shift = 32 + s`, `|acc| < 2^30` and `|bias| < 2^30` (the identity is proven in
//! `kernels::arch`'s fused epilogue).

use super::params::I32s;
use super::requant::ChannelRequant;

/// One channel's prepared parameters. `repr(C)`: the Helium row kernel gathers them by byte
/// offset (`bias` at 0, `mult` at 4, `addend` at 8, `s` at 12).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(C)]
pub(crate) struct Col {
    pub(crate) bias: i32,
    pub(crate) mult: i32,
    /// `2^(s-1) + zero * 2^s`.
    pub(crate) addend: i32,
    /// `shift - 32`, in `1..=30`.
    pub(crate) s: u32,
}

impl Col {
    pub(crate) const ZERO: Col = Col {
        bias: 0,
        mult: 0,
        addend: 0,
        s: 1,
    };

    /// The channel's parameters, or `None` outside the 32-bit range (see the type).
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
    pub(crate) fn to_words(self) -> [i32; 4] {
        [self.bias, self.mult, self.addend, self.s as i32]
    }

    /// The column [`Col::to_words`] kept (checked by [`Col::new`] when it was prepared).
    #[inline(always)]
    pub(crate) fn from_words(w: &[i32; 4]) -> Col {
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

/// A requantisation's columns prepared once (every channel checked for the fused range: shifts
/// 33 to 62, bias and addend below 2^30), for the calls of a pass that share it: each call then
/// copies four words a column instead of reading and checking its parameters (the engine's values and MLP-up GEMMs run once per token block).
/// The words live in storage the caller lends (four per channel).
pub struct PreparedRequant<'a> {
    pub(crate) words: &'a [[i32; 4]],
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
pub(crate) fn requant_col<B, M, Z>(rq: &ChannelRequant<'_, B, M>, zero: &Z, c: usize) -> Option<Col>
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
