//! The fused requantisation of two rows of accumulators on Cortex-M55 (bias, multiplier,
//! addend and shift gathered from the prepared column records, in vector lanes), and its
//! portable twin for host tests of the drivers.

use crate::kernels::arch::fused::ColRecords;

/// Byte offsets of `bias`, `mult`, `addend` and `s` of four consecutive columns in an array
/// of 16-byte column records ([`ColRecords`]): the gathers of [`requant_pair`].
#[cfg(bino_mve)]
static COL_GATHER: [[u32; 4]; 4] = [[0, 16, 32, 48], [4, 20, 36, 52], [8, 24, 40, 56], [12, 28, 44, 60]];

/// Two rows of accumulators (`acc0`, `acc1`: dot products without the bias, one per column of
/// `cols`) through the fused requantisation into `out0` and `out1` (`None`: an unpaired row,
/// `acc1` then repeats `acc0`), in one tail-predicated Helium loop, four columns a step:
/// the columns' `bias`, `mult`, `addend` and `s` gathered from their records, then per row
/// `vadd`, `vmulh.s32`, `vadd`, `vshl.s32` by `-s`, two saturating narrowings and a 4-byte
/// store (23 instructions per 8 outputs). `false` (nothing written) for other lengths. Host
/// tests of the drivers run its portable twin (the same outputs) after the same checks.
pub(super) fn requant_pair<C: ColRecords + ?Sized>(
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
    #[cfg(not(bino_mve))]
    {
        let rows = [(acc0, Some(out0)), (acc1, out1)];
        for (acc, out) in rows {
            for (j, (o, &v)) in out.into_iter().flatten().zip(acc).enumerate() {
                if let Some(c) = cols.col(j) {
                    *o = c.apply(v.wrapping_add(c.bias()));
                }
            }
        }
    }
    #[cfg(bino_mve)]
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
    #[cfg(bino_mve)]
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
