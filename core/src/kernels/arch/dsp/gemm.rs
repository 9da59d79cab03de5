//! The Cortex-M7 GEMM: the tile driver ([`gemm`]: blocks of four rows widened once, then the
//! tile per column or the epilogue's block kernel), its variant on a lent scratch
//! ([`gemm_rows_in`]), and the four-row block kernels that run every column in one assembly
//! call with a plain `i32` store ([`rows_i32`]) or the fused requantisation ([`rows_requant`]).

use super::tile::{tile, widen, words};
use super::ROWS;
#[cfg(bino_dsp)]
use crate::kernels::arch::fused::Col;
use crate::kernels::arch::{Epilogue, MAX_K};

/// The tile driver: `m` rows of `a` against every row of `w`, each finished accumulator to
/// `epi`. Declines (`false`) `k` not a multiple of 4 or `w` not word-aligned (the kernel loads
/// whole weight words); the caller has checked `k` in `1..=MAX_K` and the lengths.
#[inline(always)]
pub(crate) fn gemm<E: Epilogue>(a: &[i8], w: &[i8], k: usize, m: usize, epi: &mut E) -> bool {
    if !k.is_multiple_of(4) || k > MAX_K || !(w.as_ptr() as usize).is_multiple_of(4) {
        return false;
    }
    // A scratch no larger than the shape needs: it is zeroed on every call (attention's
    // 32-element dot products would otherwise clear 8 KiB each time).
    match k {
        0..=32 => gemm_in::<E, { words(32) }>(a, w, k, m, epi),
        33..=128 => gemm_in::<E, { words(128) }>(a, w, k, m, epi),
        129..=512 => gemm_in::<E, { words(512) }>(a, w, k, m, epi),
        // The head's hidden convolutions (27 taps of 24 channels).
        513..=648 => gemm_in::<E, { words(648) }>(a, w, k, m, epi),
        _ => gemm_in::<E, { words(MAX_K) }>(a, w, k, m, epi),
    }
}

/// [`gemm`] for one block of at most four rows, widened into the caller's `scratch` (at least
/// `k / 2` words per row block of four: attention's weighted sums lend it the scores' room,
/// no longer needed, so no stack scratch is zeroed for each call). Declines as [`gemm`] does,
/// and for more than four rows or a short scratch.
#[cfg_attr(not(any(bino_dsp, test)), allow(dead_code))]
pub(crate) fn gemm_rows_in<E: Epilogue>(
    a: &[i8],
    w: &[i8],
    k: usize,
    m: usize,
    epi: &mut E,
    scratch: &mut [u32],
) -> bool {
    if k == 0 || !k.is_multiple_of(4) || k > MAX_K || m == 0 || m > ROWS || !(w.as_ptr() as usize).is_multiple_of(4) {
        return false;
    }
    let Some(x) = scratch.get_mut(..k / 4 * 2 * ROWS) else {
        return false;
    };
    let rows: [&[i8]; ROWS] = core::array::from_fn(|i| {
        let r = i.min(m - 1);
        a.get(r * k..(r + 1) * k).unwrap_or(&[])
    });
    widen(rows, x);
    if m == ROWS && epi.block_of_rows(0, x, w, k) {
        return true;
    }
    for (j, w_row) in w.chunks_exact(k).enumerate() {
        let acc = tile(x, w_row, [epi.init(j); ROWS]);
        epi.put_col(0, j, acc, m);
    }
    true
}

/// [`gemm`] with a `WORDS`-word scratch (`k <= 4 * WORDS / (2 * ROWS)`). Never inlined: the
/// scratch then lives on the stack only while it runs, instead of in the frame of every
/// caller (the encoder's GEMMs and attention would each add one to the stack peak).
#[inline(never)]
fn gemm_in<E: Epilogue, const WORDS: usize>(a: &[i8], w: &[i8], k: usize, m: usize, epi: &mut E) -> bool {
    let groups = k / 4;
    let mut x = [0u32; WORDS];
    let Some(scratch) = x.get_mut(..groups * 2 * ROWS) else {
        return false;
    };
    for r0 in (0..m).step_by(ROWS) {
        // Rows past the end repeat the last one; their results are not stored.
        let rows: [&[i8]; ROWS] = core::array::from_fn(|i| {
            let r = (r0 + i).min(m - 1);
            a.get(r * k..(r + 1) * k).unwrap_or(&[])
        });
        widen(rows, scratch);
        if m - r0 >= ROWS && epi.block_of_rows(r0, scratch, w, k) {
            continue;
        }
        for (j, w_row) in w.chunks_exact(k).enumerate() {
            let acc = tile(scratch, w_row, [epi.init(j); ROWS]);
            epi.put_col(r0, j, acc, m - r0);
        }
    }
    true
}

