//! The residual add by the saturating per-channel formula: the specification.

use crate::fixed::sat_i8_i64;
use crate::kernels::types::params::I32s;
use crate::kernels::types::requant::{ChannelRequant, ChannelRescale};

/// `dispatch::residual_add` by the saturating per-channel formula only: the specification of its
/// faster paths (the decoded chunks, their 32-bit lanes, the Helium loop).
pub fn residual_add_reference<Z, M, B, M2, Z2>(
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
    let n = delta.channels();
    if n == 0 {
        return;
    }
    let whole_rows = x.len().min(acc.len()) / n * n;
    for (i, (xq, &a)) in x.iter_mut().zip(acc).enumerate().take(whole_rows) {
        let c = i % n;
        *xq = sat_i8_i64(carry.apply(c, *xq) + delta.apply(c, a) + new_zero.at(c) as i64);
    }
}
