//! Cortex-M55 (Helium, MVE) kernels: the GEMMs, a pair of rows against every column triple in
//! one kernel call (2 x 3 tiles, 16 MACs per `vmladava.s8` into scalar accumulators and an
//! `i32` store; a 2 x 1 or 2 x 2 tile for the last one or two columns), the fused
//! requantisation of two rows of accumulators in vector lanes; attention's scores with the
//! queries held in vector registers; the softmax row; LayerNorm's and the residual add's lanes.
//!
//! Where `k` is a multiple of 32 (the encoder's GEMMs and attention) the first 32 codes start
//! the accumulators and a plain loop runs two 16-code steps per iteration: per 192 MACs ten
//! `vldrb`, twelve `vmladava` and the loop end. Any other `k` runs one tail-predicated loop
//! (`dlstp.8` / `letp`) in steps of 16, whose last step loads and multiplies only the elements
//! left, so nothing is read past a row.

use super::fused::{ColRecords, Fused, CHUNK};
use super::shape;
#[cfg(bino_mve)]
use crate::config::HEAD_DIM;
#[cfg(bino_mve)]
use crate::kernels::exp::{ExpQ32, EXP2_NEG_I8_TABLE, EXP2_TABLE_LAST, EXP_Q32_MAX_GAP};

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
/// `false` (nothing written) for other lengths.
#[cfg(bino_mve)]
fn rows_i32(a0: &[i8], a1: &[i8], w: &[i8], k: usize, out0: &mut [i32], mut out1: Option<&mut [i32]>) -> bool {
    let n = out0.len();
    if k == 0 || k > super::MAX_K || a0.len() != k || a1.len() != k {
        return false;
    }
    if n == 0 || !n.is_multiple_of(3) || w.len() != n * k || out1.as_ref().is_some_and(|o| o.len() != n) {
        return false;
    }
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

/// The portable twin of [`rows_i32`] (host tests of the driver).
#[cfg(not(bino_mve))]
fn rows_i32(a0: &[i8], a1: &[i8], w: &[i8], k: usize, out0: &mut [i32], mut out1: Option<&mut [i32]>) -> bool {
    let n = out0.len();
    if k == 0 || !n.is_multiple_of(3) || w.len() != n * k || out1.as_ref().is_some_and(|o| o.len() != n) {
        return false;
    }
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
    true
}

/// Byte offsets of `bias`, `mult`, `addend` and `s` of four consecutive columns in an array
/// of 16-byte column records ([`ColRecords`]): the gathers of [`requant_pair`].
#[cfg(bino_mve)]
static COL_GATHER: [[u32; 4]; 4] = [[0, 16, 32, 48], [4, 20, 36, 52], [8, 24, 40, 56], [12, 28, 44, 60]];

/// Two rows of accumulators (`acc0`, `acc1`: dot products without the bias, one per column of
/// `cols`) through the fused requantisation into `out0` and `out1` (`None`: an unpaired row,
/// `acc1` then repeats `acc0`), in one tail-predicated Helium loop, four columns a step:
/// the columns' `bias`, `mult`, `addend` and `s` gathered from their records, then per row
/// `vadd`, `vmulh.s32`, `vadd`, `vshl.s32` by `-s`, two saturating narrowings and a 4-byte
/// store (23 instructions per 8 outputs). `false` (nothing written) for other lengths.
#[cfg(bino_mve)]
fn requant_pair<C: ColRecords + ?Sized>(
    acc0: &[i32],
    acc1: &[i32],
    cols: &C,
    out0: &mut [i8],
    out1: Option<&mut [i8]>,
) -> bool {
    let n = cols.count();
    if n == 0 || acc0.len() != n || acc1.len() != n || out0.len() != n || out1.as_ref().is_some_and(|o| o.len() != n) {
        return false;
    }
    let second = out1.map_or(out0.as_mut_ptr(), |o| o.as_mut_ptr());
    // SAFETY: the tail-predicated loop (`n >= 1` 32-bit lanes, four a step) reads exactly
    // `n` words of `acc0` and of `acc1`, the four gathered words of each of the `n` 16-byte
    // records at `cols.base()` (`ColRecords` promises `count()` of them; offsets from
    // `COL_GATHER`, 64 bytes a step) and writes exactly `n` bytes through `out0` and
    // `second` (`out1`'s, or `out0`'s again with the same values: then `acc1` is `acc0`).
    // Predicated-off lanes of the last step are not accessed. All lengths are checked above;
    // `vldrw` gets word-aligned `i32` data, `vstrb.32` needs no alignment (and low registers,
    // r3 and r5). It writes only its declared outputs: the pointers, `lr` (`letp` restores
    // FPSCR.LTPSIZE) and q0-q7.
    unsafe {
        core::arch::asm!(
            "vldrw.u32 q4, [{gather}]",
            "vldrw.u32 q5, [{gather}, #16]",
            "vldrw.u32 q6, [{gather}, #32]",
            "vldrw.u32 q7, [{gather}, #48]",
            "dlstp.32 lr, lr",
            "2:",
            "vldrw.u32 q0, [r0], #16",
            "vldrw.u32 q1, [r1], #16",
            "vldrw.u32 q2, [r2, q4]",
            "vadd.i32 q0, q0, q2",
            "vadd.i32 q1, q1, q2",
            "vldrw.u32 q2, [r2, q5]",
            "vmulh.s32 q0, q0, q2",
            "vmulh.s32 q1, q1, q2",
            "vldrw.u32 q2, [r2, q6]",
            "vadd.i32 q0, q0, q2",
            "vadd.i32 q1, q1, q2",
            "vldrw.u32 q3, [r2, q7]",
            "vneg.s32 q3, q3",
            "vshl.s32 q0, q0, q3",
            "vshl.s32 q1, q1, q3",
            "vqmovnb.s32 q0, q0",
            "vqmovnb.s32 q1, q1",
            "vqmovnb.s16 q0, q0",
            "vqmovnb.s16 q1, q1",
            "vstrb.32 q0, [r3], #4",
            "vstrb.32 q1, [r5], #4",
            "adds r2, #64",
            "letp lr, 2b",
            gather = in(reg) COL_GATHER.as_ptr(),
            inout("r0") acc0.as_ptr() => _,
            inout("r1") acc1.as_ptr() => _,
            inout("r2") cols.base() => _,
            inout("r3") out0.as_mut_ptr() => _,
            inout("r5") second => _,
            inout("lr") n => _,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _, out("d4") _, out("d5") _, out("d6") _,
            out("d7") _, out("d8") _, out("d9") _, out("d10") _, out("d11") _, out("d12") _, out("d13") _,
            out("d14") _, out("d15") _,
            options(nostack),
        );
    }
    true
}

/// The portable twin of [`requant_pair`] (host tests of the drivers).
#[cfg(not(bino_mve))]
fn requant_pair<C: ColRecords + ?Sized>(
    acc0: &[i32],
    acc1: &[i32],
    cols: &C,
    out0: &mut [i8],
    out1: Option<&mut [i8]>,
) -> bool {
    let n = cols.count();
    if n == 0 || acc0.len() != n || acc1.len() != n || out0.len() != n || out1.as_ref().is_some_and(|o| o.len() != n) {
        return false;
    }
    let rows = [(acc0, Some(out0)), (acc1, out1)];
    for (acc, out) in rows {
        for (j, (o, &v)) in out.into_iter().flatten().zip(acc).enumerate() {
            if let Some(c) = cols.col(j) {
                *o = c.apply(v.wrapping_add(c.bias()));
            }
        }
    }
    true
}

/// `init[c] + a_r . w_c` for rows `a0`, `a1` and two weight rows: per 64 MACs four `vldrb`,
/// four `vmladava` and the loop end (two `tile1`s take six loads for the same work).
#[cfg(bino_mve)]
#[inline(always)]
fn tile2(a0: &[i8], a1: &[i8], w: [&[i8]; 2], init: [i32; 2]) -> [[i32; 2]; 2] {
    let k = a0.len();
    if k == 0 || a1.len() != k || w.iter().any(|w| w.len() != k) {
        return [init; 2];
    }
    let ([mut s00, mut s01], [mut s10, mut s11]) = (init, init);
    // SAFETY: the tail-predicated loop reads exactly `k >= 1` bytes from each of the four
    // pointers, all checked above to be rows of `k` bytes (`vldrb.u8` needs no alignment;
    // predicated-off lanes of the last step are not accessed). It writes only its declared
    // outputs: the accumulators, the pointers, `lr` (loop count) and q0-q3 (declared through
    // their `d` aliases). `letp` restores FPSCR.LTPSIZE to 4 when the loop exits.
    unsafe {
        core::arch::asm!(
            "dlstp.8 lr, lr",
            "2:",
            "vldrb.u8 q0, [{a0}], #16",
            "vldrb.u8 q1, [{a1}], #16",
            "vldrb.u8 q2, [{w0}], #16",
            "vmladava.s8 r0, q0, q2",
            "vmladava.s8 r2, q1, q2",
            "vldrb.u8 q3, [{w1}], #16",
            "vmladava.s8 r4, q0, q3",
            "vmladava.s8 r8, q1, q3",
            "letp lr, 2b",
            a0 = inout(reg) a0.as_ptr() => _,
            a1 = inout(reg) a1.as_ptr() => _,
            w0 = inout(reg) w[0].as_ptr() => _,
            w1 = inout(reg) w[1].as_ptr() => _,
            inout("lr") k => _,
            inout("r0") s00,
            inout("r2") s10,
            inout("r4") s01,
            inout("r8") s11,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _,
            out("d4") _, out("d5") _, out("d6") _, out("d7") _,
            options(nostack, readonly, pure),
        );
    }
    [[s00, s01], [s10, s11]]
}

/// `init + a_r . w` for rows `a0`, `a1` and one weight row.
#[cfg(bino_mve)]
#[inline(always)]
fn tile1(a0: &[i8], a1: &[i8], w: &[i8], init: i32) -> [i32; 2] {
    let k = a0.len();
    if k == 0 || a1.len() != k || w.len() != k {
        return [init; 2];
    }
    let (mut s0, mut s1) = (init, init);
    // SAFETY: the tail-predicated loop reads exactly `k >= 1` bytes from each of the three
    // pointers, all checked above to be rows of `k` bytes (`vldrb.u8` needs no alignment;
    // predicated-off lanes of the last step are not accessed). It writes only its declared
    // outputs: the accumulators, the pointers, `lr` (loop count) and q0-q2 (declared through
    // their `d` aliases). `letp` restores FPSCR.LTPSIZE to 4 when the loop exits.
    unsafe {
        core::arch::asm!(
            "dlstp.8 lr, lr",
            "2:",
            "vldrb.u8 q0, [{a0}], #16",
            "vldrb.u8 q1, [{a1}], #16",
            "vldrb.u8 q2, [{w0}], #16",
            "vmladava.s8 r0, q0, q2",
            "vmladava.s8 r2, q1, q2",
            "letp lr, 2b",
            a0 = inout(reg) a0.as_ptr() => _,
            a1 = inout(reg) a1.as_ptr() => _,
            w0 = inout(reg) w.as_ptr() => _,
            inout("lr") k => _,
            inout("r0") s0,
            inout("r2") s1,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _, out("d4") _, out("d5") _,
            options(nostack, readonly, pure),
        );
    }
    [s0, s1]
}

/// Attention scores of four queries (`HEAD_DIM` = 32 codes: two vectors each) against every
/// key, two queries at a time held in q0-q3 and three keys a step through q4-q7: per key
/// triple six `vldrb`, twelve `vmladav(a)` and two `stm` (192 MACs in 21 instructions; two
/// keys a step took 15 per 128, one key 18). The last one or two keys of a count not divisible
/// by three are scored in Rust. Declines (`false`) unless `scores` is exactly `4 * n` for
/// `n >= 1` keys.
#[cfg(bino_mve)]
pub(crate) fn attention_scores(queries: &[[i8; HEAD_DIM]; 4], keys: &[i8], scores: &mut [i32]) -> bool {
    const _: () = assert!(HEAD_DIM == 32);
    let n = keys.len() / HEAD_DIM;
    if n == 0 || scores.len() != 4 * n {
        return false;
    }
    let triples = n / 3;
    let (first, second) = scores.split_at_mut(2 * n);
    let [q0, q1, q2, q3] = queries;
    for ((qa, qb), rows) in [((q0, q1), first), ((q2, q3), second)] {
        let (row_a, row_b) = rows.split_at_mut(n);
        if triples > 0 {
            // SAFETY: reads the two 32-byte queries, then loops `triples >= 1` times
            // (`dls`/`le`), each time reading 96 bytes of `keys` (`3 * triples * 32 <= n * 32`
            // bytes in all, checked above) and writing three words to each of `row_a` and
            // `row_b` (`3 * triples <= n` words each). `vldrb.u8` needs no alignment; `stm`
            // needs word alignment, which the `i32` rows have. It writes only its declared
            // outputs: the pointers, r0, r2, r4, r8, r10, r12 (`vmladav` takes even
            // accumulators), `lr` and q0-q7 (through their `d` aliases; the compiler saves the
            // callee-saved d8-d15).
            unsafe {
                core::arch::asm!(
                    "vldrb.u8 q0, [{qa}]",
                    "vldrb.u8 q1, [{qa}, #16]",
                    "vldrb.u8 q2, [{qb}]",
                    "vldrb.u8 q3, [{qb}, #16]",
                    "dls lr, lr",
                    "2:",
                    // Loads interleaved with products: the M55 overlaps a load's beats with
                    // a multiply's (Software Optimization Guide), not two of one kind.
                    "vldrb.u8 q4, [{k}], #16",
                    "vldrb.u8 q5, [{k}], #16",
                    "vmladav.s8 r0, q0, q4",
                    "vldrb.u8 q6, [{k}], #16",
                    "vmladava.s8 r0, q1, q5",
                    "vldrb.u8 q7, [{k}], #16",
                    "vmladav.s8 r8, q2, q4",
                    "vmladava.s8 r8, q3, q5",
                    "vldrb.u8 q4, [{k}], #16",
                    "vmladav.s8 r2, q0, q6",
                    "vldrb.u8 q5, [{k}], #16",
                    "vmladava.s8 r2, q1, q7",
                    "vmladav.s8 r10, q2, q6",
                    "vmladava.s8 r10, q3, q7",
                    "vmladav.s8 r4, q0, q4",
                    "vmladava.s8 r4, q1, q5",
                    "vmladav.s8 r12, q2, q4",
                    "vmladava.s8 r12, q3, q5",
                    "stm {sa}!, {{r0, r2, r4}}",
                    "stm {sb}!, {{r8, r10, r12}}",
                    "le lr, 2b",
                    qa = in(reg) qa.as_ptr(),
                    qb = in(reg) qb.as_ptr(),
                    k = inout(reg) keys.as_ptr() => _,
                    sa = inout(reg) row_a.as_mut_ptr() => _,
                    sb = inout(reg) row_b.as_mut_ptr() => _,
                    inout("lr") triples => _,
                    out("r0") _,
                    out("r2") _,
                    out("r4") _,
                    out("r8") _,
                    out("r10") _,
                    out("r12") _,
                    out("d0") _, out("d1") _, out("d2") _, out("d3") _, out("d4") _, out("d5") _,
                    out("d6") _, out("d7") _, out("d8") _, out("d9") _, out("d10") _, out("d11") _,
                    out("d12") _, out("d13") _, out("d14") _, out("d15") _,
                    options(nostack),
                );
            }
        }
        for j in 3 * triples..n {
            let key = keys.get(j * HEAD_DIM..(j + 1) * HEAD_DIM).unwrap_or(&[]);
            if let (Some(a), Some(b)) = (row_a.get_mut(j), row_b.get_mut(j)) {
                *a = crate::kernels::matmul::dot(qa, key);
                *b = crate::kernels::matmul::dot(qb, key);
            }
        }
    }
    true
}

/// The softmax rows' first step as assembly text: four scores from `r0` and their gaps below
/// the row maximum in `q2`.
#[cfg(bino_mve)]
macro_rules! softmax_gap {
    () => {
        concat!("vldrw.u32 q0, [r0], #16\n", "vsub.i32 q0, q2, q0\n")
    };
}

/// The softmax rows' weights from the gaps in `q0`: the multiplier `q4`'s high half, the
/// rounding shift by `-post`, the index clamp to the table's last entry (`q5`), the gather of
/// `w - 128` from `r2`, its sum into `r4` and the byte store to `r1`.
#[cfg(bino_mve)]
macro_rules! softmax_weight {
    () => {
        concat!(
            "vmulh.u32 q0, q0, q4\n",
            "vrshl.u32 q0, {neg_post}\n",
            "vmin.u32 q0, q0, q5\n",
            "vldrb.s32 q1, [r2, q0]\n",
            "vaddva.s32 r4, q1\n",
            "vstrb.32 q1, [r1], #4\n",
        )
    };
}

/// One softmax row, four scores a step: `ExpQ32::weight_by_table` on every lane (`vmulh.u32`
/// gives the product's high word directly, a gather load reads the byte table), the weights
/// stored as `w ^ 0x80` and summed. Nine instructions per four elements where a gap of 2^20
/// already reaches weight 0 (every attention of the shipped blob), eleven otherwise, where the
/// auto-vectorised cubic takes 42.
#[cfg(bino_mve)]
pub(crate) fn softmax_row(e: &ExpQ32, max: i32, scores: &[i32], weights: &mut [u8]) -> u32 {
    let n = scores.len().min(weights.len());
    if n == 0 {
        return 0;
    }
    // The immediates below are `vmov.i32` encodable; the table ends at its last entry.
    const _: () = assert!(EXP_Q32_MAX_GAP == 0x10_0000 && EXP2_TABLE_LAST == 0x900);
    const _: () = assert!(EXP2_NEG_I8_TABLE.len() == EXP2_TABLE_LAST as usize + 1);
    let (pre, round, post) = e.shifts();
    // `round` is `2^(post - 1)` (`ExpQ32::new`; `exp.rs` tests it for every shift), so the add
    // and the right shift are one rounding shift (`vrshl.u32` by `-post`, exact: its
    // intermediate cannot overflow).
    let mut centred = 0u32;
    // Where the multiplier shifted by `pre` fits 32 bits and the gap 2^20 already maps to the
    // table's last entry (weight 0), the gap needs neither its clamp nor its shift: the index
    // grows with the gap, so larger gaps (which the specification clamps to 2^20) and wrapped
    // ones land on weight 0 too, and `hi(gap * (mult << pre))` is `hi((gap << pre) * mult)`.
    // Nine instructions per four scores instead of eleven (every attention of the shipped blob).
    let folded = (e.mult() as u64) << pre;
    let index = |gap: u64| (((gap * folded) >> 32) + round as u64) >> post;
    let folds = folded < 1 << 32 && index(EXP_Q32_MAX_GAP as u64) >= EXP2_TABLE_LAST as u64;
    if folds && n.is_multiple_of(8) {
        // Eight scores a step (a band's 960): loaded de-interleaved (`vld20`/`vld21`: even
        // elements in q0, odd in q1), so that after the per-lane steps one `vmovnt` packs the
        // eight indices in order into 16-bit lanes for one gather of eight weights, one sum and
        // one store: 15 instructions per eight scores instead of 18.
        // SAFETY: the loop runs `n / 8 >= 1` times (`dls`/`le`), each time reading 32 bytes
        // (eight words) of `scores` and writing eight bytes of `weights` (both at least `n`
        // long). Every gather offset is clamped to `EXP2_TABLE_LAST` (below 2^16) by the
        // `vmin.u32` before the narrowing, so each table read lies inside
        // `EXP2_NEG_I8_TABLE`. `vld2` takes word-aligned `i32` data. The narrowing `vstrb.16`
        // and the gather need low registers (r0-r2), `vaddva` an even one (r4). It writes only
        // its declared outputs: the pointers, the sum, `lr` and q0-q5.
        unsafe {
            core::arch::asm!(
                "vdup.32 q2, {max}",
                "vdup.32 q4, {mult}",
                "vmov.i32 q5, #0x900",
                "dls lr, lr",
                "2:",
                "vld20.32 {{q0, q1}}, [r0]",
                "vld21.32 {{q0, q1}}, [r0]!",
                "vsub.i32 q0, q2, q0",
                "vsub.i32 q1, q2, q1",
                "vmulh.u32 q0, q0, q4",
                "vmulh.u32 q1, q1, q4",
                "vrshl.u32 q0, {neg_post}",
                "vrshl.u32 q1, {neg_post}",
                "vmin.u32 q0, q0, q5",
                "vmin.u32 q1, q1, q5",
                "vmovnt.i32 q0, q1",
                "vldrb.s16 q1, [r2, q0]",
                "vaddva.s16 r4, q1",
                "vstrb.16 q1, [r1], #8",
                "le lr, 2b",
                max = in(reg) max,
                mult = in(reg) folded as u32,
                neg_post = in(reg) (post as i32).wrapping_neg(),
                inout("r0") scores.as_ptr() => _,
                inout("r1") weights.as_mut_ptr() => _,
                in("r2") EXP2_NEG_I8_TABLE.as_ptr(),
                inout("r4") centred,
                inout("lr") n / 8 => _,
                out("d0") _, out("d1") _, out("d2") _, out("d3") _, out("d4") _, out("d5") _,
                out("d8") _, out("d9") _, out("d10") _, out("d11") _,
                options(nostack),
            );
        }
        return centred.wrapping_add((n as u32).wrapping_mul(128));
    }
    if folds {
        // SAFETY: as below, with the gap's clamp and shift left out: every gather offset is
        // still clamped to `EXP2_TABLE_LAST` by the `vmin.u32` just before it.
        unsafe {
            core::arch::asm!(
                "vdup.32 q2, {max}",
                "vdup.32 q4, {mult}",
                "vmov.i32 q5, #0x900",
                "dlstp.32 lr, lr",
                "2:",
                softmax_gap!(),
                softmax_weight!(),
                "letp lr, 2b",
                max = in(reg) max,
                mult = in(reg) folded as u32,
                neg_post = in(reg) (post as i32).wrapping_neg(),
                inout("r0") scores.as_ptr() => _,
                inout("r1") weights.as_mut_ptr() => _,
                in("r2") EXP2_NEG_I8_TABLE.as_ptr(),
                inout("r4") centred,
                inout("lr") n => _,
                out("d0") _, out("d1") _, out("d2") _, out("d3") _, out("d4") _, out("d5") _,
                out("d8") _, out("d9") _, out("d10") _, out("d11") _,
                options(nostack),
            );
        }
        return centred.wrapping_add((n as u32).wrapping_mul(128));
    }
    // SAFETY: the tail-predicated loop reads `n` words from `scores` and writes `n` bytes to
    // `weights` (both at least `n` long; predicated-off lanes of the last step are not
    // accessed). Every gather offset is clamped to `EXP2_TABLE_LAST` by the `vmin.u32` just
    // before it, so each table read lies inside `EXP2_NEG_I8_TABLE`. The narrowing `vstrb.32`
    // and the gather need low registers, hence the fixed r0-r2 (and `vaddva` an even one, r4).
    // It writes only its declared outputs: the pointers, the sum, `lr` and q0-q5 (through
    // their `d` aliases); `letp` restores FPSCR.LTPSIZE when the loop exits.
    unsafe {
        core::arch::asm!(
            "vdup.32 q2, {max}",
            "vdup.32 q4, {mult}",
            "vmov.i32 q3, #0x100000",
            "vmov.i32 q5, #0x900",
            "dlstp.32 lr, lr",
            "2:",
            softmax_gap!(),
            // The gap clamped to 2^20 and shifted by `pre` (what the rows above fold away).
            "vmin.u32 q0, q0, q3",
            "vshl.u32 q0, {pre}",
            softmax_weight!(),
            "letp lr, 2b",
            max = in(reg) max,
            mult = in(reg) e.mult(),
            pre = in(reg) pre,
            neg_post = in(reg) (post as i32).wrapping_neg(),
            inout("r0") scores.as_ptr() => _,
            inout("r1") weights.as_mut_ptr() => _,
            in("r2") EXP2_NEG_I8_TABLE.as_ptr(),
            inout("r4") centred,
            inout("lr") n => _,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _, out("d4") _, out("d5") _,
            out("d6") _, out("d7") _, out("d8") _, out("d9") _, out("d10") _, out("d11") _,
            options(nostack),
        );
    }
    // Each lane held `w - 128`: the weights' sum is the lanes' sum plus 128 per element.
    centred.wrapping_add((n as u32).wrapping_mul(128))
}

/// One half of a head rotated, bit for bit `rope::rotate_half_in_lanes`: pairs
/// `(a_i, b_i) = (v[i], v[8 + i])` with angles `(cos[i], sin[i])`, four pairs a step in 32-bit
/// lanes, the operands split at bit 12 (`a = 2^12 a_h + a_l`) so that no product passes 32 bits:
/// `((a_h c - b_h s) + ((a_l c - b_l s + 2^21) >> 12)) >> 10` into `out[i]` and
/// `((b_h c + a_h s) + ((b_l c + a_l s + 2^21) >> 12)) >> 10` into `out[8 + i]`, each saturated
/// to int8 (37 instructions per four pairs).
#[cfg(bino_mve)]
pub(crate) fn rope_rotate_half(v: &[i32; 16], cos: &[i16; 8], sin: &[i16; 8], out: &mut [i8; 16]) {
    // SAFETY: two iterations (`dls`/`le`), each reading four words of each half of `v` (from
    // `v` and `v + 8`), four halfwords of `cos` and of `sin`, and writing four bytes of each half
    // of `out` (from `out` and `out + 8`): exactly the arrays' sizes. `vldrw` gets word-aligned
    // `i32`s and `vldrh` halfword-aligned `i16`s; the widening loads and narrowing stores use low
    // registers (r0-r5). It writes only its declared outputs: the pointers, `lr` and q0-q7.
    unsafe {
        core::arch::asm!(
            "dls lr, lr",
            "2:",
            "vldrw.u32 q0, [r0], #16",
            "vldrw.u32 q1, [r1], #16",
            "vldrh.s32 q2, [r2], #8",
            "vldrh.s32 q3, [r3], #8",
            // a_h, b_h, then a_l = a - 2^12 a_h and b_l likewise.
            "vshr.s32 q4, q0, #12",
            "vshr.s32 q5, q1, #12",
            "vshl.i32 q6, q4, #12",
            "vsub.i32 q0, q0, q6",
            "vshl.i32 q6, q5, #12",
            "vsub.i32 q1, q1, q6",
            // The first output of each pair in q6.
            "vmul.i32 q6, q0, q2",
            "vmul.i32 q7, q1, q3",
            "vsub.i32 q6, q6, q7",
            "vadd.i32 q6, q6, {half}",
            "vshr.s32 q6, q6, #12",
            "vmul.i32 q7, q4, q2",
            "vadd.i32 q6, q6, q7",
            "vmul.i32 q7, q5, q3",
            "vsub.i32 q6, q6, q7",
            "vshr.s32 q6, q6, #10",
            // The second in q7 (a_l's register reused once it is read).
            "vmul.i32 q7, q1, q2",
            "vmul.i32 q0, q0, q3",
            "vadd.i32 q7, q7, q0",
            "vadd.i32 q7, q7, {half}",
            "vshr.s32 q7, q7, #12",
            "vmul.i32 q0, q5, q2",
            "vadd.i32 q7, q7, q0",
            "vmul.i32 q0, q4, q3",
            "vadd.i32 q7, q7, q0",
            "vshr.s32 q7, q7, #10",
            "vqmovnb.s32 q6, q6",
            "vqmovnb.s32 q7, q7",
            "vqmovnb.s16 q6, q6",
            "vqmovnb.s16 q7, q7",
            "vstrb.32 q6, [r4], #4",
            "vstrb.32 q7, [r5], #4",
            "le lr, 2b",
            half = in(reg) 1i32 << 21,
            inout("r0") v.as_ptr() => _,
            inout("r1") v[8..].as_ptr() => _,
            inout("r2") cos.as_ptr() => _,
            inout("r3") sin.as_ptr() => _,
            inout("r4") out.as_mut_ptr() => _,
            inout("r5") out[8..].as_mut_ptr() => _,
            inout("lr") 2usize => _,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _, out("d4") _, out("d5") _, out("d6") _,
            out("d7") _, out("d8") _, out("d9") _, out("d10") _, out("d11") _, out("d12") _, out("d13") _,
            out("d14") _, out("d15") _,
            options(nostack),
        );
    }
}

/// The largest of `scores` for a multiple of 16 of them: sixteen a step, four vector loads
/// and four running `vmax.s32`, then one `vmaxv` per accumulator (9 instructions per 16
/// scores, where the compiler's loop takes 12). `None` (nothing read) for other lengths.
#[cfg(bino_mve)]
pub(crate) fn row_max(scores: &[i32]) -> Option<i32> {
    let n = scores.len();
    if n == 0 || !n.is_multiple_of(16) {
        return None;
    }
    let mut max = i32::MIN;
    // SAFETY: the loop runs `n / 16 >= 1` times (`dls`/`le`), each time reading 64 bytes
    // (sixteen words) of `scores`, `n` words in all (checked above); `vldrw` gets word-aligned
    // `i32` data. It writes only its declared outputs: the pointer, the maximum, `lr` and
    // q0-q7.
    unsafe {
        core::arch::asm!(
            "vdup.32 q4, {max}",
            "vmov q5, q4",
            "vmov q6, q4",
            "vmov q7, q4",
            "dls lr, lr",
            "2:",
            "vldrw.u32 q0, [{p}], #16",
            "vldrw.u32 q1, [{p}], #16",
            "vmax.s32 q4, q4, q0",
            "vldrw.u32 q2, [{p}], #16",
            "vmax.s32 q5, q5, q1",
            "vldrw.u32 q3, [{p}], #16",
            "vmax.s32 q6, q6, q2",
            "vmax.s32 q7, q7, q3",
            "le lr, 2b",
            "vmaxv.s32 {max}, q4",
            "vmaxv.s32 {max}, q5",
            "vmaxv.s32 {max}, q6",
            "vmaxv.s32 {max}, q7",
            max = inout(reg) max,
            p = inout(reg) scores.as_ptr() => _,
            inout("lr") n / 16 => _,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _, out("d4") _, out("d5") _, out("d6") _,
            out("d7") _, out("d8") _, out("d9") _, out("d10") _, out("d11") _, out("d12") _, out("d13") _,
            out("d14") _, out("d15") _,
            options(nostack, readonly, pure),
        );
    }
    Some(max)
}

/// `store[c * tokens + t] = token[c]` for every channel `c` (the attention values stored
/// channel-major, `[channel][token]`): eight channels a step, one widening `vldrb.s16` and one
/// scatter `vstrb.16` through the offsets `0, tokens, .., 7 tokens` (four instructions per
/// eight channels, where the byte loop takes about 50). `false` (nothing written) unless
/// `token` holds a positive multiple of eight channels, `t < tokens`, `7 * tokens` fits the
/// scatter's 16-bit offsets and `store` holds `token.len() * tokens` bytes.
#[cfg(bino_mve)]
pub(crate) fn scatter_channels(token: &[i8], store: &mut [i8], tokens: usize, t: usize) -> bool {
    let n = token.len();
    let fits = n.checked_mul(tokens).is_some_and(|len| len <= store.len());
    let offsets_fit = tokens.checked_mul(7).is_some_and(|last| last <= u16::MAX as usize);
    if n == 0 || !n.is_multiple_of(8) || t >= tokens || !offsets_fit || !fits {
        return false;
    }
    let offsets: [u16; 8] = core::array::from_fn(|i| (i * tokens) as u16);
    // SAFETY: the loop runs `n / 8 >= 1` times (`dls`/`le`), each time reading eight bytes of
    // `token` (`n` in all) and writing eight bytes at `store + t + 8 s tokens + i tokens` for
    // step `s` and lane `i < 8`: channel `c = 8 s + i < n` at `c * tokens + t < n * tokens <=
    // store.len()` (checked above), each offset below 2^16. Bytes need no alignment; `offsets`
    // is a `u16` array. It writes only its declared outputs: the pointers, `lr`, q0 and q1.
    unsafe {
        core::arch::asm!(
            "vldrh.u16 q1, [{off}]",
            "dls lr, lr",
            "2:",
            "vldrb.s16 q0, [{src}], #8",
            "vstrb.16 q0, [{dst}, q1]",
            "add {dst}, {step}",
            "le lr, 2b",
            off = in(reg) offsets.as_ptr(),
            src = inout(reg) token.as_ptr() => _,
            dst = inout(reg) store.as_mut_ptr().wrapping_add(t) => _,
            step = in(reg) 8 * tokens,
            inout("lr") n / 8 => _,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _,
            options(nostack),
        );
    }
    true
}

/// LayerNorm values of one row, four channels a step: `vldrb.s32`, `vsub`, `vmul`, the 64-bit
/// sum (`vaddlva`) and the extremes (`vminv`, `vmaxv`). `None` unless the slices have one
/// length `n >= 1`.
#[cfg(bino_mve)]
pub(crate) fn layernorm_values(row: &[i8], zero: &[i32], rel: &[i32], v: &mut [i32]) -> Option<(i64, i32, i32)> {
    let n = row.len();
    if n == 0 || zero.len() != n || rel.len() != n || v.len() != n {
        return None;
    }
    let (mut lo, mut hi) = (i32::MAX, i32::MIN);
    let (mut sum_lo, mut sum_hi) = (0u32, 0u32);
    // SAFETY: the tail-predicated loop reads `n` bytes of `row` and `n` words of `zero` and
    // `rel`, and writes `n` words of `v` (all checked to be `n` long; predicated-off lanes are
    // not accessed). The narrowing `vldrb.s32` needs a low register (r0). It writes only its
    // declared outputs: the pointers, the sums and extremes, `lr` and q0-q1.
    unsafe {
        core::arch::asm!(
            "dlstp.32 lr, lr",
            "2:",
            "vldrb.s32 q0, [r0], #4",
            "vldrw.u32 q1, [{zero}], #16",
            "vsub.i32 q0, q0, q1",
            "vldrw.u32 q1, [{rel}], #16",
            "vmul.i32 q0, q0, q1",
            "vstrw.32 q0, [{v}], #16",
            "vaddlva.s32 r2, r3, q0",
            "vminv.s32 {lo}, q0",
            "vmaxv.s32 {hi}, q0",
            "letp lr, 2b",
            inout("r0") row.as_ptr() => _,
            zero = inout(reg) zero.as_ptr() => _,
            rel = inout(reg) rel.as_ptr() => _,
            v = inout(reg) v.as_mut_ptr() => _,
            inout("r2") sum_lo,
            inout("r3") sum_hi,
            lo = inout(reg) lo,
            hi = inout(reg) hi,
            inout("lr") n => _,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _,
            options(nostack),
        );
    }
    Some(((((sum_hi as u64) << 32) | sum_lo as u64) as i64, lo, hi))
}

/// LayerNorm normalisation of one row: `n = ((v << left) + add) >> right` (arithmetic) and
/// the 64-bit sum of `n * n` (`vmlaldava`). `None` unless `v` and `n` have one length `>= 1`
/// and the shifts are below 32.
#[cfg(bino_mve)]
pub(crate) fn layernorm_normalise(v: &[i32], left: u32, add: i32, right: u32, n: &mut [i32]) -> Option<i64> {
    let len = v.len();
    if len == 0 || n.len() != len || left > 31 || right > 31 {
        return None;
    }
    let (mut sq_lo, mut sq_hi) = (0u32, 0u32);
    // SAFETY: the tail-predicated loop reads `len` words of `v` and writes `len` words of `n`
    // (both checked). It writes only its declared outputs: the pointers, the sums, `lr` and q0.
    unsafe {
        core::arch::asm!(
            "dlstp.32 lr, lr",
            "2:",
            "vldrw.u32 q0, [{v}], #16",
            "vshl.s32 q0, {left}",
            "vadd.i32 q0, q0, {add}",
            "vshl.s32 q0, {neg_right}",
            "vstrw.32 q0, [{n}], #16",
            "vmlaldava.s32 r2, r3, q0, q0",
            "letp lr, 2b",
            v = inout(reg) v.as_ptr() => _,
            n = inout(reg) n.as_mut_ptr() => _,
            left = in(reg) left,
            add = in(reg) add,
            neg_right = in(reg) (right as i32).wrapping_neg(),
            inout("r2") sq_lo,
            inout("r3") sq_hi,
            inout("lr") len => _,
            out("d0") _, out("d1") _,
            options(nostack),
        );
    }
    Some((((sq_hi as u64) << 32) | sq_lo as u64) as i64)
}

/// LayerNorm's output of one row and attention's normalised average: `z = vrmulh(n, recip_q)`,
/// `sat8((vmulh(z, mult) + round) >> post)`, stored as bytes. `false` unless `n` and `out` have one length `>= 1` and `post` is
/// in `1..=31`.
#[cfg(bino_mve)]
pub(crate) fn scaled_requant_lanes(n: &[i32], recip_q: i32, mult: i32, round: i32, post: u32, out: &mut [i8]) -> bool {
    let len = n.len();
    if len == 0 || out.len() != len || !(1..=31).contains(&post) {
        return false;
    }
    // SAFETY: the tail-predicated loop reads `len` words of `n` and writes `len` bytes of `out`
    // (both checked). The narrowing `vstrb.32` needs a low register (r1). It writes only its
    // declared outputs: the pointers, `lr` and q0-q4.
    unsafe {
        core::arch::asm!(
            "vdup.32 q1, {recip}",
            "vdup.32 q2, {mult}",
            "vmov.i32 q3, #0x7f",
            "vmvn.i32 q4, #0x7f",
            "dlstp.32 lr, lr",
            "2:",
            "vldrw.u32 q0, [{n}], #16",
            "vrmulh.s32 q0, q0, q1",
            "vmulh.s32 q0, q0, q2",
            "vadd.i32 q0, q0, {round}",
            "vshl.s32 q0, {neg_post}",
            "vmin.s32 q0, q0, q3",
            "vmax.s32 q0, q0, q4",
            "vstrb.32 q0, [r1], #4",
            "letp lr, 2b",
            recip = in(reg) recip_q,
            mult = in(reg) mult,
            round = in(reg) round,
            neg_post = in(reg) (post as i32).wrapping_neg(),
            n = inout(reg) n.as_ptr() => _,
            inout("r1") out.as_mut_ptr() => _,
            inout("lr") len => _,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _, out("d4") _,
            out("d5") _, out("d6") _, out("d7") _, out("d8") _, out("d9") _,
            options(nostack),
        );
    }
    true
}

/// The rotary embedding's requantisation lanes (the first pass of `rope::RopeLanes::token`):
/// `v = clamp((vmulh((acc + bias) << pre, mult) + round) >> post, -limit, limit)`, four
/// channels a step (15 instructions and the loop end). `false` (nothing written) unless every
/// slice has the length `n >= 1` of `v`. The caller's ranges (`|acc|, |bias| < 2^29`, `pre` 0
/// or 1, `post` in `1..=30`) keep every lane in 32 bits, as in its portable loop.
#[cfg(bino_mve)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn rope_requant(
    acc: &[i32],
    bias: &[i32],
    mult: &[i32],
    round: &[i32],
    pre: &[u8],
    post: &[u8],
    limit: i32,
    v: &mut [i32],
) -> bool {
    let n = v.len();
    if n == 0
        || [acc.len(), bias.len(), mult.len(), round.len(), pre.len(), post.len()]
            .iter()
            .any(|&l| l != n)
    {
        return false;
    }
    // SAFETY: the tail-predicated loop reads `n` words of `acc`, `bias`, `mult` and `round`,
    // `n` bytes of `pre` and `post`, and writes `n` words of `v` (all checked above;
    // predicated-off lanes of the last step are not accessed). The widening `vldrb.u32` needs
    // low registers (r2, r3). It writes only its declared outputs: the pointers, `lr` and
    // q0-q3.
    unsafe {
        core::arch::asm!(
            "vdup.32 q2, {limit}",
            "vneg.s32 q3, q2",
            "dlstp.32 lr, lr",
            "2:",
            "vldrw.u32 q0, [{acc}], #16",
            "vldrw.u32 q1, [{bias}], #16",
            "vadd.i32 q0, q0, q1",
            "vldrb.u32 q1, [r2], #4",
            "vshl.s32 q0, q0, q1",
            "vldrw.u32 q1, [{mult}], #16",
            "vmulh.s32 q0, q0, q1",
            "vldrw.u32 q1, [{round}], #16",
            "vadd.i32 q0, q0, q1",
            "vldrb.u32 q1, [r3], #4",
            "vneg.s32 q1, q1",
            "vshl.s32 q0, q0, q1",
            "vmin.s32 q0, q0, q2",
            "vmax.s32 q0, q0, q3",
            "vstrw.32 q0, [{v}], #16",
            "letp lr, 2b",
            limit = in(reg) limit,
            acc = inout(reg) acc.as_ptr() => _,
            bias = inout(reg) bias.as_ptr() => _,
            mult = inout(reg) mult.as_ptr() => _,
            round = inout(reg) round.as_ptr() => _,
            v = inout(reg) v.as_mut_ptr() => _,
            inout("r2") pre.as_ptr() => _,
            inout("r3") post.as_ptr() => _,
            inout("lr") n => _,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _,
            out("d4") _, out("d5") _, out("d6") _, out("d7") _,
            options(nostack),
        );
    }
    true
}

