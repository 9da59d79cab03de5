//! The portable softmax row of attention: the specification of every faster path.

use crate::kernels::types::exp::ExpQ32;

/// One row's softmax weights `e.weight(max - s)`, stored as `w - 128` (int8), and their sum:
/// the specification of every faster path (`attention::softmax_row_fastest`).
#[inline(always)]
pub fn softmax_row(e: &ExpQ32, max: i32, scores: &[i32], weights: &mut [u8]) -> u32 {
    let mut sum = 0u32;
    for (w, &s) in weights.iter_mut().zip(scores) {
        let x = e.weight(max.wrapping_sub(s) as u32);
        *w = x ^ 0x80;
        sum = sum.wrapping_add(x as u32);
    }
    sum
}
