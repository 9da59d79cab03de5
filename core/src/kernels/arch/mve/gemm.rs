//! The Cortex-M55 GEMM drivers (the fused one on a chunk of columns, the prepared one, the
//! plain `i32` one), all a pair of rows at a time, and their kernel: the pair against every
//! column triple in one Helium call ([`rows_i32`], the 2 x 3 tile), the last one or two columns
//! through the small tiles.

use super::requant::requant_pair;
#[cfg(not(bino_mve))]
use super::tile::tile3;
use super::tile::{tile1, tile2};
use crate::kernels::arch::fused::{ColRecords, Fused, CHUNK};
use crate::kernels::arch::shape;

/// The fused GEMM's driver (one chunk of at most [`CHUNK`] channels): per pair of rows their
/// accumulators ([`pair_i32`], into a stack scratch), then both rows' requantisation in one
/// Helium kernel ([`requant_pair`]) on the chunk's columns.
pub(crate) fn gemm_fused(a: &[i8], w: &[i8], k: usize, m: usize, epi: &mut Fused<'_>) -> bool {
    let channels = w.len() / k.max(1);
    if k == 0 || channels > CHUNK {
        return false;
    }
    let mut acc = [[0i32; CHUNK]; 2];
    let [acc0, acc1] = &mut acc;
    let (acc0, acc1) = (&mut acc0[..channels], &mut acc1[..channels]);
    for r0 in (0..m).step_by(2) {
        let row = |r: usize| a.get(r * k..(r + 1) * k).unwrap_or(&[]);
        let (a0, a1) = (row(r0), row((r0 + 1).min(m - 1)));
        let pair = r0 + 1 < m;
        if !pair_i32(a0, a1, w, k, acc0, Some(&mut *acc1)) {
            return false;
        }
        if !epi.rows(r0, pair, channels, |p, o0, o1| {
            requant_pair(acc0, acc1, p, o0, Some(o1))
        }) {
            return false;
        }
    }
    true
}

/// The prepared GEMM (the engine's values and MLP-up): every accumulator through
/// [`gemm_i32`] into `acc`, then the rows' requantisation on the prepared columns `cols`, two
/// rows per [`requant_pair`] call. `false` (the caller runs the reference) for shapes
/// [`shape`] declines, `cols` not one per row of `w`, or `acc` shorter than the output.
pub(crate) fn gemm_prepared<C: ColRecords + ?Sized>(
    a: &[i8],
    w: &[i8],
    k: usize,
    cols: &C,
    acc: &mut [i32],
    out: &mut [i8],
) -> bool {
    let Some((m, n)) = shape(a, w, k, out.len()) else {
        return false;
    };
    if cols.count() != n {
        return false;
    }
    let (Some(acc), Some(out)) = (acc.get_mut(..m * n), out.get_mut(..m * n)) else {
        return false;
    };
    if !gemm_i32(a, w, k, m, n, acc) {
        return false;
    }
    let mut rows = acc.chunks_exact(n).zip(out.chunks_exact_mut(n));
    while let Some((acc0, out0)) = rows.next() {
        let done = match rows.next() {
            Some((acc1, out1)) => requant_pair(acc0, acc1, cols, out0, Some(out1)),
            None => requant_pair(acc0, acc0, cols, out0, None),
        };
        if !done {
            return false;
        }
    }
    true
}

/// The plain GEMM's driver (`i32` out, `m x n`): [`pair_i32`] per pair of rows. `false`
/// where the lengths do not hold `m x n` (the caller has checked them).
pub(crate) fn gemm_i32(a: &[i8], w: &[i8], k: usize, m: usize, n: usize, out: &mut [i32]) -> bool {
    for r0 in (0..m).step_by(2) {
        let row = |r: usize| a.get(r * k..(r + 1) * k).unwrap_or(&[]);
        let (a0, a1) = (row(r0), row((r0 + 1).min(m - 1)));
        let pair = r0 + 1 < m;
        let end = (r0 + if pair { 2 } else { 1 }) * n;
        let Some((out0, out1)) = out.get_mut(r0 * n..end).and_then(|o| o.split_at_mut_checked(n)) else {
            return false;
        };
        let out1 = if pair { Some(out1) } else { None };
        if !pair_i32(a0, a1, w, k, out0, out1) {
            return false;
        }
    }
    true
}

