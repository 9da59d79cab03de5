//! The residual add on Cortex-M55: one row of a chunk of channels, four a step.

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
