//! x86-64 kernels of host builds, chosen at run time from what the CPU reports (`cpuid`), so
//! a crate that depends on `bino-core` gets them without `-C target-cpu` flags:
//! - [`mod@vnni`]: AVX-512 VNNI tiles (`vpdpbusd`) where the CPU and OS support AVX-512 F, DQ,
//!   BW, VL and VNNI;
//! - [`mod@vbmi`]: AVX-512 VBMI table lookups (`vpermi2b`) where the CPU has them too;
//! - [`mod@avx2`]: AVX2 tiles (`vpmaddwd`) where the CPU has AVX2;
//! - [`with_avx2`] / [`vnni::with_avx512`]: portable loops compiled again for those features
//!   (LLVM vectorises them wider than the SSE2 baseline of `x86_64-unknown-linux-gnu`).
//!
//! Every kernel is bit-identical to the portable one it replaces (each module's tests), so
//! which one runs changes the time, never the output. [`allow_avx2`] and [`vnni::enable`]
//! switch them off for the process: that is how the slower paths are measured and tested on
//! a fast CPU.

pub mod avx2;
pub mod vbmi;
pub mod vnni;

use core::sync::atomic::{AtomicU8, Ordering};

// The features `with_avx2` compiles for: AVX2 and the BMI shifts of x86-64-v3.
cpufeatures::new!(cpuid_avx2, "avx2", "bmi1", "bmi2");

// 0: not yet looked, 1: absent or switched off, 2: in use.
static AVX2: AtomicU8 = AtomicU8::new(0);

/// Whether the AVX2 kernels run: the CPU has AVX2, BMI1 and BMI2, the OS saves the YMM
/// registers, and [`allow_avx2`] has not switched them off. One relaxed atomic load after the
/// first call.
#[inline]
pub fn avx2() -> bool {
    match AVX2.load(Ordering::Relaxed) {
        1 => false,
        2 => true,
        _ => allow_avx2(true),
    }
}

/// Lets the AVX2 kernels run (only where the CPU has them) or keeps every x86 kernel off
/// (`false`: the portable kernels, and no VNNI either, which needs AVX2), for this process;
/// returns whether AVX2 now runs.
pub fn allow_avx2(on: bool) -> bool {
    let run = on && cpuid_avx2::get();
    AVX2.store(if run { 2 } else { 1 }, Ordering::Relaxed);
    if !run {
        vnni::enable(false);
    }
    run
}

/// `f()` compiled for AVX2 (with BMI1 / BMI2) where [`avx2()`] holds (`None`, `f` not called,
/// elsewhere). Portable loops inlined into `f` vectorise with 256-bit lanes; the results are
/// those of `f` compiled for the baseline.
#[inline(always)]
pub fn with_avx2<R>(f: impl FnOnce() -> R) -> Option<R> {
    if !avx2() {
        return None;
    }
    // SAFETY: `avx2()` saw AVX2, BMI1 and BMI2 on this CPU, enabled by the OS.
    #[allow(unsafe_code)]
    Some(unsafe { run_avx2(f) })
}

/// `f()` compiled for AVX-512 where the VNNI kernels run ([`vnni::with_avx512`]: 64-bit lane
/// multiplies and shifts, which the portable loops' 64-bit arithmetic needs), else for AVX2 where
/// [`avx2()`] holds, else `f()` as the build compiled it: the same result every way.
#[inline(always)]
pub fn widened<R>(f: impl FnOnce() -> R) -> R {
    if vnni::available() {
        // SAFETY: `available()` saw AVX-512 F/BW/VL/DQ/VNNI on this CPU, enabled by the OS.
        #[allow(unsafe_code)]
        unsafe {
            vnni::run_avx512(f)
        }
    } else if avx2() {
        // SAFETY: `avx2()` saw AVX2, BMI1 and BMI2 on this CPU, enabled by the OS.
        #[allow(unsafe_code)]
        unsafe {
            run_avx2(f)
        }
    } else {
        f()
    }
}

/// `out` (`m x n` int8) = the prepared columns `words` (one per row of `w`) applied to
/// `a` times the transpose of `w`, through `acc` (at least `m * n`): the VNNI or AVX2 matrix
/// multiply, then `avx2::requant_prepared`. `false` where neither multiply takes the shape,
/// the lengths differ or an accumulator is outside the lanes' range (then `out` may be partly
/// written: the caller recomputes it).
pub fn matmul_requant_prepared(
    a: &[i8],
    w: &[i8],
    k: usize,
    words: &[[i32; 4]],
    acc: &mut [i32],
    out: &mut [i8],
) -> bool {
    let n = words.len();
    if k == 0 || w.len() != n * k || !a.len().is_multiple_of(k) {
        return false;
    }
    let cells = a.len() / k * n;
    let (Some(acc), Some(out)) = (acc.get_mut(..cells), out.get_mut(..cells)) else {
        return false;
    };
    (vnni::matmul_i32(a, w, k, acc) || avx2::matmul_i32(a, w, k, acc)) && avx2::requant_prepared(words, acc, out)
}

/// [`matmul_requant_prepared`] through the VNNI broadcast multiply (`vnni::gemm`), given the
/// weights' `sums` ([`vnni::gemm::weight_sums`]): `false` where it does not take the shape, the
/// lengths differ or an accumulator is outside the lanes' range (then `out` may be partly
/// written: the caller recomputes it).
pub fn matmul_requant_summed(
    a: &[i8],
    w: &[i8],
    k: usize,
    sums: &[i32],
    words: &[[i32; 4]],
    acc: &mut [i32],
    out: &mut [i8],
) -> bool {
    let n = words.len();
    if k == 0 || sums.len() != n || !a.len().is_multiple_of(k) {
        return false;
    }
    let cells = a.len() / k * n;
    let Some(out) = out.get_mut(..cells) else {
        return false;
    };
    // Requantised in registers where the shape allows, else through `acc`.
    if vnni::gemm::matmul_requant_summed(a, w, k, sums, words, out) {
        return true;
    }
    let Some(acc) = acc.get_mut(..cells) else {
        return false;
    };
    vnni::gemm::matmul_i32_summed(a, w, k, sums, acc) && avx2::requant_prepared(words, acc, out)
}

#[target_feature(enable = "avx2,bmi1,bmi2")]
fn run_avx2<R>(f: impl FnOnce() -> R) -> R {
    f()
}

#[cfg(test)]
mod tests;