/// Rows `a0`, `a1` (`k` codes each) against every row of `w` (`out0.len()` of them): every
/// whole column triple in one kernel call ([`rows_i32`]), then the last one or two columns
/// through `tile1` / `tile2`. `out1` is `None` for an unpaired last row (`a1` then repeats
/// `a0`). `false` where the lengths do not fit.
fn pair_i32(a0: &[i8], a1: &[i8], w: &[i8], k: usize, out0: &mut [i32], mut out1: Option<&mut [i32]>) -> bool {
    let n = out0.len();
    let whole = n / 3 * 3;
    if out1.as_ref().is_some_and(|o| o.len() != n) {
        return false;
    }
    let Some((w_whole, w_rest)) = w.get(..n * k).map(|w| w.split_at(whole * k)) else {
        return false;
    };
    if whole > 0
        && !rows_i32(
            a0,
            a1,
            w_whole,
            k,
            &mut out0[..whole],
            out1.as_mut().map(|o| &mut o[..whole]),
        )
    {
        return false;
    }
    let acc = last_columns(a0, a1, w_rest, [0; 2]);
    for (c, j) in (whole..n).enumerate() {
        out0[j] = acc[0][c];
        if let Some(out1) = out1.as_mut() {
            out1[j] = acc[1][c];
        }
    }
    true
}

/// The one or two columns a chunk has past its triples (`w_rest`: one or two weight rows of
/// `a0.len()` codes), per row; columns not there keep their `init`.
#[inline(always)]
fn last_columns(a0: &[i8], a1: &[i8], w_rest: &[i8], init: [i32; 2]) -> [[i32; 2]; 2] {
    let k = a0.len();
    if k == 0 {
        return [init; 2];
    }
    match w_rest.len() / k {
        2 => {
            let (w0, w1) = w_rest.split_at(k);
            tile2(a0, a1, [w0, w1], init)
        }
        1 => {
            let [acc0, acc1] = tile1(a0, a1, w_rest, init[0]);
            [[acc0, init[1]], [acc1, init[1]]]
        }
        _ => [init; 2],
    }
}

/// One 16-code step of the 2 x 3 tile (rows from r1 and r3, weight rows from r5, r9 and r11,
/// accumulators r0, r2, r4, r8, r10, r12) as assembly text: `vmladav` starting the
/// accumulators ([`tile_step_first`]) or `vmladava` adding to them.
#[cfg(bino_mve)]
macro_rules! tile_step_first {
    () => {
        concat!(
            "vldrb.u8 q0, [r1], #16\n",
            "vldrb.u8 q1, [r3], #16\n",
            "vldrb.u8 q2, [r5], #16\n",
            "vmladav.s8 r0, q0, q2\n",
            "vmladav.s8 r2, q1, q2\n",
            "vldrb.u8 q3, [r9], #16\n",
            "vmladav.s8 r4, q0, q3\n",
            "vmladav.s8 r8, q1, q3\n",
            "vldrb.u8 q2, [r11], #16\n",
            "vmladav.s8 r10, q0, q2\n",
            "vmladav.s8 r12, q1, q2\n",
        )
    };
}

