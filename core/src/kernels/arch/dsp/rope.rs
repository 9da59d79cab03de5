//! The rotary embedding on Cortex-M7: a token's requantisation ([`rope_requant`]) and the
//! rotation of half a head ([`rope_rotate_half`]).

use crate::config::DIM;

/// RoPE's requantisation of one token on Cortex-M7 (`rope::RopeLanes`): per channel
/// `v = clamp((hi32(((acc + bias) << pre) mult) + round) >> post, -2^24, 2^24)` (`smmla`, then
/// `ssat #25` and one more where the value reaches `2^24`), 19 instructions a channel.
/// Returns the OR of `a ^ (a >> 31)` over the accumulators: the caller keeps `v` only where it
/// is below `2^29` (every `|acc| <= 2^29`, where the lanes' identities hold).
#[cfg(bino_dsp)]
#[inline(never)]
pub(crate) fn rope_requant(
    acc: &[i32; DIM],
    bias: &[i32; DIM],
    mult: &[i32; DIM],
    round: &[i32; DIM],
    pre: &[u8; DIM],
    post: &[u8; DIM],
    v: &mut [i32; DIM],
) -> u32 {
    let mut bits = 0u32;
    // SAFETY: the loop runs `DIM` times, reading one word of each of `acc`, `bias`, `mult`,
    // `round` (`[i32; DIM]`) and one byte of `pre` and `post` (`[u8; DIM]`) and writing one word of `v`
    // (`[i32; DIM]`) per pass. Only declared outputs are written; the flags are clobbered.
    unsafe {
        core::arch::asm!(
            "2:",
            "ldr {a}, [{ap}], #4",
            "eor {t}, {a}, {a}, asr #31",
            "orr {m}, {m}, {t}",
            "ldr {t}, [{bp}], #4",
            "add {a}, {a}, {t}",
            "ldrb {t}, [{ep}], #1",
            "lsl {a}, {a}, {t}",
            "ldr {t}, [{mp}], #4",
            "ldr {u}, [{rp}], #4",
            "smmla {a}, {a}, {t}, {u}",
            "ldrb {t}, [{qp}], #1",
            "asr {a}, {a}, {t}",
            "ssat {t}, #25, {a}",
            "cmp {a}, #0x1000000",
            "it ge",
            "addge {t}, {t}, #1",
            "str {t}, [{vp}], #4",
            "subs {cnt}, {cnt}, #1",
            "bne 2b",
            ap = inout(reg) acc.as_ptr() => _,
            bp = inout(reg) bias.as_ptr() => _,
            mp = inout(reg) mult.as_ptr() => _,
            rp = inout(reg) round.as_ptr() => _,
            ep = inout(reg) pre.as_ptr() => _,
            qp = inout(reg) post.as_ptr() => _,
            vp = inout(reg) v.as_mut_ptr() => _,
            cnt = inout(reg) DIM => _,
            m = inout(reg) bits,
            a = out(reg) _,
            t = out(reg) _,
            u = out(reg) _,
            options(nostack),
        );
    }
    bits
}

/// One half of a head rotated on Cortex-M7 (`rope`'s rotation): per pair `(a, b)` of `v`
/// (`a = v[i]`, `b = v[8 + i]`) the two 64-bit sums `a c - b s` and `b c + a s` by `smlal` from
/// `2^21`, bits 22 to 53 by `lsr` and `orr`, `ssat #8`, into `out[i]` and `out[8 + i]`.
#[cfg(bino_dsp)]
pub(crate) fn rope_rotate_half(v: &[i32; 16], angles: &crate::kernels::types::rope::Angles, out: &mut [i8; 16]) {
    // SAFETY: the loop runs 8 times; pass `i` reads words `i` and `8 + i` of `v` (`[i32; 16]`),
    // halfwords `i` of `angles.cos` and of `angles.sin` (`Angles` is `repr(C)`: `sin` 16 bytes
    // after `cos`, eight `i16` each) and writes bytes `i` and `8 + i` of `out` (`[i8; 16]`).
    // Only declared outputs are written; the flags are clobbered.
    unsafe {
        core::arch::asm!(
            "2:",
            "ldr {vb}, [{vp}, #32]",
            "ldr {va}, [{vp}], #4",
            "ldrsh {s}, [{cp}, #16]",
            "ldrsh {c}, [{cp}], #2",
            "mov {lo}, #0x200000",
            "mov {hi}, #0",
            "smlal {lo}, {hi}, {va}, {c}",
            "rsb {t}, {s}, #0",
            "smlal {lo}, {hi}, {vb}, {t}",
            "lsr {lo}, {lo}, #22",
            "orr {lo}, {lo}, {hi}, lsl #10",
            "ssat {lo}, #8, {lo}",
            "strb {lo}, [{op}]",
            "mov {lo}, #0x200000",
            "mov {hi}, #0",
            "smlal {lo}, {hi}, {vb}, {c}",
            "smlal {lo}, {hi}, {va}, {s}",
            "lsr {lo}, {lo}, #22",
            "orr {lo}, {lo}, {hi}, lsl #10",
            "ssat {lo}, #8, {lo}",
            "strb {lo}, [{op}, #8]",
            "add {op}, {op}, #1",
            "subs {cnt}, {cnt}, #1",
            "bne 2b",
            vp = inout(reg) v.as_ptr() => _,
            cp = inout(reg) angles.cos.as_ptr() => _,
            op = inout(reg) out.as_mut_ptr() => _,
            cnt = inout(reg) 8usize => _,
            va = out(reg) _,
            vb = out(reg) _,
            c = out(reg) _,
            s = out(reg) _,
            lo = out(reg) _,
            hi = out(reg) _,
            t = out(reg) _,
            options(nostack),
        );
    }
}
