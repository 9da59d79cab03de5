//! int8 x int8 -> int32 matrix multiply: `out[m][n] = sum_k a[m][k] * w[n][k]`.
//!
//! Weights are stored one output channel per row (`n x k`), activations one token per row
//! (`m x k`), so every output is a contiguous dot product that LLVM vectorises (AVX2
//! `vpmaddwd` on the host, MVE `vmladav` on Cortex-M55). Four activation rows are done
//! together so each weight row is loaded once per four outputs.

#[cfg(not(bino_dsp))]
use crate::kernels::reference::matmul::dot4_portable;
use crate::kernels::reference::matmul::matmul_rows;
pub use crate::kernels::reference::matmul::{dot, dot4_pairs, matmul_i8_reference};
pub use crate::kernels::types::code::Code;

/// `out` (`m x n`, row-major) = `a` (`m x k`) times the transpose of `w` (`n x k`).
///
/// `m = a.len() / k`, `n = w.len() / k`; `out` should hold `m * n` values (a shorter `out`
/// gets fewer rows). `k` must be at most 2^17 so sums of int8 products cannot overflow.
///
/// On Cortex-M7 and Cortex-M55 this runs the core's assembly tile (`kernels::arch`), on AVX2
/// hosts the AVX-512 VNNI tile where the CPU has it (`kernels::arch::x86::vnni`) or the AVX2 tile
/// (`kernels::arch::x86::avx2`), where it takes the shape, and
/// [`matmul_i8_portable`] otherwise: the results are the same as [`matmul_i8_reference`]'s.
#[inline]
pub fn matmul_i8(a: &[i8], w: &[i8], k: usize, out: &mut [i32]) {
    #[cfg(target_arch = "x86_64")]
    if crate::kernels::arch::x86::vnni::matmul_i32(a, w, k, out)
        || crate::kernels::arch::x86::avx2::matmul_i32(a, w, k, out)
    {
        return;
    }
    if !crate::kernels::arch::matmul_i32(a, w, k, out) {
        crate::kernels::arch::vectorised(
            #[inline(always)]
            || matmul_i8_portable(a, w, k, out),
        )
    }
}

/// [`matmul_i8`]'s portable path as this core compiles it: the reference loops
/// ([`matmul_rows`]) on this core's [`dot4`]. On Cortex-M7 (`bino_dsp`) the model widths are
/// constants, so the two-row products unroll with constant offsets.
pub fn matmul_i8_portable(a: &[i8], w: &[i8], k: usize, out: &mut [i32]) {
    if cfg!(bino_dsp) && k == crate::config::DIM {
        matmul_rows(a, w, crate::config::DIM, out, dot4::<i8>)
    } else if cfg!(bino_dsp) && k == crate::config::MLP_HIDDEN {
        matmul_rows(a, w, crate::config::MLP_HIDDEN, out, dot4::<i8>)
    } else {
        matmul_rows(a, w, k, out, dot4::<i8>)
    }
}

/// Widest matrix [`PassWeights`] keeps channel sums for: the MLP's hidden layer.
#[cfg(target_arch = "x86_64")]
const MAX_SUMMED: usize = crate::config::MLP_HIDDEN;

/// A weight matrix (`n x k`, one channel per row) for the calls of one pass, with what the
/// host's fastest multiply needs made once: on x86 with AVX-512 VNNI, each channel's
/// `128 * sum(w)` (`kernels::arch::x86::vnni::gemm`: the weights are read in place as
/// broadcasts, and the sums take off the unsigned activations' offset); elsewhere, or for
/// shapes that kernel does not take, just the matrix.
pub struct PassWeights<'w> {
    w: &'w [i8],
    k: usize,
    #[cfg(target_arch = "x86_64")]
    sums: [i32; MAX_SUMMED],
    /// Channels with a sum in `sums` (0: none made).
    #[cfg(target_arch = "x86_64")]
    summed: usize,
}

impl<'w> PassWeights<'w> {
    /// `w` (`n x k`) with its sums where the kernels take it.
    pub fn new(w: &'w [i8], k: usize) -> Self {
        #[cfg(target_arch = "x86_64")]
        {
            let n = w.len().checked_div(k).unwrap_or(0);
            let mut sums = [0; MAX_SUMMED];
            let made = sums
                .get_mut(..n)
                .is_some_and(|s| crate::kernels::arch::x86::vnni::gemm::weight_sums(w, k, s));
            let summed = if made { n } else { 0 };
            PassWeights { w, k, sums, summed }
        }
        #[cfg(not(target_arch = "x86_64"))]
        PassWeights { w, k }
    }

