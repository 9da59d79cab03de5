//! The Cortex-M55's small tiles for the columns past the last triple (a pair of rows against
//! two weight rows or one), and the portable twins of all three tiles (host tests of the
//! drivers).

/// `init[c] + a_r . w_c` for rows `a0`, `a1` and two weight rows: per 64 MACs four `vldrb`,
/// four `vmladava` and the loop end (two `tile1`s take six loads for the same work).
#[cfg(bino_mve)]
#[inline(always)]
pub(super) fn tile2(a0: &[i8], a1: &[i8], w: [&[i8]; 2], init: [i32; 2]) -> [[i32; 2]; 2] {
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
pub(super) fn tile1(a0: &[i8], a1: &[i8], w: &[i8], init: i32) -> [i32; 2] {
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

/// Portable twins of the tiles (host tests of the drivers).
#[cfg(not(bino_mve))]
pub(super) fn tile3(a0: &[i8], a1: &[i8], w: [&[i8]; 3], init: [i32; 3]) -> [[i32; 3]; 2] {
    let dot = crate::kernels::reference::matmul::dot;
    [
        core::array::from_fn(|c| init[c].wrapping_add(dot(a0, w[c]))),
        core::array::from_fn(|c| init[c].wrapping_add(dot(a1, w[c]))),
    ]
}

#[cfg(not(bino_mve))]
pub(super) fn tile2(a0: &[i8], a1: &[i8], w: [&[i8]; 2], init: [i32; 2]) -> [[i32; 2]; 2] {
    let dot = crate::kernels::reference::matmul::dot;
    [
        core::array::from_fn(|c| init[c].wrapping_add(dot(a0, w[c]))),
        core::array::from_fn(|c| init[c].wrapping_add(dot(a1, w[c]))),
    ]
}

#[cfg(not(bino_mve))]
pub(super) fn tile1(a0: &[i8], a1: &[i8], w: &[i8], init: i32) -> [i32; 2] {
    let dot = crate::kernels::reference::matmul::dot;
    [init.wrapping_add(dot(a0, w)), init.wrapping_add(dot(a1, w))]
}
