//! The residual add: a layer's output added to the residual stream while the stream moves to
//! the next stage's per-channel format, `x <- sat(carry(x) + delta(acc) + new_zero)`.

use crate::fixed::sat_i8_i64;
pub use crate::kernels::reference::residual::residual_add_reference;
use crate::kernels::types::requant::{ChannelRequant, ChannelRescale, ChunkParams, CHANNEL_CHUNK};
use crate::kernels::I32s;

/// `x <- sat(carry(x) + delta(acc) + new_zero)`: adds a layer's output to the residual stream
/// while moving the stream to the next stage's per-channel format.
pub fn residual_add<Z, M, B, M2, Z2>(
    x: &mut [i8],
    carry: &ChannelRescale<'_, Z, M>,
    acc: &[i32],
    delta: &ChannelRequant<'_, B, M2>,
    new_zero: &Z2,
) where
    Z: I32s + ?Sized,
    M: I32s + ?Sized,
    B: I32s + ?Sized,
    M2: I32s + ?Sized,
    Z2: I32s + ?Sized,
{
    residual_add_prepared(x, carry, acc, delta, new_zero, None);
}

/// A residual add's lane parameters prepared once for the calls of a pass that share them (the
/// encoder adds one token block at a time), in storage the caller lends (ten words a channel,
/// rounded up to whole chunks of 64), instead of once per call.
pub struct PreparedResidual<'s> {
    params: &'s [i32],
    n: usize,
    per_channel: bool,
}

impl<'s> PreparedResidual<'s> {
    /// The parameters for blocks of `rows` rows; `None` where a channel is outside the lanes'
    /// bounds or `storage` is short (then [`residual_add`]).
    pub fn new<Z, M, B, M2, Z2>(
        carry: &ChannelRescale<'_, Z, M>,
        delta: &ChannelRequant<'_, B, M2>,
        new_zero: &Z2,
        rows: usize,
        storage: &'s mut [i32],
    ) -> Option<Self>
    where
        Z: I32s + ?Sized,
        M: I32s + ?Sized,
        B: I32s + ?Sized,
        M2: I32s + ?Sized,
        Z2: I32s + ?Sized,
    {
        let n = delta.channels();
        let per_channel = residual_lanes::per_channel(rows, n);
        let words = n.div_ceil(CHANNEL_CHUNK) * CHUNK_WORDS;
        let params = storage.get_mut(..words).filter(|_| n > 0)?;
        for (i, chunk) in params.chunks_exact_mut(CHUNK_WORDS).enumerate() {
            let start = i * CHANNEL_CHUNK;
            let len = (n - start).min(CHANNEL_CHUNK);
            if !residual_lanes::chunk_params(carry, delta, new_zero, start, len, per_channel, chunk) {
                return None;
            }
        }
        Some(PreparedResidual { params, n, per_channel })
    }
}

/// Words of one chunk's lane parameters.
const CHUNK_WORDS: usize = CHANNEL_CHUNK * residual_lanes::VECTORS;

