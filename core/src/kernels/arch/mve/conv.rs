//! The head's hidden-convolution epilogue on Cortex-M55 (`model::head::ConvEpilogue`):
//! requantisation, ReLU, the carried input code and the int8 store, four channels a step.

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
