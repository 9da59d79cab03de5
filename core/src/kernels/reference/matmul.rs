//! The portable dot products: the specification of every instruction set's tiles.

use crate::kernels::types::code::Code;

/// Dot product of two int8 vectors in 32 bits.
#[inline(always)]
pub fn dot(a: &[i8], b: &[i8]) -> i32 {
    a.iter()
        .zip(b)
        .fold(0i32, |s, (&x, &y)| s.wrapping_add(x as i32 * y as i32))
}

/// The four-row dot product as two passes of two rows, for cores without a vector unit (Cortex-M7,
/// `bino_dsp`): four accumulators, five row pointers and the loop state do not fit the
/// registers of Armv7E-M, and LLVM spills in the four-row loop (66 instructions per 16
/// products in the matrix multiply, 59 as two two-row passes that read `w` twice). Same sums
/// as `dot4_portable`, over the common length of the rows.
#[inline(always)]
pub fn dot4_pairs<A: Code>(a0: &[A], a1: &[A], a2: &[A], a3: &[A], w: &[i8]) -> [i32; 4] {
    let len = w.len().min(a0.len()).min(a1.len()).min(a2.len()).min(a3.len());
    let [a0, a1, a2, a3] = [a0, a1, a2, a3].map(|x| x.get(..len).unwrap_or(&[]));
    let w = w.get(..len).unwrap_or(&[]);
    let [s0, s1] = dot2(a0, a1, w);
    let [s2, s3] = dot2(a2, a3, w);
    [s0, s1, s2, s3]
}

#[inline(always)]
fn dot2<A: Code>(a0: &[A], a1: &[A], w: &[i8]) -> [i32; 2] {
    let mut s = [0i32; 2];
    for ((&x0, &x1), &wv) in a0.iter().zip(a1).zip(w) {
        let wv = wv as i32;
        s[0] = s[0].wrapping_add(x0.wide() * wv);
        s[1] = s[1].wrapping_add(x1.wide() * wv);
    }
    s
}

/// Four dot products in one pass over `w`: the specification of every `dot4` kernel.
#[inline(always)]
#[cfg_attr(bino_dsp, allow(dead_code))] // only the tests use it there
pub fn dot4_portable<A: Code>(a0: &[A], a1: &[A], a2: &[A], a3: &[A], w: &[i8]) -> [i32; 4] {
    let mut s = [0i32; 4];
    for ((((&x0, &x1), &x2), &x3), &wv) in a0.iter().zip(a1).zip(a2).zip(a3).zip(w) {
        let wv = wv as i32;
        s[0] = s[0].wrapping_add(x0.wide() * wv);
        s[1] = s[1].wrapping_add(x1.wide() * wv);
        s[2] = s[2].wrapping_add(x2.wide() * wv);
        s[3] = s[3].wrapping_add(x3.wide() * wv);
    }
    s
}