/// [`residual_add`] with the lanes' parameters prepared once where `prepared` has them for
/// this call's shape (else decoded for this call).
pub fn residual_add_prepared<Z, M, B, M2, Z2>(
    x: &mut [i8],
    carry: &ChannelRescale<'_, Z, M>,
    acc: &[i32],
    delta: &ChannelRequant<'_, B, M2>,
    new_zero: &Z2,
    prepared: Option<&PreparedResidual<'_>>,
) where
    Z: I32s + ?Sized,
    M: I32s + ?Sized,
    B: I32s + ?Sized,
    M2: I32s + ?Sized,
    Z2: I32s + ?Sized,
{
    crate::kernels::arch::vectorised(
        #[inline(always)]
        || {
            let n = delta.channels();
            if n == 0 {
                return;
            }
            let rows = x.len().min(acc.len()) / n;
            // The lanes' bound on the accumulators, checked once for every chunk.
            // (Not on x86 hosts: there the 64-bit chunk vectorises better than the lanes' groups of 4.)
            let small = cfg!(any(bino_mve, bino_dsp, test))
                && residual_lanes::accumulators_fit(acc.get(..rows * n).unwrap_or(&[]));
            let mut start = 0;
            while start < n {
                let len = (n - start).min(CHANNEL_CHUNK);
                let chunk = residual_lanes::Chunk {
                    n,
                    start,
                    len,
                    rows,
                    small,
                };
                let prepared_params = prepared
                    .filter(|p| p.n == n && p.per_channel == residual_lanes::per_channel(rows, n))
                    .and_then(|p| p.params.get(start / CHANNEL_CHUNK * CHUNK_WORDS..))
                    .and_then(|p| p.get(..len.div_ceil(4) * 4 * residual_lanes::VECTORS));
                let done = match prepared_params {
                    Some(params) if small => {
                        residual_lanes::run_chunk(x, acc, &chunk, params, residual_lanes::per_channel(rows, n))
                    }
                    _ => small && residual_lanes::add_chunk(x, acc, &chunk, carry, delta, new_zero),
                };
                if done {
                    start += len;
                    continue;
                }
                match (
                    ChunkParams::decode(delta, start, len),
                    CarryParams::decode(carry, start, len),
                ) {
                    (Some(d), Some(k)) => {
                        let mut zeros = [0i64; CHANNEL_CHUNK];
                        for (i, z) in zeros[..len].iter_mut().enumerate() {
                            *z = new_zero.at(start + i) as i64;
                        }
                        #[cfg(target_arch = "x86_64")]
                        let done = crate::kernels::arch::x86::vnni::with_avx512(|| {
                            add_decoded_rows(x, acc, &chunk, &d, &k, &zeros)
                        })
                        .is_some();
                        #[cfg(not(target_arch = "x86_64"))]
                        let done = false;
                        if !done {
                            add_decoded_rows(x, acc, &chunk, &d, &k, &zeros);
                        }
                    }
                    _ => {
                        for r in 0..rows {
                            for c in start..start + len {
                                let i = r * n + c;
                                if let (Some(xq), Some(&a)) = (x.get_mut(i), acc.get(i)) {
                                    let value = carry.apply(c, *xq) + delta.apply(c, a) + new_zero.at(c) as i64;
                                    *xq = sat_i8_i64(value);
                                }
                            }
                        }
                    }
                }
                start += len;
            }
        },
    )
}

/// One decoded chunk of [`residual_add_prepared`] over every row, in 64-bit arithmetic.
#[inline(always)]
fn add_decoded_rows(
    x: &mut [i8],
    acc: &[i32],
    chunk: &residual_lanes::Chunk,
    d: &ChunkParams,
    k: &CarryParams,
    zeros: &[i64; CHANNEL_CHUNK],
) {
    let (n, start, len) = (chunk.n, chunk.start, chunk.len);
    for r in 0..chunk.rows {
        let at = r * n + start..r * n + start + len;
        let (Some(x_part), Some(acc_part)) = (x.get_mut(at.clone()), acc.get(at)) else {
            break;
        };
        for (i, (xq, &a)) in x_part.iter_mut().zip(acc_part).enumerate() {
            *xq = sat_i8_i64(k.apply(i, *xq) + d.apply(i, a) + zeros[i % CHANNEL_CHUNK]);
        }
    }
}

/// A chunk of the residual add in 32-bit lanes: a Helium loop per row on Cortex-M55
/// (`kernels::arch`), a portable twin elsewhere: on Cortex-M7 (scalar, but each 64-bit product
/// and shift becomes one `smmul` and 32-bit operations) and in host tests (the same lane
/// arithmetic, so the tests
/// prove the identities the loop relies on).
///
/// For a product `P` and a shift `s`, `(P + 2^(s-1)) >> s` equals
/// `(hi32(P 2^e) + 2^(s-33+e)) >> (s - 32 + e)` whenever `s - 32 + e >= 1` (the low bits of
/// `P 2^e` cannot carry past a multiple of the divisor): one high-half multiply (`vmulh.s32`),
/// an add and a per-lane shift. The delta's `acc + bias` takes `e = 0` (shifts from 33; it
/// stays in 32 bits for `|acc| < 2^30`, checked per block, and `|bias| < 2^30`); the carry's
/// `q - zero`, below `2^16`, is first shifted left by `e = 15` (shifts 18 to 47: a format
/// change near 1 has a shift near 31) or by 0 (shifts 48 to 62). With `|new_zero| < 2^29` the
/// sum of the three stays in 32 bits. Other chunks take the scalar path.
mod residual_lanes {
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
}

