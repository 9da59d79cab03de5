//! LayerNorm's lane passes on Cortex-M55: the values with their sum and extremes
//! ([`layernorm_values`]), the normalisation with its sum of squares ([`layernorm_normalise`]),
//! and the output requantisation, which attention's normalised average shares
//! ([`scaled_requant_lanes`]).

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
