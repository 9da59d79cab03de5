//! Attention's scores (Q·Kᵀ) on Cortex-M7: four queries widened once, then every key in one
//! assembly loop (eight 4-element groups unrolled at fixed offsets), and the portable twin for
//! host tests of its layout.

#[cfg(not(bino_dsp))]
use super::tile::tile;
use super::tile::{widen, words};
use super::ROWS;
use crate::config::HEAD_DIM;

/// One group of the scores kernel: as `group!`, with the widened queries at the fixed byte
/// offsets `$o0`-`$o3` of `{x}` (rows 0-3) instead of post-incremented.
#[cfg(bino_dsp)]
macro_rules! key_group {
    ($o0:literal, $o1:literal, $o2:literal, $o3:literal) => {
        concat!(
            "ldr {t0}, [{w}], #4\n",
            "ldrd {x0}, {x1}, [{x}, #",
            $o0,
            "]\n",
            "sxtb16 {t1}, {t0}\n",
            "sxtb16 {t0}, {t0}, ror #8\n",
            "smlad {a0}, {x0}, {t1}, {a0}\n",
            "smlad {a0}, {x1}, {t0}, {a0}\n",
            "ldrd {x0}, {x1}, [{x}, #",
            $o1,
            "]\n",
            "smlad {a1}, {x0}, {t1}, {a1}\n",
            "smlad {a1}, {x1}, {t0}, {a1}\n",
            "ldrd {x0}, {x1}, [{x}, #",
            $o2,
            "]\n",
            "smlad {a2}, {x0}, {t1}, {a2}\n",
            "smlad {a2}, {x1}, {t0}, {a2}\n",
            "ldrd {x0}, {x1}, [{x}, #",
            $o3,
            "]\n",
            "smlad {a3}, {x0}, {t1}, {a3}\n",
            "smlad {a3}, {x1}, {t0}, {a3}\n",
        )
    };
}

/// Attention scores of four queries against every key (`HEAD_DIM` codes each, `keys` word
/// aligned): `scores[q * n + j] = queries[q] . keys[j]`, `scores` exactly `4 n` long. The queries
/// are widened once into the tile's interleaved layout, then one assembly loop runs every key:
/// the eight 4-element groups unrolled (per group one `ldr`, two `sxtb16`, four `ldrd` at fixed
/// offsets and eight `smlad`, the first group's `smuad` starting the sums) and the four scores
/// stored at the query rows' stride. `false` (nothing written) for other lengths or alignments.
#[cfg(bino_dsp)]
pub(crate) fn attention_scores(queries: &[[i8; HEAD_DIM]; ROWS], keys: &[i8], scores: &mut [i32]) -> bool {
    const { assert!(HEAD_DIM == 32, "the unrolled loop takes eight groups of four") };
    let n = keys.len() / HEAD_DIM;
    if n == 0 || keys.len() != n * HEAD_DIM || scores.len() != ROWS * n || !(keys.as_ptr() as usize).is_multiple_of(4) {
        return false;
    }
    let mut x = [0u32; words(HEAD_DIM)];
    widen(queries.each_ref().map(|q| &q[..]), &mut x);
    // SAFETY: the loop runs `n >= 1` times; each pass reads one key's 32 bytes through `w`
    // (word loads: `keys` is word-aligned, checked, and holds exactly `n` keys), 256 bytes of
    // `x` at fixed offsets 0..=248 (`x` is 64 words, a `[u32]`, so word-aligned for `ldrd`), and
    // writes `scores[j]`, `scores[n + j]`, `scores[2n + j]`, `scores[3n + j]` for the key `j`
    // (`scores` is exactly `4 n` words: checked). The row stride in bytes, `4 n`, waits in one
    // word pushed below `sp` and popped before the end. Only declared outputs are written;
    // the flags are clobbered.
    unsafe {
        core::arch::asm!(
            "push {{{t0}}}",
            "2:",
                "ldr {t0}, [{w}], #4",
                "ldrd {x0}, {x1}, [{x}, #0]",
                "sxtb16 {t1}, {t0}",
                "sxtb16 {t0}, {t0}, ror #8",
                "smuad {a0}, {x0}, {t1}",
                "smlad {a0}, {x1}, {t0}, {a0}",
                "ldrd {x0}, {x1}, [{x}, #8]",
                "smuad {a1}, {x0}, {t1}",
                "smlad {a1}, {x1}, {t0}, {a1}",
                "ldrd {x0}, {x1}, [{x}, #16]",
                "smuad {a2}, {x0}, {t1}",
                "smlad {a2}, {x1}, {t0}, {a2}",
                "ldrd {x0}, {x1}, [{x}, #24]",
                "smuad {a3}, {x0}, {t1}",
                "smlad {a3}, {x1}, {t0}, {a3}",
                key_group!(32, 40, 48, 56),
                key_group!(64, 72, 80, 88),
                key_group!(96, 104, 112, 120),
                key_group!(128, 136, 144, 152),
                key_group!(160, 168, 176, 184),
                key_group!(192, 200, 208, 216),
                key_group!(224, 232, 240, 248),
            "ldr {t0}, [sp]",
            "str {a0}, [{s}]",
            "str {a1}, [{s}, {t0}]",
            "add {t1}, {s}, {t0}, lsl #1",
            "str {a2}, [{t1}]",
            "str {a3}, [{t1}, {t0}]",
            "add {s}, {s}, #4",
            "subs {cnt}, {cnt}, #1",
            "bne 2b",
            "add sp, sp, #4",
            w = inout(reg) keys.as_ptr() => _,
            x = in(reg) x.as_ptr(),
            s = inout(reg) scores.as_mut_ptr() => _,
            cnt = inout(reg) n => _,
            t0 = inout(reg) 4 * n => _,
            t1 = out(reg) _,
            x0 = out(reg) _,
            x1 = out(reg) _,
            a0 = out(reg) _,
            a1 = out(reg) _,
            a2 = out(reg) _,
            a3 = out(reg) _,
        );
    }
    true
}

/// The portable twin of the Cortex-M7 scores kernel (host tests of its layout): the same
/// widening, the tile per key.
#[cfg(not(bino_dsp))]
pub(crate) fn attention_scores(queries: &[[i8; HEAD_DIM]; ROWS], keys: &[i8], scores: &mut [i32]) -> bool {
    let n = keys.len() / HEAD_DIM;
    if n == 0 || keys.len() != n * HEAD_DIM || scores.len() != ROWS * n {
        return false;
    }
    let mut x = [0u32; words(HEAD_DIM)];
    widen(queries.each_ref().map(|q| &q[..]), &mut x);
    for (j, key) in keys.chunks_exact(HEAD_DIM).enumerate() {
        for (r, v) in tile(&x, key, [0; ROWS]).into_iter().enumerate() {
            if let Some(s) = scores.get_mut(r * n + j) {
                *s = v;
            }
        }
    }
    true
}