/// The head's hidden-convolution epilogue with its carry (`model::head::ConvEpilogue`), cell by
/// cell of `HEAD_HIDDEN` channels, four a step: `relu = max((vmulh(acc + bias, mult) + round)
/// >> post, 0)`, `carried = (vmulh((x - zero) << pre, cmult) + cround) >> cpost`, then
/// `sat8(carried + relu + next_zero)` by two saturating narrowings (22 instructions per four
/// channels). `lanes`: bias, multiplier, rounding term and negated right shift, `HEAD_HIDDEN`
/// words each; `carry`: `(cmult, pre, cround, -cpost)`. `false` (nothing written) unless `acc`
/// and `out` have one length, a multiple of `HEAD_HIDDEN` from one cell, and `x` at least that.
/// The caller's ranges (see `ConvEpilogue`) keep every lane in 32 bits.
#[cfg(bino_mve)]
pub(crate) fn conv_epilogue(
    acc: &[i32],
    x: &[i8],
    lanes: &[i32; 4 * crate::config::HEAD_HIDDEN],
    carry: (i32, i32, i32, i32),
    zero: i32,
    next_zero: i32,
    out: &mut [i8],
) -> bool {
    const H: usize = crate::config::HEAD_HIDDEN;
    // The kernel's immediate offsets and step count assume 24 channels.
    const _: () = assert!(H == 24);
    let n = acc.len();
    if n == 0 || !n.is_multiple_of(H) || out.len() != n || x.len() < n {
        return false;
    }
    let (cmult, pre, cround, neg_cpost) = carry;
    // SAFETY: per cell (`n / 24` of them) the loop reads 24 words of `acc`, 24 bytes of `x`
    // and the 96 words of `lanes` (offsets 0-380 from its start, reset per cell), and writes
    // 24 bytes of `out`: in all exactly `n` words, `n` bytes of `x` (checked above: `x` holds
    // at least `n`) and `n` bytes of `out`. The widening `vldrb.s32` and narrowing
    // `vstrb.32` need low registers (r2, r3). It writes only its declared outputs: the
    // pointers, the counters, `lr` and q0-q6.
    unsafe {
        core::arch::asm!(
            "vdup.32 q3, {cmult}",
            "vdup.32 q4, {cround}",
            "vdup.32 q5, {next_zero}",
            "vmov.i32 q6, #0",
            "3:",
            "mov {p}, {base}",
            "mov lr, #6",
            "dls lr, lr",
            "4:",
            "vldrw.u32 q0, [{acc}], #16",
            "vldrw.u32 q1, [{p}]",
            "vadd.i32 q0, q0, q1",
            "vldrw.u32 q1, [{p}, #96]",
            "vmulh.s32 q0, q0, q1",
            "vldrw.u32 q1, [{p}, #192]",
            "vadd.i32 q0, q0, q1",
            "vldrw.u32 q1, [{p}, #288]",
            "vshl.s32 q0, q0, q1",
            "vmax.s32 q0, q0, q6",
            "vldrb.s32 q2, [r2], #4",
            "vsub.i32 q2, q2, {zero}",
            "vshl.s32 q2, {pre}",
            "vmulh.s32 q2, q2, q3",
            "vadd.i32 q2, q2, q4",
            "vshl.s32 q2, {neg_cpost}",
            "vadd.i32 q0, q0, q2",
            "vadd.i32 q0, q0, q5",
            "vqmovnb.s32 q0, q0",
            "vqmovnb.s16 q0, q0",
            "vstrb.32 q0, [r3], #4",
            "adds {p}, #16",
            "le lr, 4b",
            "subs {cells}, #1",
            "bne 3b",
            cmult = in(reg) cmult,
            cround = in(reg) cround,
            next_zero = in(reg) next_zero,
            zero = in(reg) zero,
            pre = in(reg) pre,
            neg_cpost = in(reg) neg_cpost,
            base = in(reg) lanes.as_ptr(),
            p = out(reg) _,
            cells = inout(reg) n / H => _,
            acc = inout(reg) acc.as_ptr() => _,
            inout("r2") x.as_ptr() => _,
            inout("r3") out.as_mut_ptr() => _,
            out("lr") _,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _, out("d4") _, out("d5") _,
            out("d6") _, out("d7") _, out("d8") _, out("d9") _, out("d10") _, out("d11") _,
            out("d12") _, out("d13") _,
            options(nostack),
        );
    }
    true
}

