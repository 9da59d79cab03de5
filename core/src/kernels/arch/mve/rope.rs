//! The rotary embedding on Cortex-M55: the rotation of half a head ([`rope_rotate_half`]) and
//! a token's requantisation lanes ([`rope_requant`]).

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
