//! Attention's softmax row on Cortex-M55 (the exp table gathered in vector lanes) and the
//! largest score of a row.

use crate::kernels::types::exp::{ExpQ32, EXP2_NEG_I8_TABLE, EXP2_TABLE_LAST, EXP_Q32_MAX_GAP};

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