/// Four widened rows (`x`, from [`widen`]) against every row of `w` (`k` codes each, `k` a
/// multiple of 8, `w` word-aligned) in one assembly call, the sums stored as `i32` into `out`
/// (four rows of `n = w.len() / k` values at a stride of `n`): per column the accumulators
/// zeroed, the eight-group loop of [`tile`] then a two-group loop for the rest of `k` (the
/// head's convolutions: `k` = 27 x 16 or 27 x 24), and four row-strided stores, without returning to
/// Rust (the per-column driver spent about 100 instructions a column around the loop). `false`
/// (nothing written) for other lengths or alignments.
#[cfg(bino_dsp)]
pub(crate) fn rows_i32(x: &[u32], w: &[i8], k: usize, out: &mut [i32]) -> bool {
    let n = w.len() / k.max(1);
    if k == 0 || !k.is_multiple_of(8) || w.len() != n * k || n == 0 || out.len() != ROWS * n {
        return false;
    }
    if x.len() < k / 4 * 2 * ROWS || !(w.as_ptr() as usize).is_multiple_of(4) {
        return false;
    }
    // SAFETY: per column `j` (`n` of them) the loop reads the `k` bytes of weight row `j` (word
    // loads: `w` is word-aligned and exactly `n * k` bytes, checked) and the first `2 k` words
    // of `x` (checked), and writes `out[j]`, `out[n + j]`, `out[2n + j]`, `out[3n + j]` (`out`
    // is exactly `4 n` words, checked); the eight-group loop runs `k / 32` times and the
    // two-group loop `k % 32 / 8` times, `k` bytes of `w` and `2 k` words of `x` together. The
    // row stride, both loop counts, the output pointer and the column count live in 24 bytes
    // below `sp`, dropped before the end. Only declared outputs are written; the flags are
    // clobbered.
    unsafe {
        core::arch::asm!(
            "sub sp, sp, #24",
            "strd {t0}, {t1}, [sp]",
            "strd {x0}, {x1}, [sp, #8]",
            "str {g}, [sp, #16]",
            "3:",
            "movs {a0}, #0",
            "movs {a1}, #0",
            "movs {a2}, #0",
            "movs {a3}, #0",
            "mov {x}, {xb}",
            "ldr {g}, [sp, #4]",
            "cmp {g}, #0",
            "beq 4f",
            "2:",
            groups8!(),
            "subs {g}, {g}, #1",
            "bne 2b",
            "4:",
            "ldr {g}, [sp, #16]",
            "cmp {g}, #0",
            "beq 5f",
            "6:",
            group!(),
            group!(),
            "subs {g}, {g}, #1",
            "bne 6b",
            "5:",
            "ldr {t0}, [sp, #0]",
            "ldr {t1}, [sp, #8]",
            "str {a0}, [{t1}]",
            "str {a1}, [{t1}, {t0}]",
            "add {x0}, {t1}, {t0}, lsl #1",
            "str {a2}, [{x0}]",
            "str {a3}, [{x0}, {t0}]",
            "add {t1}, {t1}, #4",
            "str {t1}, [sp, #8]",
            "ldr {x1}, [sp, #12]",
            "subs {x1}, {x1}, #1",
            "str {x1}, [sp, #12]",
            "bne 3b",
            "add sp, sp, #24",
            w = inout(reg) w.as_ptr() => _,
            xb = in(reg) x.as_ptr(),
            x = out(reg) _,
            g = inout(reg) k % 32 / 8 => _,
            t0 = inout(reg) 4 * n => _,
            t1 = inout(reg) k / 32 => _,
            x0 = inout(reg) out.as_mut_ptr() => _,
            x1 = inout(reg) n => _,
            a0 = out(reg) _,
            a1 = out(reg) _,
            a2 = out(reg) _,
            a3 = out(reg) _,
        );
    }
    true
}

