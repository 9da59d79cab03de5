//! A chunk of the residual add in 32-bit lanes: a Helium loop per row on Cortex-M55
//! (`kernels::arch`), a portable twin elsewhere: on Cortex-M7 (scalar, but each 64-bit product
//! and shift becomes one `smmul` and 32-bit operations) and in host tests (the same lane
//! arithmetic, so the tests prove the identities the loop relies on).
//!
//! For a product `P` and a shift `s`, `(P + 2^(s-1)) >> s` equals
//! `(hi32(P 2^e) + 2^(s-33+e)) >> (s - 32 + e)` whenever `s - 32 + e >= 1` (the low bits of
//! `P 2^e` cannot carry past a multiple of the divisor): one high-half multiply (`vmulh.s32`),
//! an add and a per-lane shift. The delta's `acc + bias` takes `e = 0` (shifts from 33; it
//! stays in 32 bits for `|acc| < 2^30`, checked per block, and `|bias| < 2^30`); the carry's
//! `q - zero`, below `2^16`, is first shifted left by `e = 15` (shifts 18 to 47: a format
//! change near 1 has a shift near 31) or by 0 (shifts 48 to 62). With `|new_zero| < 2^29` the
//! sum of the three stays in 32 bits. Other chunks take the scalar path.

use super::{ChannelRequant, ChannelRescale, CHANNEL_CHUNK};
/// The Cortex-M7's block shape for its per-channel kernel (never matched elsewhere).
#[cfg(bino_dsp)]
use crate::kernels::arch::dsp::{RESIDUAL_ROWS, RESIDUAL_STRIDE, RESIDUAL_WORDS};
use crate::kernels::I32s;
#[cfg(not(bino_dsp))]
const RESIDUAL_ROWS: usize = 0;
#[cfg(not(bino_dsp))]
const RESIDUAL_STRIDE: usize = 0;

/// Per group of four channels: carry zero, left shift, multiplier, rounding term, negated
/// shift; delta bias, multiplier, rounding term, negated shift; the new zero point.
pub(super) const VECTORS: usize = 10;
#[cfg(bino_dsp)]
const _: () = assert!(
    RESIDUAL_WORDS == VECTORS,
    "a channel's parameters fill one group's lane"
);

/// Where a chunk lies: channels `start..start + len` of rows of `n`, `rows` rows; `small`:
/// the block's accumulators passed [`accumulators_fit`].
pub(super) struct Chunk {
    pub n: usize,
    pub start: usize,
    pub len: usize,
    pub rows: usize,
    pub small: bool,
}

/// Whether every accumulator of a block is below `2^30` in magnitude (the delta's bound).
#[cfg_attr(not(any(bino_mve, bino_dsp, test)), allow(dead_code))]
pub(super) fn accumulators_fit(acc: &[i32]) -> bool {
    // Cortex-M7: the bits of every magnitude ORed in assembly, which also lets -2^30 in:
    // its kernel adds a bias below 2^30 in magnitude, still without overflow.
    #[cfg(bino_dsp)]
    if let Some(bits) = crate::kernels::arch::dsp::magnitude_bits(acc) {
        return bits < 1 << 30;
    }
    acc.iter().fold(0u32, |m, &a| m.max(a.unsigned_abs())) < 1 << 30
}

/// The chunk added in lanes; `false` (nothing written) where an identity of the module
/// does not hold.
#[cfg_attr(not(any(bino_mve, bino_dsp, test)), allow(dead_code))]
pub(super) fn add_chunk<Z, M, B, M2, Z2>(
    x: &mut [i8],
    acc: &[i32],
    chunk: &Chunk,
    carry: &ChannelRescale<'_, Z, M>,
    delta: &ChannelRequant<'_, B, M2>,
    new_zero: &Z2,
) -> bool
where
    Z: I32s + ?Sized,
    M: I32s + ?Sized,
    B: I32s + ?Sized,
    M2: I32s + ?Sized,
    Z2: I32s + ?Sized,
{
    let Chunk {
        n,
        start,
        len,
        rows,
        small,
    } = *chunk;
    if !small || len == 0 || len > CHANNEL_CHUNK || start + len > n {
        return false;
    }
    let per_channel = per_channel(rows, n);
    let mut params = [0i32; CHANNEL_CHUNK * VECTORS];
    if !chunk_params(carry, delta, new_zero, start, len, per_channel, &mut params) {
        return false;
    }
    run_chunk(x, acc, chunk, &params[..len.div_ceil(4) * 4 * VECTORS], per_channel)
}

/// Cortex-M7, a full block of the encoder's stream: one channel's ten parameters together
/// (`arch::residual_rows8`), in place of the lanes' groups of four.
#[inline(always)]
pub(super) fn per_channel(rows: usize, n: usize) -> bool {
    cfg!(bino_dsp) && rows == RESIDUAL_ROWS && n == RESIDUAL_STRIDE
}

