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
    /// Words of storage the parameters of `n` channels take.
    pub const fn storage_words(n: usize) -> usize {
        n.div_ceil(CHANNEL_CHUNK) * CHUNK_WORDS
    }

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
        let words = Self::storage_words(n);
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
            // x86 with AVX2: the prepared lanes eight channels a vector, all rows at once.
            #[cfg(target_arch = "x86_64")]
            if let Some(p) = prepared.filter(|p| p.n == n && !p.per_channel) {
                if crate::kernels::arch::x86::avx2::residual::residual_rows(x, acc, n, rows, p.params) {
                    return;
                }
            }
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

// The 32-bit lane form of a chunk: Helium on Cortex-M55, a portable twin elsewhere.
mod residual_lanes;

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
mod tests;
