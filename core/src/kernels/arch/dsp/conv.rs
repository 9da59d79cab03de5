//! The head's convolution epilogue on Cortex-M7 (`model::head::ConvEpilogue`): requantisation,
//! ReLU, the carried input code and the int8 store, cell by cell.

/// The head's convolution epilogue on Cortex-M7 (`model::head::ConvEpilogue`), for `cells`
/// cells of 24 channels: per code `relu = max((hi32((acc + bias) mult) + round) >> post, 0)`
/// (`usat #31` for the maximum), plus `carried[x + 128]` (the carry of the cell's input code
/// `x` with the next zero point, a 256-entry table made once per layer), `ssat #8`. `params`:
/// per channel bias, multiplier, rounding term, right shift. Returns the OR of `a ^ (a >> 31)`
/// over the accumulators: the caller keeps the codes only where it is below `2^30`. `x` may
/// be `None` (no carry: the table is then one value, and the codes read are the outputs' own,
/// each before it is written).
#[cfg(bino_dsp)]
pub(crate) fn conv_epilogue(
    acc: &[i32],
    x: Option<&[i8]>,
    params: &[[i32; 4]; 24],
    carried: &[i32; 256],
    out: &mut [i8],
) -> Option<u32> {
    let cells = acc.len() / 24;
    if cells == 0 || acc.len() != 24 * cells || out.len() != acc.len() || x.is_some_and(|x| x.len() < acc.len()) {
        return None;
    }
    let xp = x.map_or(out.as_ptr(), |x| x.as_ptr());
    let mut bits = 0u32;
    // SAFETY: the outer loop runs `cells >= 1` times, the inner one 24 times per cell: each
    // inner pass reads one word of `acc` and one byte at `xp` (`acc.len()` of each in all:
    // `x` holds at least that many, checked, or `xp` is `out`, whose byte is read before the
    // same pass writes it), one word of `carried` at an index `0..=255` (a signed byte plus
    // 128), four words of `params` (the pointer steps back 384 bytes, the whole array, after
    // each cell) and writes one byte of `out` (`acc.len()` bytes, checked). Only declared
    // outputs are written; the flags are clobbered.
    unsafe {
        core::arch::asm!(
            "3:",
            "mov {cnt}, #24",
            "2:",
            "ldr {a}, [{ap}], #4",
            "eor {t}, {a}, {a}, asr #31",
            "orr {m}, {m}, {t}",
            "ldrd {t}, {u}, [{p}], #8",
            "add {a}, {a}, {t}",
            "ldr {t}, [{p}], #4",
            "smmla {a}, {a}, {u}, {t}",
            "ldr {t}, [{p}], #4",
            "asr {a}, {a}, {t}",
            "usat {a}, #31, {a}",
            "ldrsb {t}, [{xp}], #1",
            "ldr {t}, [{tb}, {t}, lsl #2]",
            "add {a}, {a}, {t}",
            "ssat {a}, #8, {a}",
            "strb {a}, [{op}], #1",
            "subs {cnt}, {cnt}, #1",
            "bne 2b",
            "sub {p}, {p}, #384",
            "subs {cells}, {cells}, #1",
            "bne 3b",
            ap = inout(reg) acc.as_ptr() => _,
            xp = inout(reg) xp => _,
            op = inout(reg) out.as_mut_ptr() => _,
            p = inout(reg) params.as_ptr() => _,
            tb = in(reg) carried.as_ptr().wrapping_add(128),
            cells = inout(reg) cells => _,
            cnt = out(reg) _,
            m = inout(reg) bits,
            a = out(reg) _,
            t = out(reg) _,
            u = out(reg) _,
            options(nostack),
        );
    }
    Some(bits)
}
