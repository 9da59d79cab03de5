//! The matrix multiply with fused requantisation, output by output: the specification.

use crate::kernels::reference::matmul::dot;
use crate::kernels::types::params::I32s;
use crate::kernels::types::requant::ChannelRequant;

/// The portable `dispatch::matmul_requant_i8`, output by output: the specification.
pub fn matmul_requant_reference<B, M, Z>(
    a: &[i8],
    w: &[i8],
    k: usize,
    rq: &ChannelRequant<'_, B, M>,
    zero: &Z,
    out: &mut [i8],
) where
    B: I32s + ?Sized,
    M: I32s + ?Sized,
    Z: I32s + ?Sized,
{
    let n = rq.channels();
    if k == 0 || n == 0 || w.len() / k < n {
        return;
    }
    for (a_row, out_row) in a.chunks_exact(k).zip(out.chunks_exact_mut(n)) {
        for (c, (o, w_row)) in out_row.iter_mut().zip(w.chunks_exact(k)).enumerate() {
            *o = crate::fixed::sat_i8_i64(rq.apply(c, dot(a_row, w_row)) + zero.at(c) as i64);
        }
    }
}
