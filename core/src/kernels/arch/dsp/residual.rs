//! The residual add on Cortex-M7: a chunk of channels over a block of eight rows of 128
//! ([`residual_rows8`]), and the magnitude bound of the accumulators it takes
//! ([`magnitude_bits`]).

/// The OR of `a ^ (a >> 31)` over `values` (`|a|`, or `|a| - 1` for a negative `a`) on
/// Cortex-M7, for lengths that are a multiple of 4: per four values one `ldm` and two
/// instructions each. `None` (nothing read) for other lengths.
#[cfg(bino_dsp)]
pub(crate) fn magnitude_bits(values: &[i32]) -> Option<u32> {
    let n = values.len();
    if n == 0 || !n.is_multiple_of(4) {
        return None;
    }
    let mut bits = 0u32;
    // SAFETY: the loop runs `n / 4 >= 1` times and reads the `n` words of `values` (an
    // `[i32]`, word-aligned for `ldm`); `r0`-`r3` are declared clobbered. Only declared outputs
    // are written; the flags are clobbered.
    unsafe {
        core::arch::asm!(
            "2:",
            "ldm {s}!, {{r0, r1, r2, r3}}",
            "eor r0, r0, r0, asr #31",
            "eor r1, r1, r1, asr #31",
            "eor r2, r2, r2, asr #31",
            "eor r3, r3, r3, asr #31",
            "orr {m}, {m}, r0",
            "orr {m}, {m}, r1",
            "orr {m}, {m}, r2",
            "orr {m}, {m}, r3",
            "subs {n}, {n}, #1",
            "bne 2b",
            s = inout(reg) values.as_ptr() => _,
            n = inout(reg) n / 4 => _,
            m = inout(reg) bits,
            out("r0") _,
            out("r1") _,
            out("r2") _,
            out("r3") _,
            options(nostack, readonly),
        );
    }
    Some(bits)
}

/// Rows in one call of [`residual_rows8`], and their stride in codes: a block of the encoder's
/// residual stream (`TOKEN_BLOCK` tokens of `DIM` channels), at fixed offsets in the assembly.
#[cfg(bino_dsp)]
pub(crate) const RESIDUAL_ROWS: usize = 8;
#[cfg(bino_dsp)]
pub(crate) const RESIDUAL_STRIDE: usize = 128;

/// Words per channel of [`residual_rows8`]'s parameters: the delta's bias, multiplier, rounding
/// term and shift, the new zero point; the carry's zero point, left shift, multiplier,
/// rounding term and shift.
#[cfg(bino_dsp)]
pub(crate) const RESIDUAL_WORDS: usize = 10;

/// Phase one of a residual channel for row `$r`: `delta + zero` into the stack slot `$r`.
#[cfg(bino_dsp)]
macro_rules! residual_delta {
    ($acc:literal, $slot:literal) => {
        concat!(
            "ldr {u}, [{ap}, #",
            $acc,
            "]\n",
            "add {u}, {u}, {p0}\n",
            "smmla {u}, {u}, {p1}, {p2}\n",
            "asr {u}, {u}, {p3}\n",
            "add {u}, {u}, {p4}\n",
            "str {u}, [sp, #",
            $slot,
            "]\n",
        )
    };
}

/// Phase two for row `$r`: the carried code plus the slot, saturated and stored.
#[cfg(bino_dsp)]
macro_rules! residual_carry {
    ($x:literal, $slot:literal) => {
        concat!(
            "ldrsb {t}, [{xp}, #",
            $x,
            "]\n",
            "sub {t}, {t}, {p0}\n",
            "lsl {t}, {t}, {p1}\n",
            "smmla {t}, {t}, {p2}, {p3}\n",
            "asr {t}, {t}, {p4}\n",
            "ldr {u}, [sp, #",
            $slot,
            "]\n",
            "add {t}, {t}, {u}\n",
            "ssat {t}, #8, {t}\n",
            "strb {t}, [{xp}, #",
            $x,
            "]\n",
        )
    };
}

/// The residual add of `len` channels of a block of [`RESIDUAL_ROWS`] rows of
/// [`RESIDUAL_STRIDE`] codes on Cortex-M7, bit for bit the lanes' formula
/// (`dispatch::residual::residual_lanes`): per channel its ten parameters loaded once (`params`, see
/// [`RESIDUAL_WORDS`]), then for the eight rows `delta = ((acc + bias) * mult >> 32) + round) >>
/// shift` plus the zero point into a stack slot, and `x <- ssat8(carry(x) + slot)` with
/// `carry(x) = ((((x - zero) << left) * mult >> 32) + round) >> shift`: 16 instructions per code,
/// where the lanes' portable loop took about 42. `x` and `acc` start at the chunk's first
/// channel of the block's first row. `false` (nothing written) for short slices.
#[cfg(bino_dsp)]
pub(crate) fn residual_rows8(x: &mut [i8], acc: &[i32], params: &[i32], len: usize) -> bool {
    const { assert!(RESIDUAL_ROWS == 8 && RESIDUAL_STRIDE == 128, "the offsets below") };
    let span = (RESIDUAL_ROWS - 1) * RESIDUAL_STRIDE + len;
    if len == 0 || x.len() < span || acc.len() < span || params.len() < len * RESIDUAL_WORDS {
        return false;
    }
    // SAFETY: the loop runs `len >= 1` times; pass `c` reads the ten words `10c..10c + 10` of
    // `params` (checked), and for the rows `r < 8` word `128 r + c` of `acc` and byte
    // `128 r + c` of `x` (both hold `7 * 128 + len` elements, checked), which it writes; the
    // eight delta slots live in 32 bytes below `sp`, dropped before the end. Only declared
    // outputs are written; the flags are clobbered.
    unsafe {
        core::arch::asm!(
            "sub sp, sp, #32",
            "2:",
            "ldrd {p0}, {p1}, [{p}], #8",
            "ldrd {p2}, {p3}, [{p}], #8",
            "ldr {p4}, [{p}], #4",
            residual_delta!(0, 0),
            residual_delta!(512, 4),
            residual_delta!(1024, 8),
            residual_delta!(1536, 12),
            residual_delta!(2048, 16),
            residual_delta!(2560, 20),
            residual_delta!(3072, 24),
            residual_delta!(3584, 28),
            "ldrd {p0}, {p1}, [{p}], #8",
            "ldrd {p2}, {p3}, [{p}], #8",
            "ldr {p4}, [{p}], #4",
            residual_carry!(0, 0),
            residual_carry!(128, 4),
            residual_carry!(256, 8),
            residual_carry!(384, 12),
            residual_carry!(512, 16),
            residual_carry!(640, 20),
            residual_carry!(768, 24),
            residual_carry!(896, 28),
            "add {xp}, {xp}, #1",
            "add {ap}, {ap}, #4",
            "subs {cnt}, {cnt}, #1",
            "bne 2b",
            "add sp, sp, #32",
            p = inout(reg) params.as_ptr() => _,
            ap = inout(reg) acc.as_ptr() => _,
            xp = inout(reg) x.as_mut_ptr() => _,
            cnt = inout(reg) len => _,
            p0 = out(reg) _,
            p1 = out(reg) _,
            p2 = out(reg) _,
            p3 = out(reg) _,
            p4 = out(reg) _,
            t = out(reg) _,
            u = out(reg) _,
        );
    }
    true
}
