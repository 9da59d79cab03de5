//! The one place that picks an instruction set for the portable kernels' loops at run time.
//!
//! Cortex-M builds choose at compile time (target features, `build.rs`'s `bino_dsp` /
//! `bino_mve`), so there this is the plain call. On x86-64 the CPU is asked once (`cpuid`):
//! a crate that depends on `bino-core` gets the AVX2 and AVX-512 VNNI kernels with no
//! `-C target-cpu` flag, and [`active`] says which run.

use super::attention::{self, AttentionQ, KeyLayout, QUERY_BLOCK};
use crate::config::HEAD_DIM;

/// The instruction set whose kernels run in this process.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Isa {
    /// x86-64 with AVX-512 F/DQ/BW/VL and VNNI (with the AVX2 kernels where VNNI has none).
    Avx512Vnni,
    /// x86-64 with AVX2.
    Avx2,
    /// Cortex-M7 (Armv7E-M DSP extension: `smlad`).
    Dsp,
    /// Cortex-M55 (Helium, MVE).
    Mve,
    /// The portable kernels only (the reference).
    Portable,
}

impl Isa {
    /// Its name in reports: `avx512-vnni`, `avx2`, `dsp`, `mve` or `portable`.
    pub const fn name(self) -> &'static str {
        match self {
            Isa::Avx512Vnni => "avx512-vnni",
            Isa::Avx2 => "avx2",
            Isa::Dsp => "dsp",
            Isa::Mve => "mve",
            Isa::Portable => "portable",
        }
    }
}

/// The kernels that run now (x86: detected at the first kernel call, or by this call).
pub fn active() -> Isa {
    #[cfg(target_arch = "x86_64")]
    {
        use super::arch::x86;
        if x86::vnni::available() {
            return Isa::Avx512Vnni;
        }
        if x86::avx2() {
            return Isa::Avx2;
        }
    }
    if cfg!(bino_dsp) {
        Isa::Dsp
    } else if cfg!(bino_mve) {
        Isa::Mve
    } else {
        Isa::Portable
    }
}

/// Caps the x86 kernels for this process, to measure or test the slower ones on a fast CPU:
/// `Avx512Vnni` (no cap), `Avx2` (no VNNI) or `Portable` (no x86 kernels at all). Returns
/// [`active`] afterwards (never more than the CPU has). A no-op elsewhere.
pub fn limit(to: Isa) -> Isa {
    #[cfg(target_arch = "x86_64")]
    {
        use super::arch::x86;
        let avx2 = x86::allow_avx2(!matches!(to, Isa::Portable));
        x86::vnni::enable(avx2 && matches!(to, Isa::Avx512Vnni));
    }
    let _ = to;
    active()
}

/// Stores token `t`'s values channel-major (`store[c * tokens + t] = token[c]`, `DIM x tokens`):
/// each head's slice is then the `HEAD_DIM x tokens` transposed layout attention reads. The
/// Cortex-M55's Helium scatter where it takes the shape, else the plain loop.
pub fn scatter_channels(token: &[i8], store: &mut [i8], tokens: usize, t: usize) {
    if super::arch::scatter_channels(token, store, tokens, t) {
        return;
    }
    for (channel, &v) in store.chunks_exact_mut(tokens).zip(token) {
        if let Some(slot) = channel.get_mut(t) {
            *slot = v;
        }
    }
}

/// Whether this core's GEMMs take requantisation columns prepared once per pass
/// ([`PreparedRequant`](super::types::prepared::PreparedRequant)): the Cortex-M assembly kernels
/// fuse the requantisation into their tiles; elsewhere the columns would go unused.
pub const PREPARED_GEMM: bool = cfg!(any(bino_dsp, bino_mve));

/// One query block's attention over keys stored in `layout` (see
/// [`attention::attend_block`]): the x86 VNNI scores on
/// transposed keys where the keys were stored so, the block kernels of this core otherwise.
#[allow(clippy::too_many_arguments)]
#[inline]
pub fn attend_block(
    layout: KeyLayout,
    queries: &[[i8; HEAD_DIM]; QUERY_BLOCK],
    keys: &[i8],
    values_t: &[i8],
    sums: &[i32; HEAD_DIM],
    p: &AttentionQ,
    scores: &mut [i32],
    weights: &mut [u8],
    out: &mut [[i8; HEAD_DIM]; QUERY_BLOCK],
) {
    #[cfg(target_arch = "x86_64")]
    if layout == KeyLayout::Transposed {
        return attention::attend_block_keys_transposed(queries, keys, values_t, sums, p, scores, weights, out);
    }
    let _ = layout;
    attention::attend_block(queries, keys, values_t, sums, p, scores, weights, out)
}

/// Token `t`'s key (`HEAD_DIM` codes) into a head's store of `layout`
/// ([`attention::store_key`]). Only x86 hosts transpose: elsewhere
/// the layout is the constant [`KeyLayout::Rows`], so the Cortex-M builds keep the plain copy.
#[inline]
pub fn store_key(layout: KeyLayout, key: &[i8], store: &mut [i8], t: usize) {
    let layout = if cfg!(target_arch = "x86_64") {
        layout
    } else {
        KeyLayout::Rows
    };
    attention::store_key(layout, key, store, t)
}