/// One chunk of a [`ChannelRescale`] decoded into plain arrays, for zero points within
/// `2^15` (quantiser-made formats: below `2^9`): `|q - zero| < 2^16` and `|mult| <= 2^31` keep
/// the product below `2^47`, so no saturation is reachable and plain arithmetic equals
/// [`ChannelRescale::apply`] bit for bit.
struct CarryParams {
    zero: [i32; CHANNEL_CHUNK],
    mult: [i32; CHANNEL_CHUNK],
    shift: [u32; CHANNEL_CHUNK],
}

impl CarryParams {
    fn decode<Z: I32s + ?Sized, M: I32s + ?Sized>(
        carry: &ChannelRescale<'_, Z, M>,
        start: usize,
        len: usize,
    ) -> Option<Self> {
        let mut p = CarryParams {
            zero: [0; CHANNEL_CHUNK],
            mult: [0; CHANNEL_CHUNK],
            shift: [1; CHANNEL_CHUNK],
        };
        for i in 0..len.min(CHANNEL_CHUNK) {
            let c = start + i;
            let (zero, shift) = (carry.zero.at(c), carry.shift.get(c).copied().unwrap_or(1) as u32);
            if zero.unsigned_abs() > 1 << 15 || !(1..=62).contains(&shift) {
                return None;
            }
            (p.zero[i], p.mult[i], p.shift[i]) = (zero, carry.mult.at(c), shift);
        }
        Some(p)
    }

