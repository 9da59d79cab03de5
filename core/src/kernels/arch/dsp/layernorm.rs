//! LayerNorm's lane passes on Cortex-M7: the values with their sum and extremes
//! ([`layernorm_values`]), the normalisation with its sum of squares ([`layernorm_normalise`]),
//! and the output requantisation, which attention's normalised average shares
//! ([`scaled_requant`]).

/// LayerNorm's first lane pass on Cortex-M7 (`layernorm::lanes::values`): `v = (q - zero) rel`
/// per channel, their 64-bit sum (`smlal` by one), minimum and maximum; 15 instructions a
/// channel. `None` (nothing written) unless the four slices have one non-zero length.
#[cfg(bino_dsp)]
#[inline(never)]
pub(crate) fn layernorm_values(row: &[i8], zero: &[i32], rel: &[i32], v: &mut [i32]) -> Option<(i64, i32, i32)> {
    let n = row.len();
    if n == 0 || zero.len() != n || rel.len() != n || v.len() != n {
        return None;
    }
    let (mut lo, mut hi, mut min, mut max) = (0u32, 0u32, i32::MAX, i32::MIN);
    // SAFETY: the loop runs `n >= 1` times, reading one byte of `row` and one word of `zero`
    // and `rel` and writing one word of `v` per pass (all `n` long, checked). Only declared
    // outputs are written; the flags are clobbered.
    unsafe {
        core::arch::asm!(
            "2:",
            "ldrsb {q}, [{rp}], #1",
            "ldr {t}, [{zp}], #4",
            "sub {q}, {q}, {t}",
            "ldr {t}, [{lp}], #4",
            "mul {q}, {q}, {t}",
            "str {q}, [{vp}], #4",
            "smlal {lo}, {hi}, {q}, {one}",
            "cmp {q}, {min}",
            "it lt",
            "movlt {min}, {q}",
            "cmp {q}, {max}",
            "it gt",
            "movgt {max}, {q}",
            "subs {cnt}, {cnt}, #1",
            "bne 2b",
            rp = inout(reg) row.as_ptr() => _,
            zp = inout(reg) zero.as_ptr() => _,
            lp = inout(reg) rel.as_ptr() => _,
            vp = inout(reg) v.as_mut_ptr() => _,
            cnt = inout(reg) n => _,
            one = in(reg) 1u32,
            lo = inout(reg) lo,
            hi = inout(reg) hi,
            min = inout(reg) min,
            max = inout(reg) max,
            q = out(reg) _,
            t = out(reg) _,
            options(nostack),
        );
    }
    Some((((hi as u64) << 32 | lo as u64) as i64, min, max))
}

/// LayerNorm's second lane pass on Cortex-M7 (`layernorm::lanes::normalise`):
/// `n = ((v << left) + add) >> right` (wrapping, arithmetic shift) and the 64-bit sum of the
/// squares (`smlal`), two values a pass (`ldrd`, `strd`): 6 instructions a value. `None`
/// (nothing written) unless both slices have one even, non-zero length.
#[cfg(bino_dsp)]
pub(crate) fn layernorm_normalise(v: &[i32], left: u32, add: i32, right: u32, n: &mut [i32]) -> Option<i64> {
    let len = v.len();
    if len == 0 || !len.is_multiple_of(2) || n.len() != len {
        return None;
    }
    let (mut lo, mut hi) = (0u32, 0u32);
    // SAFETY: the loop runs `len / 2 >= 1` times, reading two words of `v` and writing two of
    // `n` per pass (`[i32]`s of `len` words, word-aligned for `ldrd`/`strd`). Only declared
    // outputs are written; the flags are clobbered.
    unsafe {
        core::arch::asm!(
            "2:",
            "ldrd {a}, {b}, [{vp}], #8",
            "lsl {a}, {a}, {left}",
            "lsl {b}, {b}, {left}",
            "add {a}, {a}, {add}",
            "add {b}, {b}, {add}",
            "asr {a}, {a}, {right}",
            "asr {b}, {b}, {right}",
            "strd {a}, {b}, [{np}], #8",
            "smlal {lo}, {hi}, {a}, {a}",
            "smlal {lo}, {hi}, {b}, {b}",
            "subs {cnt}, {cnt}, #1",
            "bne 2b",
            vp = inout(reg) v.as_ptr() => _,
            np = inout(reg) n.as_mut_ptr() => _,
            cnt = inout(reg) len / 2 => _,
            left = in(reg) left & 31,
            add = in(reg) add,
            right = in(reg) right & 31,
            lo = inout(reg) lo,
            hi = inout(reg) hi,
            a = out(reg) _,
            b = out(reg) _,
            options(nostack),
        );
    }
    Some(((hi as u64) << 32 | lo as u64) as i64)
}

/// LayerNorm's output pass and attention's normalised average on Cortex-M7
/// (`epilogue::scaled_requant_lanes`): `sat8((hi32(rnd_hi32(n recip_q) mult) + round) >> post)`
/// by `smmulr`, `smmla`, `asr` and `ssat #8`, two values a pass: 6.5 instructions a value.
/// `false` (nothing written) unless both slices have one even, non-zero length.
#[cfg(bino_dsp)]
pub(crate) fn scaled_requant(n: &[i32], recip_q: i32, mult: i32, round: i32, post: u32, out: &mut [i8]) -> bool {
    let len = n.len();
    if len == 0 || !len.is_multiple_of(2) || out.len() != len {
        return false;
    }
    // SAFETY: the loop runs `len / 2 >= 1` times, reading two words of `n` (an `[i32]`,
    // word-aligned for `ldrd`) and writing two bytes of `out` per pass (`len` of each). Only
    // declared outputs are written; the flags are clobbered.
    unsafe {
        core::arch::asm!(
            "2:",
            "ldrd {a}, {b}, [{np}], #8",
            "smmulr {a}, {a}, {recip}",
            "smmulr {b}, {b}, {recip}",
            "smmla {a}, {a}, {mult}, {round}",
            "smmla {b}, {b}, {mult}, {round}",
            "asr {a}, {a}, {post}",
            "asr {b}, {b}, {post}",
            "ssat {a}, #8, {a}",
            "ssat {b}, #8, {b}",
            "strb {a}, [{op}], #1",
            "strb {b}, [{op}], #1",
            "subs {cnt}, {cnt}, #1",
            "bne 2b",
            np = inout(reg) n.as_ptr() => _,
            op = inout(reg) out.as_mut_ptr() => _,
            cnt = inout(reg) len / 2 => _,
            recip = in(reg) recip_q,
            mult = in(reg) mult,
            round = in(reg) round,
            post = in(reg) post & 31,
            a = out(reg) _,
            b = out(reg) _,
            options(nostack),
        );
    }
    true
}
