//! int8 x int8 -> int32 matrix multiply: `out[m][n] = sum_k a[m][k] * w[n][k]`.
//!
//! Weights are stored one output channel per row (`n x k`), activations one token per row
//! (`m x k`), so every output is a contiguous dot product that LLVM vectorises (AVX2
//! `vpmaddwd` on the host, MVE `vmladav` on Cortex-M55). Four activation rows are done
//! together so each weight row is loaded once per four outputs.

/// `out` (`m x n`, row-major) = `a` (`m x k`) times the transpose of `w` (`n x k`).
///
/// `m = a.len() / k`, `n = w.len() / k`; `out` should hold `m * n` values (a shorter `out`
/// gets fewer rows). `k` must be at most 2^17 so sums of int8 products cannot overflow.
pub fn matmul_i8(a: &[i8], w: &[i8], k: usize, out: &mut [i32]) {
    if k == 0 || w.len() < k {
        out.fill(0);
        return;
    }
    let n = w.len() / k;
    let mut a_quads = a.chunks_exact(4 * k);
    let mut out_quads = out.chunks_exact_mut(4 * n);
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

/// Dot product of two int8 vectors in 32 bits.
#[inline(always)]
pub fn dot(a: &[i8], b: &[i8]) -> i32 {
    a.iter()
        .zip(b)
        .fold(0i32, |s, (&x, &y)| s.wrapping_add(x as i32 * y as i32))
}

#[inline(always)]
fn dot4(a0: &[i8], a1: &[i8], a2: &[i8], a3: &[i8], w: &[i8]) -> [i32; 4] {
    let mut s = [0i32; 4];
    for ((((&x0, &x1), &x2), &x3), &wv) in a0.iter().zip(a1).zip(a2).zip(a3).zip(w) {
        let wv = wv as i32;
        s[0] = s[0].wrapping_add(x0 as i32 * wv);
        s[1] = s[1].wrapping_add(x1 as i32 * wv);
        s[2] = s[2].wrapping_add(x2 as i32 * wv);
        s[3] = s[3].wrapping_add(x3 as i32 * wv);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::Rng;

    fn reference(a: &[i8], w: &[i8], k: usize) -> [i32; 64] {
        let (m, n) = (a.len() / k, w.len() / k);
        let mut out = [0i32; 64];
        for i in 0..m {
            for j in 0..n {
                out[i * n + j] = (0..k).map(|t| a[i * k + t] as i32 * w[j * k + t] as i32).sum();
            }
        }
        out
    }

    #[test]
    fn matches_reference_on_random_shapes() {
        let mut rng = Rng::new(7);
        let mut a = [0i8; 7 * 33];
        let mut w = [0i8; 9 * 33];
        for (m, n, k) in [(1, 1, 1), (4, 3, 5), (5, 7, 33), (7, 9, 33), (3, 2, 16), (8, 8, 17)] {
            rng.fill_i8(&mut a[..m * k]);
            rng.fill_i8(&mut w[..n * k]);
            let mut out = [i32::MIN; 64];
            matmul_i8(&a[..m * k], &w[..n * k], k, &mut out[..m * n]);
            let want = reference(&a[..m * k], &w[..n * k], k);
            assert_eq!(out[..m * n], want[..m * n], "m={m} n={n} k={k}");
        }
    }

    #[test]
    fn extreme_values_do_not_overflow_at_model_sizes() {
        let a = [-128i8; 4 * 480];
        let w = [-128i8; 2 * 480];
        let mut out = [0i32; 8];
        matmul_i8(&a, &w, 480, &mut out);
        assert!(out.iter().all(|&v| v == 480 * 128 * 128));
    }

    #[test]
    fn short_buffers_do_not_panic() {
        let mut out = [0i32; 3];
        matmul_i8(&[1; 10], &[1; 10], 5, &mut out);
        matmul_i8(&[1; 10], &[1; 3], 5, &mut out);
        assert_eq!(out, [0; 3]);
        matmul_i8(&[1; 10], &[1; 10], 0, &mut out);
    }
}
