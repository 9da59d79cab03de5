//! Requantisation parameters: per-channel rescaling of accumulators and of residual codes, and
//! the 32-bit lane form of a channel chunk the vector kernels take.

use super::params::I32s;
use crate::fixed::Requant;

/// Per-output-channel `acc -> (acc + bias[c]) * mult[c] / 2^shift[c]`.
#[derive(Clone, Copy)]
pub struct ChannelRequant<'p, B: I32s + ?Sized, M: I32s + ?Sized> {
    /// Bias in accumulator units.
    pub bias: &'p B,
    /// Fixed-point multipliers.
    pub mult: &'p M,
    /// Right shifts (validated `1..=62` when the weights are loaded).
    pub shift: &'p [u8],
}

impl<B: I32s + ?Sized, M: I32s + ?Sized> ChannelRequant<'_, B, M> {
    /// Output channels.
    pub fn channels(&self) -> usize {
        self.shift.len()
    }

    /// Channel `c` of an accumulator, rescaled (not yet saturated).
    #[inline(always)]
    pub fn apply(&self, c: usize, acc: i32) -> i64 {
        let shift = self.shift.get(c).copied().unwrap_or(1) as u32;
        let r = Requant {
            mult: self.mult.at(c),
            shift,
        };
        r.apply_i64(acc as i64 + self.bias.at(c) as i64)
    }
}

/// The residual stream's per-channel int8 format: real value = `scale[c] * (q - zero[c])`.
/// The scales themselves never appear in the int8 path: only ratios between formats do.
#[derive(Clone, Copy)]
pub struct ChannelRescale<'p, Z: I32s + ?Sized, M: I32s + ?Sized> {
    /// Zero points of the input format.
    pub zero: &'p Z,
    /// Multipliers from the input format's scale to the output format's.
    pub mult: &'p M,
    /// Their shifts.
    pub shift: &'p [u8],
}

impl<Z: I32s + ?Sized, M: I32s + ?Sized> ChannelRescale<'_, Z, M> {
    /// Channel `c` of an input code, rescaled to the output format (not yet saturated).
    #[inline(always)]
    pub fn apply(&self, c: usize, q: i8) -> i64 {
        let shift = self.shift.get(c).copied().unwrap_or(1) as u32;
        let r = Requant {
            mult: self.mult.at(c),
            shift,
        };
        r.apply_i64(q as i64 - self.zero.at(c) as i64)
    }
}

/// Channels whose requantisation parameters are decoded at once (1 KiB of stack).
pub const CHANNEL_CHUNK: usize = 64;

/// One chunk of [`ChannelRequant`] decoded into plain arrays, for formats in which the exact
/// arithmetic needs no saturation: `|bias| < 2^30` and shifts in `1..=62` make
/// `|(acc + bias) * mult| < 1.5 * 2^62`, so adding the rounding half cannot overflow and the
/// result equals [`ChannelRequant::apply`] bit for bit. The quantiser only makes such formats.
pub(crate) struct ChunkParams {
    pub bias: [i32; CHANNEL_CHUNK],
    pub mult: [i32; CHANNEL_CHUNK],
    pub shift: [u32; CHANNEL_CHUNK],
}

impl ChunkParams {
    pub(crate) fn decode<B: I32s + ?Sized, M: I32s + ?Sized>(
        rq: &ChannelRequant<'_, B, M>,
        start: usize,
        len: usize,
    ) -> Option<Self> {
        let mut p = ChunkParams {
            bias: [0; CHANNEL_CHUNK],
            mult: [0; CHANNEL_CHUNK],
            shift: [1; CHANNEL_CHUNK],
        };
        for i in 0..len.min(CHANNEL_CHUNK) {
            let c = start + i;
            let (bias, shift) = (rq.bias.at(c), rq.shift.get(c).copied().unwrap_or(1) as u32);
            if bias.unsigned_abs() >= 1 << 30 || !(1..=62).contains(&shift) {
                return None;
            }
            (p.bias[i], p.mult[i], p.shift[i]) = (bias, rq.mult.at(c), shift);
        }
        Some(p)
    }

    /// [`ChannelRequant::apply`] for channel `start + i`, without saturation (see the type).
    #[inline(always)]
    pub(crate) fn apply(&self, i: usize, acc: i32) -> i64 {
        let i = i % CHANNEL_CHUNK;
        let product = (acc as i64 + self.bias[i] as i64).wrapping_mul(self.mult[i] as i64);
        let shift = self.shift[i] & 63;
        product.wrapping_add(1i64 << ((shift.wrapping_sub(1)) & 63)) >> shift
    }
}

/// A chunk whose every shift lies in `33..=62`, rewritten for 32-bit lanes (the identity
/// proven in `kernels::arch`'s fused epilogue): for `|acc| < 2^30` and `|bias| < 2^30`,
/// `sat8(rq(acc) + zero) = sat8((hi32((acc + bias) * mult) + addend) >> s)` with
/// `s = shift - 32` and `addend = 2^(s-1) + zero * 2^s`. Host builds run it eight channels
/// at a time (AVX2); elsewhere it is never built.
#[cfg_attr(not(target_arch = "x86_64"), allow(dead_code))]
pub(crate) struct NarrowChunk {
    pub bias: [i32; CHANNEL_CHUNK],
    pub mult: [i32; CHANNEL_CHUNK],
    pub addend: [i32; CHANNEL_CHUNK],
    pub s: [i32; CHANNEL_CHUNK],
    pub len: usize,
}
