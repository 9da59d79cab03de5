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

/// `out` (`m x n`, row-major) = `a` (`m x k`) times the transpose of `w` (`n x k`), with
/// `m = a.len() / k`, `n = w.len() / k` (a shorter `out` gets fewer rows): the specification
/// of every matrix multiply kernel.
pub fn matmul_i8_reference(a: &[i8], w: &[i8], k: usize, out: &mut [i32]) {
    matmul_rows(a, w, k, out, dot4_portable::<i8>)
}

/// [`matmul_i8_reference`]'s loops with the four-row dot product `dot4` given by the caller
/// (the portable one, or a faster one with the same sums): four activation rows at a time, so
/// each weight row is loaded once per four outputs, then the rows left over one by one.
#[inline(always)]
pub fn matmul_rows(
    a: &[i8],
    w: &[i8],
    k: usize,
    out: &mut [i32],
    dot4: impl Fn(&[i8], &[i8], &[i8], &[i8], &[i8]) -> [i32; 4],
) {
    if k == 0 || w.len() < k {
        out.fill(0);
        return;
    }
    let n = w.len() / k;
    // Checked rather than saturating: LLVM then still knows a block is exactly four rows of
    // `k` (no per-block bounds checks); sizes that overflow compute nothing.
    let (Some(quad_in), Some(quad_out)) = (k.checked_mul(4), n.checked_mul(4)) else {
        out.fill(0);
        return;
    };
    let mut a_quads = a.chunks_exact(quad_in);
    let mut out_quads = out.chunks_exact_mut(quad_out);
    for (a4, o4) in (&mut a_quads).zip(&mut out_quads) {
        let (a01, a23) = a4.split_at(2 * k);
        let (a0, a1) = a01.split_at(k);
        let (a2, a3) = a23.split_at(k);
        for (j, w_row) in w.chunks_exact(k).enumerate() {
            let s = dot4(a0, a1, a2, a3, w_row);
            for (r, value) in s.into_iter().enumerate() {
                if let Some(o) = o4.get_mut(r * n + j) {
                    *o = value;
                }
            }
        }
    }
    let rest_a = a_quads.remainder();
    let rest_out = out_quads.into_remainder();
    for (a_row, out_row) in rest_a.chunks_exact(k).zip(rest_out.chunks_exact_mut(n)) {
        for (o, w_row) in out_row.iter_mut().zip(w.chunks_exact(k)) {
            *o = dot(a_row, w_row);
        }
    }
}