/// [`tile_step_first`] adding to the accumulators.
#[cfg(bino_mve)]
macro_rules! tile_step {
    () => {
        concat!(
            "vldrb.u8 q0, [r1], #16\n",
            "vldrb.u8 q1, [r3], #16\n",
            "vldrb.u8 q2, [r5], #16\n",
            "vmladava.s8 r0, q0, q2\n",
            "vmladava.s8 r2, q1, q2\n",
            "vldrb.u8 q3, [r9], #16\n",
            "vmladava.s8 r4, q0, q3\n",
            "vmladava.s8 r8, q1, q3\n",
            "vldrb.u8 q2, [r11], #16\n",
            "vmladava.s8 r10, q0, q2\n",
            "vmladava.s8 r12, q1, q2\n",
        )
    };
}

/// Six accumulators zeroed (the steps for `k < 32` add to them).
#[cfg(bino_mve)]
macro_rules! zero_accumulators {
    () => {
        concat!(
            "movs r0, #0\n",
            "movs r2, #0\n",
            "movs r4, #0\n",
            "mov.w r8, #0\n",
            "mov.w r10, #0\n",
            "mov.w r12, #0\n",
        )
    };
}

/// The first 32 codes starting the accumulators (`vmladav`, no zeroing), then a plain
/// low-overhead loop (`wls` / `le`) of two 16-code steps per iteration over the next
/// `k / 32 - 1` pairs of steps (the frame's word 5): one loop end per 192 MACs.
#[cfg(bino_mve)]
macro_rules! two_steps {
    () => {
        concat!(
            tile_step_first!(),
            tile_step!(),
            "ldr lr, [sp, #20]\n",
            "wls lr, lr, 5f\n",
            "4:\n",
            tile_step!(),
            tile_step!(),
            "le lr, 4b\n",
            "5:\n",
        )
    };
}

/// A tail-predicated loop (`dlstp` / `letp`) over `lr` codes, 16 a step.
#[cfg(bino_mve)]
macro_rules! tail_steps {
    () => {
        concat!("dlstp.8 lr, lr\n", "6:\n", tile_step!(), "letp lr, 6b\n")
    };
}

/// [`rows_i32`]'s kernel with `$entry` (assembly run once after the frame is laid out) and
/// `$steps` (one triple's dot products into r0, r2, r4, r8, r10, r12): r6 and r7 saved, the frame
/// at `sp` (`a0`, `a1`, the two output pointers, the triples left, the two-step iterations after
/// the first 32 codes, a spare word for `$entry`), `k` in r6 and the next triple's first weight
/// row in r7; per triple the three weight rows `k` apart, the steps, two `stm`s.
#[cfg(bino_mve)]
macro_rules! rows_i32_kernel {
    ($entry:expr, $steps:expr, $a0:expr, $a1:expr, $w:expr, $k:expr, $out0:expr, $second:expr, $n:expr) => {
        core::arch::asm!(
            "push {{r6, r7}}",
            "sub sp, #32",
            "strd r1, r3, [sp, #0]",
            "strd r2, r4, [sp, #8]",
            "str r5, [sp, #16]",
            "mov r6, lr",
            "lsrs lr, lr, #5",
            "subs lr, #1",
            "str lr, [sp, #20]",
            "mov r7, r11",
            $entry,
            "3:",
            "mov r5, r7",
            "add r9, r5, r6",
            "add r11, r9, r6",
            "add r7, r11, r6",
            "ldrd r1, r3, [sp, #0]",
            $steps,
            "ldrd r1, r3, [sp, #8]",
            "stm r1!, {{r0, r4, r10}}",
            "stm r3!, {{r2, r8, r12}}",
            "strd r1, r3, [sp, #8]",
            "ldr r1, [sp, #16]",
            "subs r1, #1",
            "str r1, [sp, #16]",
            "bne 3b",
            "add sp, #32",
            "pop {{r6, r7}}",
            inout("r1") $a0.as_ptr() => _,
            inout("r3") $a1.as_ptr() => _,
            inout("r11") $w.as_ptr() => _,
            inout("lr") $k => _,
            inout("r2") $out0.as_mut_ptr() => _,
            inout("r4") $second => _,
            inout("r5") $n / 3 => _,
            out("r0") _, out("r8") _, out("r9") _, out("r10") _, out("r12") _,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _,
            out("d4") _, out("d5") _, out("d6") _, out("d7") _,
        )
    };
}