/// One row of a residual-add chunk, four channels a step: the carry `((x - zero) << e) * mult`
/// and the delta `(acc + bias) * mult` each as `vmulh.s32`, a rounding add and a per-lane
/// shift, then the new zero point and the int8 clamp (27 instructions per four channels).
/// `false` unless `x` and `acc` have one length `n >= 1` and `params` holds ten vectors per
/// group of four channels.
#[cfg(bino_mve)]
pub(crate) fn residual_add_row(x: &mut [i8], acc: &[i32], params: &[i32]) -> bool {
    let n = x.len();
    if n == 0 || acc.len() != n || params.len() < n.div_ceil(4) * 4 * 10 {
        return false;
    }
    // SAFETY: the tail-predicated loop reads and writes `n` bytes of `x`, reads `n` words of
    // `acc` and, per step of four channels, ten vectors of `params` (all checked above:
    // `params` holds the last group's ten vectors whole; predicated-off lanes of the last step
    // are not accessed). The narrowing `vldrb.s32`/`vstrb.32` need a low
    // register (r0). It writes only its declared outputs: the pointers, `lr` and q0-q4.
    unsafe {
        core::arch::asm!(
            "vmov.i32 q3, #0x7f",
            "vmvn.i32 q4, #0x7f",
            "dlstp.32 lr, lr",
            "2:",
            "vldrb.s32 q0, [r0]",
            "vldrw.u32 q1, [{p}], #16",
            "vsub.i32 q0, q0, q1",
            "vldrw.u32 q1, [{p}], #16",
            "vshl.s32 q0, q0, q1",
            "vldrw.u32 q1, [{p}], #16",
            "vmulh.s32 q0, q0, q1",
            "vldrw.u32 q1, [{p}], #16",
            "vadd.i32 q0, q0, q1",
            "vldrw.u32 q1, [{p}], #16",
            "vshl.s32 q0, q0, q1",
            "vldrw.u32 q2, [{acc}], #16",
            "vldrw.u32 q1, [{p}], #16",
            "vadd.i32 q2, q2, q1",
            "vldrw.u32 q1, [{p}], #16",
            "vmulh.s32 q2, q2, q1",
            "vldrw.u32 q1, [{p}], #16",
            "vadd.i32 q2, q2, q1",
            "vldrw.u32 q1, [{p}], #16",
            "vshl.s32 q2, q2, q1",
            "vadd.i32 q0, q0, q2",
            "vldrw.u32 q1, [{p}], #16",
            "vadd.i32 q0, q0, q1",
            "vmin.s32 q0, q0, q3",
            "vmax.s32 q0, q0, q4",
            "vstrb.32 q0, [r0], #4",
            "letp lr, 2b",
            inout("r0") x.as_mut_ptr() => _,
            acc = inout(reg) acc.as_ptr() => _,
            p = inout(reg) params.as_ptr() => _,
            inout("lr") n => _,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _, out("d4") _,
            out("d5") _, out("d6") _, out("d7") _, out("d8") _, out("d9") _,
            options(nostack),
        );
    }
    true
}

/// Portable twins of the tiles (host tests of the drivers).
#[cfg(not(bino_mve))]
fn tile3(a0: &[i8], a1: &[i8], w: [&[i8]; 3], init: [i32; 3]) -> [[i32; 3]; 2] {
    let dot = crate::kernels::matmul::dot;
    [
        core::array::from_fn(|c| init[c].wrapping_add(dot(a0, w[c]))),
        core::array::from_fn(|c| init[c].wrapping_add(dot(a1, w[c]))),
    ]
}

#[cfg(not(bino_mve))]
fn tile2(a0: &[i8], a1: &[i8], w: [&[i8]; 2], init: [i32; 2]) -> [[i32; 2]; 2] {
    let dot = crate::kernels::matmul::dot;
    [
        core::array::from_fn(|c| init[c].wrapping_add(dot(a0, w[c]))),
        core::array::from_fn(|c| init[c].wrapping_add(dot(a1, w[c]))),
    ]
}

#[cfg(not(bino_mve))]
fn tile1(a0: &[i8], a1: &[i8], w: &[i8], init: i32) -> [i32; 2] {
    let dot = crate::kernels::matmul::dot;
    [init.wrapping_add(dot(a0, w)), init.wrapping_add(dot(a1, w))]
}