/// [`rows_i32`] with the fused epilogue: each column's accumulators start from its `Col`'s bias,
/// and each sum leaves as `ssat8((smmul(acc, mult) + addend) >> s)` (`Col::apply`), stored as a
/// byte into four rows of `out` at a stride of `stride` bytes (`out` starts at the first row's
/// first column; `params` holds one `Col` per row of `w`). `false` (nothing written) for other
/// lengths or alignments.
#[cfg(bino_dsp)]
pub(crate) fn rows_requant(x: &[u32], w: &[i8], k: usize, params: &[Col], out: &mut [i8], stride: usize) -> bool {
    let n = params.len();
    if k == 0 || !k.is_multiple_of(8) || n == 0 || w.len() != n * k || stride < n {
        return false;
    }
    if out.len() < (ROWS - 1) * stride + n || x.len() < k / 4 * 2 * ROWS || !(w.as_ptr() as usize).is_multiple_of(4) {
        return false;
    }
    // SAFETY: per column `j` (`n` of them) the loop reads the `k` bytes of weight row `j` (word
    // loads: `w` is word-aligned and exactly `n * k` bytes, checked), the first `2 k` words of
    // `x` (checked) and the four words of `params[j]` (`repr(C)` `Col`: bias, mult, addend,
    // s), and writes bytes `j`, `stride + j`, `2 stride + j`, `3 stride + j` of `out` (checked:
    // `out` holds `3 stride + n` bytes); the two loops read `k` bytes of `w` and `2 k` words of
    // `x` together, as in `rows_i32`. The row stride, both loop counts, the parameter and
    // output pointers and the column count live in 24 bytes below `sp`, dropped before the
    // end. Only declared outputs are written; the flags are clobbered.
    unsafe {
        core::arch::asm!(
            "sub sp, sp, #24",
            "strd {t0}, {t1}, [sp]",
            "strd {x0}, {x1}, [sp, #8]",
            "strd {g}, {a0}, [sp, #16]",
            "3:",
            "ldr {t0}, [sp, #8]",
            "ldr {a0}, [{t0}]",
            "mov {a1}, {a0}",
            "mov {a2}, {a0}",
            "mov {a3}, {a0}",
            "mov {x}, {xb}",
            "ldr {g}, [sp, #4]",
            "cmp {g}, #0",
            "beq 4f",
            "2:",
            groups8!(),
            "subs {g}, {g}, #1",
            "bne 2b",
            "4:",
            "ldr {g}, [sp, #20]",
            "cmp {g}, #0",
            "beq 5f",
            "6:",
            group!(),
            group!(),
            "subs {g}, {g}, #1",
            "bne 6b",
            "5:",
            "ldr {t0}, [sp, #8]",
            "ldr {x0}, [{t0}, #4]",
            "ldr {x1}, [{t0}, #8]",
            "ldr {g}, [{t0}, #12]",
            "add {t0}, {t0}, #16",
            "str {t0}, [sp, #8]",
            "ldr {t0}, [sp, #16]",
            "ldr {t1}, [sp, #0]",
            "smmul {x}, {a0}, {x0}",
            "add {x}, {x}, {x1}",
            "asr {x}, {x}, {g}",
            "ssat {x}, #8, {x}",
            "strb {x}, [{t0}]",
            "smmul {x}, {a1}, {x0}",
            "add {x}, {x}, {x1}",
            "asr {x}, {x}, {g}",
            "ssat {x}, #8, {x}",
            "strb {x}, [{t0}, {t1}]",
            "add {a1}, {t0}, {t1}, lsl #1",
            "smmul {x}, {a2}, {x0}",
            "add {x}, {x}, {x1}",
            "asr {x}, {x}, {g}",
            "ssat {x}, #8, {x}",
            "strb {x}, [{a1}]",
            "smmul {x}, {a3}, {x0}",
            "add {x}, {x}, {x1}",
            "asr {x}, {x}, {g}",
            "ssat {x}, #8, {x}",
            "strb {x}, [{a1}, {t1}]",
            "add {t0}, {t0}, #1",
            "str {t0}, [sp, #16]",
            "ldr {x1}, [sp, #12]",
            "subs {x1}, {x1}, #1",
            "str {x1}, [sp, #12]",
            "bne 3b",
            "add sp, sp, #24",
            w = inout(reg) w.as_ptr() => _,
            xb = in(reg) x.as_ptr(),
            x = out(reg) _,
            g = inout(reg) out.as_mut_ptr() => _,
            t0 = inout(reg) stride => _,
            t1 = inout(reg) k / 32 => _,
            x0 = inout(reg) params.as_ptr() => _,
            x1 = inout(reg) n => _,
            a0 = inout(reg) k % 32 / 8 => _,
            a1 = out(reg) _,
            a2 = out(reg) _,
            a3 = out(reg) _,
        );
    }
    true
}