/// The parameters of channels `start..start + len` in `params` (groups of four lanes, ten
/// vectors each, or with `per_channel` ten words per channel); `false` where a channel is
/// outside this module's bounds.
pub(super) fn chunk_params<Z, M, B, M2, Z2>(
    carry: &ChannelRescale<'_, Z, M>,
    delta: &ChannelRequant<'_, B, M2>,
    new_zero: &Z2,
    start: usize,
    len: usize,
    per_channel: bool,
    params: &mut [i32],
) -> bool
where
    Z: I32s + ?Sized,
    M: I32s + ?Sized,
    B: I32s + ?Sized,
    M2: I32s + ?Sized,
    Z2: I32s + ?Sized,
{
    let groups = len.div_ceil(4);
    if params.len() < groups * 4 * VECTORS {
        return false;
    }
    for (g, group) in params.chunks_exact_mut(4 * VECTORS).take(groups).enumerate() {
        // A fixed-size group: the stores below need no bounds checks.
        let Ok(group) = <&mut [i32; 4 * VECTORS]>::try_from(group) else {
            return false;
        };
        for lane in 0..4 {
            let c = start + 4 * g + lane;
            if c >= start + len {
                break;
            }
            let (ks, ds) = (
                carry.shift.get(c).copied().unwrap_or(0) as u32,
                delta.shift.get(c).copied().unwrap_or(0) as u32,
            );
            let (czero, bias, zero) = (carry.zero.at(c), delta.bias.at(c), new_zero.at(c));
            // ChunkParams' and CarryParams' bounds, and this module's.
            if !(18..=62).contains(&ks)
                || !(33..=62).contains(&ds)
                || czero.unsigned_abs() > 1 << 15
                || bias.unsigned_abs() >= 1 << 30
                || zero.unsigned_abs() >= 1 << 29
            {
                return false;
            }
            let pre = if ks <= 47 { 15 } else { 0 };
            if per_channel {
                let values = [
                    bias,
                    delta.mult.at(c),
                    1 << (ds - 33),
                    ds as i32 - 32,
                    zero,
                    czero,
                    pre as i32,
                    carry.mult.at(c),
                    1 << (ks + pre - 33),
                    (ks + pre) as i32 - 32,
                ];
                if let Some(slots) = group.get_mut(lane * VECTORS..(lane + 1) * VECTORS) {
                    slots.copy_from_slice(&values);
                }
                continue;
            }
            let values = [
                czero,
                pre as i32,
                carry.mult.at(c),
                1 << (ks + pre - 33),
                32 - (ks + pre) as i32,
                bias,
                delta.mult.at(c),
                1 << (ds - 33),
                32 - ds as i32,
                zero,
            ];
            for (v, value) in values.into_iter().enumerate() {
                if let Some(slot) = group.get_mut(v * 4 + lane) {
                    *slot = value;
                }
            }
        }
    }
    true
}

/// The chunk's rows on its parameters (from [`chunk_params`] with the same `per_channel`).
pub(super) fn run_chunk(x: &mut [i8], acc: &[i32], chunk: &Chunk, params: &[i32], per_channel: bool) -> bool {
    let Chunk {
        n, start, len, rows, ..
    } = *chunk;
    #[cfg(bino_dsp)]
    if per_channel {
        let (Some(x_part), Some(acc_part)) = (x.get_mut(start..), acc.get(start..)) else {
            return false;
        };
        return crate::kernels::arch::residual_rows8(x_part, acc_part, params, len);
    }
    let _ = per_channel;
    for r in 0..rows {
        let at = r * n + start..r * n + start + len;
        let (Some(x_part), Some(acc_part)) = (x.get_mut(at.clone()), acc.get(at)) else {
            return false;
        };
        // Only the first row can be declined (the checks are the same for every row).
        if !add_row(x_part, acc_part, params) {
            return false;
        }
    }
    true
}

/// One row of the chunk: `x <- sat8(carry(x) + delta(acc) + zero)` in lanes.
#[inline(always)]
fn add_row(x: &mut [i8], acc: &[i32], params: &[i32]) -> bool {
    #[cfg(bino_mve)]
    return crate::kernels::arch::residual_add_row(x, acc, params);
    #[cfg(not(bino_mve))]
    {
        let high = |a: i32, b: i32| ((a as i64 * b as i64) >> 32) as i32;
        for ((xs, accs), g) in x.chunks_mut(4).zip(acc.chunks(4)).zip(params.chunks_exact(4 * VECTORS)) {
            for (lane, (xq, &a)) in xs.iter_mut().zip(accs).enumerate() {
                let at = |v: usize| g.get(v * 4 + lane).copied().unwrap_or(0);
                let centred = (*xq as i32).wrapping_sub(at(0)) << (at(1) & 31);
                let carry = high(centred, at(2)).wrapping_add(at(3)) >> (-at(4) & 31);
                let delta = high(a.wrapping_add(at(5)), at(6)).wrapping_add(at(7)) >> (-at(8) & 31);
                *xq = carry.wrapping_add(delta).wrapping_add(at(9)).clamp(-128, 127) as i8;
            }
        }
        true
    }
}