    /// [`ChannelRescale::apply`] for channel `start + i`, without saturation (see the type).
    #[inline(always)]
    fn apply(&self, i: usize, q: i8) -> i64 {
        let i = i % CHANNEL_CHUNK;
        let product = (q as i32 - self.zero[i]) as i64 * self.mult[i] as i64;
        let shift = self.shift[i] & 63;
        (product + (1i64 << (shift.wrapping_sub(1) & 63))) >> shift
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::params::Uniform;
    use crate::testutil::{requant_of, Rng};

    fn factor(real: f64) -> (i32, u8) {
        let r = requant_of(real);
        (r.mult, r.shift as u8)
    }

    #[test]
    fn residual_add_equals_the_per_channel_formula_across_chunks() {
        const N: usize = 130;
        let mut rng = Rng::new(13);
        for trial in 0..6 {
            let mult: [i32; N] = core::array::from_fn(|_| rng.range(1 << 30, i32::MAX as i64) as i32);
            let shift: [u8; N] = core::array::from_fn(|_| rng.range(20, 45) as u8);
            let cmult: [i32; N] = core::array::from_fn(|_| rng.range(1 << 30, i32::MAX as i64) as i32);
            let cshift: [u8; N] = core::array::from_fn(|_| rng.range(28, 34) as u8);
            let mut bias: [i32; N] = core::array::from_fn(|_| rng.range(-1 << 20, 1 << 20) as i32);
            let mut zero: [i32; N] = core::array::from_fn(|_| rng.range(-300, 300) as i32);
            if trial >= 3 {
                // Parameters no quantiser makes: those chunks take the saturating path.
                bias[70] = i32::MIN;
                zero[5] = i32::MAX;
            }
            let new_zero: [i32; N] = core::array::from_fn(|_| rng.range(-128, 127) as i32);
            let delta = ChannelRequant {
                bias: &bias,
                mult: &mult,
                shift: &shift,
            };
            let carry = ChannelRescale {
                zero: &zero,
                mult: &cmult,
                shift: &cshift,
            };
            let acc: [i32; 3 * N] = core::array::from_fn(|_| {
                if trial % 3 == 2 {
                    rng.range(i32::MIN as i64, i32::MAX as i64) as i32
                } else {
                    rng.range(-1 << 24, 1 << 24) as i32
                }
            });
            let mut x = [0i8; 3 * N];
            rng.fill_i8(&mut x);
            let before = x;
            residual_add(&mut x, &carry, &acc, &delta, &new_zero);
            for i in 0..3 * N {
                let c = i % N;
                let want = sat_i8_i64(carry.apply(c, before[i]) + delta.apply(c, acc[i]) + new_zero[c] as i64);
                assert_eq!(x[i], want, "trial {trial} index {i}");
            }
        }
    }

    #[test]
    fn residual_lanes_equal_the_reference() {
        const N: usize = 128;
        const ROWS: usize = 8;
        let mut rng = Rng::new(77);
        for trial in 0..40 {
            let (lo, hi) = if trial % 5 == 4 { (10, 62) } else { (33, 62) };
            let mult: [i32; N] = core::array::from_fn(|_| rng.range(-(i32::MAX as i64), i32::MAX as i64) as i32);
            let shift: [u8; N] = core::array::from_fn(|_| rng.range(lo, hi) as u8);
            let cmult: [i32; N] = core::array::from_fn(|_| rng.range(-(i32::MAX as i64), i32::MAX as i64) as i32);
            // The carry's shifts from 18 (a format change near 1 has a shift near 31).
            let cshift: [u8; N] = core::array::from_fn(|_| rng.range(lo.min(18) + 8 * (trial % 2), hi) as u8);
            let bias: [i32; N] = core::array::from_fn(|_| rng.range(-(1 << 30) + 1, (1 << 30) - 1) as i32);
            let zero: [i32; N] = core::array::from_fn(|_| rng.range(-(1 << 15), 1 << 15) as i32);
            let new_zero: [i32; N] = core::array::from_fn(|_| {
                if trial % 7 == 6 {
                    rng.range(-(1 << 29) + 1, (1 << 29) - 1) as i32
                } else {
                    rng.range(-128, 127) as i32
                }
            });
            let delta = ChannelRequant {
                bias: &bias,
                mult: &mult,
                shift: &shift,
            };
            let carry = ChannelRescale {
                zero: &zero,
                mult: &cmult,
                shift: &cshift,
            };
            let acc: [i32; ROWS * N] = core::array::from_fn(|_| match trial % 4 {
                0 => rng.range(-(1 << 30) + 1, (1 << 30) - 1) as i32,
                1 => rng.range(i32::MIN as i64, i32::MAX as i64) as i32,
                _ => rng.range(-(1 << 22), 1 << 22) as i32,
            });
            let mut x = [0i8; ROWS * N];
            rng.fill_i8(&mut x);
            let mut want = x;
            // Where every identity holds, the lanes take the whole row block.
            if trial % 5 != 4 && trial % 4 != 1 {
                let mut lanes = x;
                for start in (0..N).step_by(CHANNEL_CHUNK) {
                    let len = CHANNEL_CHUNK.min(N - start);
                    let chunk = residual_lanes::Chunk {
                        n: N,
                        start,
                        len,
                        rows: ROWS,
                        small: residual_lanes::accumulators_fit(&acc),
                    };
                    assert!(residual_lanes::add_chunk(
                        &mut lanes, &acc, &chunk, &carry, &delta, &new_zero
                    ));
                }
                residual_add_reference(&mut want, &carry, &acc, &delta, &new_zero);
                assert_eq!(lanes, want, "trial {trial}: lanes");
                want = x;
            }
            // With the parameters prepared once (where every channel is in the lanes' bounds).
            let mut storage = [0i32; N * residual_lanes::VECTORS];
            let prepared = PreparedResidual::new(&carry, &delta, &new_zero, ROWS, &mut storage);
            assert_eq!(prepared.is_some(), trial % 5 != 4, "trial {trial}: prepared");
            let mut with_prepared = x;
            residual_add_prepared(&mut with_prepared, &carry, &acc, &delta, &new_zero, prepared.as_ref());
            residual_add(&mut x, &carry, &acc, &delta, &new_zero);
            residual_add_reference(&mut want, &carry, &acc, &delta, &new_zero);
            assert_eq!(x, want, "trial {trial}");
            assert_eq!(with_prepared, want, "trial {trial}: prepared");
        }
    }

    #[test]
    fn residual_add_changes_format_and_adds() {
        let (cm, cs) = factor(0.5);
        let (dm, ds) = factor(0.25);
        let carry = ChannelRescale {
            zero: &Uniform(10),
            mult: &[cm; 2],
            shift: &[cs; 2],
        };
        let delta = ChannelRequant {
            bias: &Uniform(4),
            mult: &[dm; 2],
            shift: &[ds; 2],
        };
        let mut x = [30i8, -10, 127, -128];
        let acc = [36, -4, 1000, -1000];
        residual_add(&mut x, &carry, &acc, &delta, &Uniform(-5));
        // (30-10)/2 + (36+4)/4 - 5 = 15; (-10-10)/2 + 0 - 5 = -15; saturated; saturated.
        assert_eq!(x, [15, -15, 127, -128]);
    }
}
