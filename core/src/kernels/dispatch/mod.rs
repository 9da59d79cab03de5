//! The one place that picks an instruction set: every layer's kernel entry point, which checks
//! the shapes, runs the active instruction set's kernel (`kernels::arch`) where it takes the
//! call and the portable path (`kernels::reference` and the portable families) otherwise.
//! `model/` and `pipeline/` call the kernels through this module only.
//!
//! Cortex-M builds choose at compile time (target features, `build.rs`'s `bino_dsp` /
//! `bino_mve`). On x86-64 the CPU is asked once (`cpuid`): a crate that depends on
//! `bino-core` gets the AVX2 and AVX-512 VNNI kernels with no `-C target-cpu` flag, and
//! [`active`] says which run. Every `cfg(bino_dsp)`, `cfg(bino_mve)` and x86 branch outside
//! `kernels::arch` lives in this module's files (one per layer).

pub mod attention;
pub mod conv;
pub mod epilogue;
pub mod gemm;
pub mod layernorm;
pub mod matmul;
pub mod residual;
pub mod rope;

use crate::config::HEAD_DIM;
pub use attention::{AttentionQ, KeyLayout, QUERY_BLOCK};

// The entry points and parameter types the model and the pipeline use.
pub use attention::{attend, key_layout, value_sums, AVG_FRAC_BITS, MAX_KEYS};
pub use conv::ConvEpilogue;
pub use epilogue::{
    requant_rows, residual_add, residual_add_prepared, ChannelRequant, ChannelRescale, PreparedResidual,
};
pub use gemm::{matmul_requant_i8, matmul_requant_i8_pass, matmul_requant_i8_prepared};
pub use layernorm::{layernorm_rows, layernorm_rows_prepared, LayerNormQ, PreparedLayerNorm, Z_FRAC_BITS};
pub use matmul::{dot, matmul_i8, matmul_i8_pass, PassWeights};
pub use rope::{rope_token, Angles, RopeLanes, QUARTER};

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
        use crate::kernels::arch::x86;
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
        use crate::kernels::arch::x86;
        let avx2 = x86::allow_avx2(!matches!(to, Isa::Portable));
        x86::vnni::enable(avx2 && matches!(to, Isa::Avx512Vnni));
    }
    let _ = to;
    active()
}

/// Maps every value of `x` through `table`, indexed by the value's two's-complement byte
/// ([`lut::apply_lut`](crate::kernels::lut::apply_lut)): 64 codes a step on x86 hosts with
/// AVX-512 VBMI, the scalar lookup elsewhere.
#[inline]
pub fn apply_lut(x: &mut [i8], table: &[i8; 256]) {
    #[cfg(target_arch = "x86_64")]
    if crate::kernels::arch::x86::vbmi::apply_lut(x, table) {
        return;
    }
    crate::kernels::lut::apply_lut(x, table)
}

/// Stores token `t`'s values channel-major (`store[c * tokens + t] = token[c]`, `DIM x tokens`):
/// each head's slice is then the `HEAD_DIM x tokens` transposed layout attention reads. The
/// Cortex-M55's Helium scatter where it takes the shape, else the plain loop.
pub fn scatter_channels(token: &[i8], store: &mut [i8], tokens: usize, t: usize) {
    if crate::kernels::arch::scatter_channels(token, store, tokens, t) {
        return;
    }
    for (channel, &v) in store.chunks_exact_mut(tokens).zip(token) {
        if let Some(slot) = channel.get_mut(t) {
            *slot = v;
        }
    }
}

/// Runs `f` in a frame of its own on Cortex-M7 (`bino_dsp`), inlined elsewhere: there the
/// encoder's per-pass parameter arrays would otherwise share the encoder's frame with pass 2 and
/// pass its 32 KiB stack budget, while on Cortex-M55 LLVM shares the frames better inlined
/// (the stack peaks in `firmware-sim/measured/<core>.log`).
#[cfg_attr(bino_dsp, inline(never))]
#[cfg_attr(not(bino_dsp), inline(always))]
pub fn out_of_line<R>(f: impl FnOnce() -> R) -> R {
    f()
}

/// `n` as the loops see it: on Cortex-M7 (`bino_dsp`, no vector unit) the constant, so that
/// unrolled two-row products address by constant offsets; elsewhere an opaque run-time value
/// (the same `n`), so that LLVM emits one tail-predicated 16-lane `vmladav.s8` loop per dot
/// product on Cortex-M55 rather than unrolling the constant into 32-bit lanes.
#[inline(always)]
pub fn loop_len(n: usize) -> usize {
    if cfg!(bino_dsp) {
        n
    } else {
        core::hint::black_box(n)
    }
}

/// Whether this core's GEMMs take requantisation columns prepared once per pass
/// ([`PreparedRequant`](super::types::prepared::PreparedRequant)): the Cortex-M assembly kernels
/// fuse the requantisation into their tiles, and x86 hosts requantise their accumulators in
/// AVX2 lanes from them (instead of decoding the parameters from the blob per token block);
/// elsewhere the columns would go unused.
pub const PREPARED_GEMM: bool = cfg!(any(bino_dsp, bino_mve, target_arch = "x86_64"));

/// One query block's attention over keys stored in `layout` (see
/// [`attention::attend_block`]): the x86 VNNI scores on
/// transposed keys or the AVX2 ones on paired keys where the keys were stored so, the block
/// kernels of this core otherwise.
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
    if layout != KeyLayout::Rows {
        return attention::attend_block_keys(layout, queries, keys, values_t, sums, p, scores, weights, out);
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