    /// The matrix.
    pub fn weight(&self) -> &'w [i8] {
        self.w
    }

    /// Its row length.
    pub fn k(&self) -> usize {
        self.k
    }

    /// The channel sums, where made.
    #[cfg(target_arch = "x86_64")]
    pub(crate) fn sums(&self) -> Option<&[i32]> {
        self.sums.get(..self.summed).filter(|s| !s.is_empty())
    }
}

/// [`matmul_i8`] of `a` and a pass's weights: the same products, through the VNNI broadcast
/// multiply where the weights carry their sums.
#[inline]
pub fn matmul_i8_pass(a: &[i8], w: &PassWeights<'_>, out: &mut [i32]) {
    #[cfg(target_arch = "x86_64")]
    if let Some(sums) = w.sums() {
        if crate::kernels::arch::x86::vnni::gemm::matmul_i32_summed(a, w.w, w.k, sums, out) {
            return;
        }
    }
    matmul_i8(a, w.w, w.k, out)
}

/// Four dot products of rows `a0..a3` (equal lengths) against one shared int8 vector `w`
/// (each `w` element loaded once). Products of a `u8` and an `i8` fit 16 bits too.
#[inline(always)]
pub fn dot4<A: Code>(a0: &[A], a1: &[A], a2: &[A], a3: &[A], w: &[i8]) -> [i32; 4] {
    #[cfg(target_arch = "x86_64")]
    {
        use crate::kernels::arch::x86::avx2::{dot4 as dot4_simd, LANES};
        let head = w.len() - w.len() % LANES;
        if let Some(s) = dot4_simd(a0, a1, a2, a3, w.get(..head).unwrap_or(&[])) {
            fn tail<T>(x: &[T], head: usize) -> &[T] {
                x.get(head..).unwrap_or(&[])
            }
            let t = dot4_portable(
                tail(a0, head),
                tail(a1, head),
                tail(a2, head),
                tail(a3, head),
                tail(w, head),
            );
            return [
                s[0].wrapping_add(t[0]),
                s[1].wrapping_add(t[1]),
                s[2].wrapping_add(t[2]),
                s[3].wrapping_add(t[3]),
            ];
        }
    }
    #[cfg(bino_dsp)]
    return dot4_pairs(a0, a1, a2, a3, w);
    #[cfg(not(bino_dsp))]
    dot4_portable(a0, a1, a2, a3, w)
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
    fn four_row_dot_matches_plain_dots_at_model_sizes() {
        // On AVX2 hosts this checks the SIMD kernel (and its tail) against the plain dot.
        let mut rng = Rng::new(11);
        let mut rows = [0i8; 5 * 480];
        for k in [1, 15, 16, 32, 33, 128, 479, 480] {
            rng.fill_i8(&mut rows);
            if k == 480 {
                rows.fill(-128);
            }
            let r: [&[i8]; 5] = core::array::from_fn(|i| &rows[i * k..(i + 1) * k]);
            let got = dot4(r[0], r[1], r[2], r[3], r[4]);
            for (i, &g) in got.iter().enumerate() {
                assert_eq!(g, dot(r[i], r[4]), "k={k} row {i}");
            }
        }
    }

    #[test]
    fn two_row_passes_match_plain_dots() {
        // The Cortex-M7 kernel, checked on every host.
        let mut rng = Rng::new(13);
        let mut rows = [0i8; 5 * 480];
        for k in [0, 1, 3, 32, 33, 128, 480] {
            rng.fill_i8(&mut rows);
            if k == 480 {
                rows.fill(-128);
            }
            let r: [&[i8]; 5] = core::array::from_fn(|i| &rows[i * k..(i + 1) * k]);
            let got = dot4_pairs(r[0], r[1], r[2], r[3], r[4]);
            for (i, &g) in got.iter().enumerate() {
                assert_eq!(g, dot(r[i], r[4]), "k={k} row {i}");
            }
            // Uneven lengths: both passes stop at the shortest row, like the four-row loop.
            let short = dot4_pairs(r[0], &r[1][..k / 2], r[2], r[3], r[4]);
            assert_eq!(short, dot4_portable(r[0], &r[1][..k / 2], r[2], r[3], r[4]));
        }
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