/// Rows `a0`, `a1` (`k` codes each) against `out0.len()` weight rows of `w` (a multiple of
/// three) in one Helium kernel: per column triple the 2 x 3 tile's dot products (for `k >= 32`
/// the first 32 codes start the accumulators, then two 16-code steps per `wls`/`le` iteration and
/// a tail-predicated step for the codes past them; for `k < 32` zeroed accumulators and the
/// tail-predicated steps alone) and two `stm`s. `out1` is `None` for an unpaired last row (`a1`
/// is then `a0`'s copy, and its results are written over `out0`'s with the same values).
/// `false` (nothing written) for other lengths. Host tests of the driver run its portable twin
/// (the same sums) after the same checks.
fn rows_i32(a0: &[i8], a1: &[i8], w: &[i8], k: usize, out0: &mut [i32], mut out1: Option<&mut [i32]>) -> bool {
    let n = out0.len();
    if k == 0 || k > crate::kernels::arch::MAX_K || a0.len() != k || a1.len() != k {
        return false;
    }
    if n == 0 || !n.is_multiple_of(3) || w.len() != n * k || out1.as_ref().is_some_and(|o| o.len() != n) {
        return false;
    }
    // Host tests of the driver: the portable twin of the kernel (the same sums).
    #[cfg(not(bino_mve))]
    {
        for (t, triple) in w.chunks_exact(3 * k).enumerate() {
            let (w0, rest) = triple.split_at(k);
            let (w1, w2) = rest.split_at(k);
            let [acc0, acc1] = tile3(a0, a1, [w0, w1, w2], [0; 3]);
            for (o, v) in out0.iter_mut().skip(3 * t).zip(acc0) {
                *o = v;
            }
            if let Some(out1) = out1.as_mut() {
                for (o, v) in out1.iter_mut().skip(3 * t).zip(acc1) {
                    *o = v;
                }
            }
        }
    }
    #[cfg(bino_mve)]
    let second = out1.as_mut().map_or(out0.as_mut_ptr(), |o| o.as_mut_ptr());
    // SAFETY: per triple `t` (`n / 3` of them) the kernel reads exactly `k` bytes of `a0`, `a1`
    // and of weight rows `3t..3t + 3` of `w` (`w`'s `n * k` bytes over the call: whole 16-code
    // steps, and a tail-predicated step whose inactive lanes are not accessed for the codes
    // past them) and writes words `3t..3t + 3` through `out0` and `second` (`out1`'s, or
    // `out0`'s again with the values just stored there: `a1` then equals `a0`). The weight
    // pointers of the next triple come from `k` (r6), never from where the loads stopped. All
    // lengths are checked above; `vldrb.u8` needs no alignment and `stm` gets word-aligned
    // `i32` slices. `r6` and `r7` (which Rust reserves) are saved and restored; the loop state
    // lives in 32 bytes below them. It writes only its declared outputs: r0-r5, r8-r12, `lr`
    // (a `letp` restores FPSCR.LTPSIZE) and q0-q3.
    #[cfg(bino_mve)]
    unsafe {
        if k < 32 {
            rows_i32_kernel!(
                "",
                concat!(zero_accumulators!(), "mov lr, r6\n", tail_steps!()),
                a0,
                a1,
                w,
                k,
                out0,
                second,
                n
            );
        } else if k.is_multiple_of(32) {
            rows_i32_kernel!("", two_steps!(), a0, a1, w, k, out0, second, n);
        } else {
            rows_i32_kernel!(
                "and r8, r6, #31\nstr r8, [sp, #24]\n",
                concat!(two_steps!(), "ldr lr, [sp, #24]\n", tail_steps!()),
                a0,
                a1,
                w,
                k,
                out0,
                second,
                n
            );
        }
    }
    true
}
