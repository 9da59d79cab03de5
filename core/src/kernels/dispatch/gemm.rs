//! Matrix multiply with the requantisation fused in: `out[m][c] = sat8(rq_c(a_m . w_c) + zero[c])`
//! in one pass, int8 out, no `i32` buffer in between on cores with an assembly kernel.

use super::epilogue::{requant_rows, ChannelRequant};
use super::matmul::{matmul_i8, PassWeights};
use crate::kernels::arch;
pub use crate::kernels::reference::gemm::matmul_requant_reference;
use crate::kernels::I32s;

/// `out` (`m x n` int8) = [`requant_rows`] of [`matmul_i8`]`(a, w, k)`, with `n` = the rows of
/// `w` = the channels of `rq`.
///
/// Cortex-M7 and Cortex-M55 run it fused in their assembly kernels (`kernels::arch`) where the
/// shape and parameters allow (quantiser-made layers do); elsewhere, and for anything else, it
/// is the two passes through `acc` (at least `m * n` values, else the rows that fit).
#[inline]
pub fn matmul_requant_i8<B, M, Z>(
    a: &[i8],
    w: &[i8],
    k: usize,
    rq: &ChannelRequant<'_, B, M>,
    zero: &Z,
    acc: &mut [i32],
    out: &mut [i8],
) where
    B: I32s + ?Sized,
    M: I32s + ?Sized,
    Z: I32s + ?Sized,
{
    if arch::matmul_requant(a, w, k, rq, zero, out) {
        return;
    }
    let cells = (a.len() / k.max(1)).saturating_mul(w.len() / k.max(1)).min(acc.len());
    let acc = &mut acc[..cells];
    matmul_i8(a, w, k, acc);
    requant_rows(acc, rq, zero, out);
}

/// [`matmul_requant_i8`] with the columns of `rq` and `zero` prepared once for the calls of a
/// pass ([`arch::PreparedRequant`], on cores with an assembly kernel); without them, or where
/// the kernel declines, as [`matmul_requant_i8`].
#[allow(clippy::too_many_arguments)]
pub fn matmul_requant_i8_prepared<B, M, Z>(
    a: &[i8],
    w: &[i8],
    k: usize,
    prepared: Option<&arch::PreparedRequant<'_>>,
    rq: &ChannelRequant<'_, B, M>,
    zero: &Z,
    acc: &mut [i32],
    out: &mut [i8],
) where
    B: I32s + ?Sized,
    M: I32s + ?Sized,
    Z: I32s + ?Sized,
{
    if prepared.is_some_and(|p| arch::matmul_requant_prepared(a, w, k, p, acc, out)) {
        return;
    }
    matmul_requant_i8(a, w, k, rq, zero, acc, out);
}

/// [`matmul_requant_i8_prepared`] on a pass's weights: on x86 with VNNI, where the weights
/// carry their sums, the broadcast multiply then the prepared requantisation.
#[allow(clippy::too_many_arguments)]
pub fn matmul_requant_i8_pass<B, M, Z>(
    a: &[i8],
    w: &PassWeights<'_>,
    prepared: Option<&arch::PreparedRequant<'_>>,
    rq: &ChannelRequant<'_, B, M>,
    zero: &Z,
    acc: &mut [i32],
    out: &mut [i8],
) where
    B: I32s + ?Sized,
    M: I32s + ?Sized,
    Z: I32s + ?Sized,
{
    #[cfg(target_arch = "x86_64")]
    if let (Some(p), Some(sums)) = (prepared, w.sums()) {
        if arch::x86::matmul_requant_summed(a, w.weight(), w.k(), sums, p.words, acc, out) {
            return;
        }
    }
    matmul_requant_i8_prepared(a, w.weight(), w.k(), prepared, rq, zero, acc, out);
}
