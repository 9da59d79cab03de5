//! Assembly GEMM kernels for the Cortex-M cores, behind safe wrappers.
//!
//! The only module of `bino-core` that may use `unsafe`, and only for `core::arch::asm!`.
//! Each kernel computes a small tile of dot products in registers (`dsp`: 4 rows x 1 column
//! with `sxtb16` + `smlad` on Cortex-M7; `mve`: 2 rows x 3 columns with `vmladava.s8` on
//! Cortex-M55), and a shared Rust driver hands each finished tile to an [`Epilogue`] in the
//! same pass: a plain `i32` store, or bias, per-channel requantisation, zero point and the
//! int8 store (`Fused`). The portable kernels (`matmul::matmul_i8_reference`,
//! `epilogue::requant_rows`) stay the specification; the wrappers return `false` for shapes
//! or parameters they do not handle, and the caller then runs the reference.
//!
//! Selected by cfgs from `core/build.rs`: `bino_dsp` (thumbv7em) and `bino_mve`
//! (thumbv8m.main built with `-C target-cpu=cortex-m55`). The drivers and the epilogues are
//! also compiled for host tests, with portable tile kernels computing the same sums.
#![allow(unsafe_code)]
// Host builds without tests use none of the drivers.
#![cfg_attr(not(any(bino_dsp, bino_mve, test)), allow(dead_code))]

#[cfg(any(bino_dsp, test))]
pub(crate) mod dsp;
mod fused;
#[cfg(any(bino_mve, test))]
pub(crate) mod mve;

pub use fused::matmul_requant;

/// Longest dot product the kernels take (their stack scratch and the accumulator bound:
/// `512 * 128 * 128 < 2^23`).
pub const MAX_K: usize = 512;

/// What happens to each finished accumulator of a tile.
pub(crate) trait Epilogue {
    /// Per-column values, loaded once per tile column.
    type Col: Copy;
    /// Column `j`'s values.
    fn col(&self, j: usize) -> Self::Col;
    /// The value an accumulator of column `c` starts from (the bias, or 0).
    fn init(c: &Self::Col) -> i32;
    /// Output `(row, j)` from its finished accumulator (`init` plus the dot product).
    fn put(&mut self, c: &Self::Col, row: usize, j: usize, acc: i32);
}

/// Stores accumulators as they are: `out[row * n + j]`.
pub(crate) struct Store<'o> {
    pub out: &'o mut [i32],
    pub n: usize,
}

impl Epilogue for Store<'_> {
    type Col = ();
    #[inline(always)]
    fn col(&self, _: usize) {}
    #[inline(always)]
    fn init(_: &()) -> i32 {
        0
    }
    #[inline(always)]
    fn put(&mut self, _: &(), row: usize, j: usize, acc: i32) {
        if let Some(o) = self.out.get_mut(row * self.n + j) {
            *o = acc;
        }
    }
}

/// Shapes every kernel takes: `m` rows of `a` and `n` rows of `w`, both `k` long, and an
/// output of at least `m * n` values. `None` for anything else.
#[cfg_attr(not(any(bino_dsp, bino_mve)), allow(dead_code))]
pub(crate) fn shape(a: &[i8], w: &[i8], k: usize, out_len: usize) -> Option<(usize, usize)> {
    if k == 0 || k > MAX_K {
        return None;
    }
    let (m, n) = (a.len() / k, w.len() / k);
    (m > 0 && n > 0 && m.checked_mul(n)? <= out_len).then_some((m, n))
}

/// `out` (`m x n`) = `a` (`m x k`) times the transpose of `w` (`n x k`) on this core's
/// assembly kernel; `false` (nothing written) where there is none or the shape is not taken.
#[inline]
pub fn matmul_i32(a: &[i8], w: &[i8], k: usize, out: &mut [i32]) -> bool {
    #[cfg(any(bino_dsp, bino_mve))]
    if let Some((m, n)) = shape(a, w, k, out.len()) {
        return run(a, w, k, m, &mut Store { out, n });
    }
    let _ = (a, w, k, out);
    false
}

/// The tile driver of this core.
#[cfg(any(bino_dsp, bino_mve))]
#[inline(always)]
pub(crate) fn run<E: Epilogue>(a: &[i8], w: &[i8], k: usize, m: usize, epi: &mut E) -> bool {
    #[cfg(bino_dsp)]
    return dsp::gemm(a, w, k, m, epi);
    #[cfg(bino_mve)]
    return mve::gemm(a, w, k, m, epi);
}
