//! Cortex-M7 (Armv7E-M DSP extension) tile: 4 rows x 1 column, two MACs per `smlad`.
//!
//! Each block of 4 activation rows is widened once into a stack scratch of signed 16-bit
//! pairs, interleaved so one `ldrd` brings a row's `(a0, a2)` and `(a1, a3)` of a 4-element
//! group; each weight word is widened in registers (`sxtb16` gives `(w0, w2)`, with `ror #8`
//! `(w1, w3)`) and shared by the 4 rows: per 16 MACs one `ldr`, two `sxtb16`, four `ldrd` and
//! eight `smlad`, the loop unrolled over eight groups where their count allows (two where it is
//! even). The scratch is reused for every output column.

#[cfg(bino_dsp)]
use super::fused::Col;
use super::{Epilogue, MAX_K};
#[cfg(bino_dsp)]
use crate::config::DIM;
use crate::config::HEAD_DIM;
#[cfg(any(bino_dsp, test))]
use crate::kernels::exp::{ExpQ32, EXP2_NEG_U8_TABLE_4K, EXP2_TABLE_LAST, EXP_Q32_MAX_GAP};

/// One 4-element group of a tile column as assembly text: a weight word from `{w}` widened by
/// two `sxtb16` into `(w0, w2)` and `(w1, w3)`, then per row one `ldrd` of its widened pair from
/// `{x}` (post-incremented) and two `smlad` into `{a0}`-`{a3}` (temporaries `{t0}`, `{t1}`,
/// `{x0}`, `{x1}`): 15 instructions for 16 MACs.
#[cfg(bino_dsp)]
macro_rules! group {
    () => {
        concat!(
            "ldr {t0}, [{w}], #4\n",
            "ldrd {x0}, {x1}, [{x}], #8\n",
            "sxtb16 {t1}, {t0}\n",
            "sxtb16 {t0}, {t0}, ror #8\n",
            "smlad {a0}, {x0}, {t1}, {a0}\n",
            "smlad {a0}, {x1}, {t0}, {a0}\n",
            "ldrd {x0}, {x1}, [{x}], #8\n",
            "smlad {a1}, {x0}, {t1}, {a1}\n",
            "smlad {a1}, {x1}, {t0}, {a1}\n",
            "ldrd {x0}, {x1}, [{x}], #8\n",
            "smlad {a2}, {x0}, {t1}, {a2}\n",
            "smlad {a2}, {x1}, {t0}, {a2}\n",
            "ldrd {x0}, {x1}, [{x}], #8\n",
            "smlad {a3}, {x0}, {t1}, {a3}\n",
            "smlad {a3}, {x1}, {t0}, {a3}\n",
        )
    };
}

/// Eight `group!`s: the unrolled loop body (122 instructions per 128 MACs with its branch).
#[cfg(bino_dsp)]
macro_rules! groups8 {
    () => {
        concat!(
            group!(),
            group!(),
            group!(),
            group!(),
            group!(),
            group!(),
            group!(),
            group!()
        )
    };
}

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

/// Activation rows per tile.
pub(super) const ROWS: usize = 4;

/// The tile driver: `m` rows of `a` against every row of `w`, each finished accumulator to
/// `epi`. Declines (`false`) `k` not a multiple of 4 or `w` not word-aligned (the kernel loads
/// whole weight words); the caller has checked `k` in `1..=MAX_K` and the lengths.
#[inline(always)]
pub(crate) fn gemm<E: Epilogue>(a: &[i8], w: &[i8], k: usize, m: usize, epi: &mut E) -> bool {
    if !k.is_multiple_of(4) || k > MAX_K || !(w.as_ptr() as usize).is_multiple_of(4) {
        return false;
    }
    // A scratch no larger than the shape needs: it is zeroed on every call (attention's
    // 32-element dot products would otherwise clear 8 KiB each time).
    match k {
        0..=32 => gemm_in::<E, { words(32) }>(a, w, k, m, epi),
        33..=128 => gemm_in::<E, { words(128) }>(a, w, k, m, epi),
        129..=512 => gemm_in::<E, { words(512) }>(a, w, k, m, epi),
        // The head's hidden convolutions (27 taps of 24 channels).
        513..=648 => gemm_in::<E, { words(648) }>(a, w, k, m, epi),
        _ => gemm_in::<E, { words(MAX_K) }>(a, w, k, m, epi),
    }
}

/// Scratch words for dot products of `k` elements: 2 per 4-element group per row.
const fn words(k: usize) -> usize {
    k / 4 * 2 * ROWS
}

/// [`gemm`] for one block of at most four rows, widened into the caller's `scratch` (at least
/// `k / 2` words per row block of four: attention's weighted sums lend it the scores' room,
/// no longer needed, so no stack scratch is zeroed for each call). Declines as [`gemm`] does,
/// and for more than four rows or a short scratch.
#[cfg_attr(not(any(bino_dsp, test)), allow(dead_code))]
pub(crate) fn gemm_rows_in<E: Epilogue>(
    a: &[i8],
    w: &[i8],
    k: usize,
    m: usize,
    epi: &mut E,
    scratch: &mut [u32],
) -> bool {
    if k == 0 || !k.is_multiple_of(4) || k > MAX_K || m == 0 || m > ROWS || !(w.as_ptr() as usize).is_multiple_of(4) {
        return false;
    }
    let Some(x) = scratch.get_mut(..k / 4 * 2 * ROWS) else {
        return false;
    };
    let rows: [&[i8]; ROWS] = core::array::from_fn(|i| {
        let r = i.min(m - 1);
        a.get(r * k..(r + 1) * k).unwrap_or(&[])
    });
    widen(rows, x);
    if m == ROWS && epi.block_of_rows(0, x, w, k) {
        return true;
    }
    for (j, w_row) in w.chunks_exact(k).enumerate() {
        let acc = tile(x, w_row, [epi.init(j); ROWS]);
        epi.put_col(0, j, acc, m);
    }
    true
}

/// [`gemm`] with a `WORDS`-word scratch (`k <= 4 * WORDS / (2 * ROWS)`). Never inlined: the
/// scratch then lives on the stack only while it runs, instead of in the frame of every
/// caller (the encoder's GEMMs and attention would each add one to the stack peak).
#[inline(never)]
fn gemm_in<E: Epilogue, const WORDS: usize>(a: &[i8], w: &[i8], k: usize, m: usize, epi: &mut E) -> bool {
    let groups = k / 4;
    let mut x = [0u32; WORDS];
    let Some(scratch) = x.get_mut(..groups * 2 * ROWS) else {
        return false;
    };
    for r0 in (0..m).step_by(ROWS) {
        // Rows past the end repeat the last one; their results are not stored.
        let rows: [&[i8]; ROWS] = core::array::from_fn(|i| {
            let r = (r0 + i).min(m - 1);
            a.get(r * k..(r + 1) * k).unwrap_or(&[])
        });
        widen(rows, scratch);
        if m - r0 >= ROWS && epi.block_of_rows(r0, scratch, w, k) {
            continue;
        }
        for (j, w_row) in w.chunks_exact(k).enumerate() {
            let acc = tile(scratch, w_row, [epi.init(j); ROWS]);
            epi.put_col(r0, j, acc, m - r0);
        }
    }
    true
}

/// Four widened rows (`x`, from [`widen`]) against every row of `w` (`k` codes each, `k` a
/// multiple of 8, `w` word-aligned) in one assembly call, the sums stored as `i32` into `out`
/// (four rows of `n = w.len() / k` values at a stride of `n`): per column the accumulators
/// zeroed, the eight-group loop of [`tile`] then a two-group loop for the rest of `k` (the
/// head's convolutions: `k` = 27 x 16 or 27 x 24), and four row-strided stores, without returning to
/// Rust (the per-column driver spent about 100 instructions a column around the loop). `false`
/// (nothing written) for other lengths or alignments.
#[cfg(bino_dsp)]
pub(super) fn rows_i32(x: &[u32], w: &[i8], k: usize, out: &mut [i32]) -> bool {
    let n = w.len() / k.max(1);
    if k == 0 || !k.is_multiple_of(8) || w.len() != n * k || n == 0 || out.len() != ROWS * n {
        return false;
    }
    if x.len() < k / 4 * 2 * ROWS || !(w.as_ptr() as usize).is_multiple_of(4) {
        return false;
    }
    // SAFETY: per column `j` (`n` of them) the loop reads the `k` bytes of weight row `j` (word
    // loads: `w` is word-aligned and exactly `n * k` bytes, checked) and the first `2 k` words
    // of `x` (checked), and writes `out[j]`, `out[n + j]`, `out[2n + j]`, `out[3n + j]` (`out`
    // is exactly `4 n` words, checked); the eight-group loop runs `k / 32` times and the
    // two-group loop `k % 32 / 8` times, `k` bytes of `w` and `2 k` words of `x` together. The
    // row stride, both loop counts, the output pointer and the column count live in 24 bytes
    // below `sp`, dropped before the end. Only declared outputs are written; the flags are
    // clobbered.
    unsafe {
        core::arch::asm!(
            "sub sp, sp, #24",
            "strd {t0}, {t1}, [sp]",
            "strd {x0}, {x1}, [sp, #8]",
            "str {g}, [sp, #16]",
            "3:",
            "movs {a0}, #0",
            "movs {a1}, #0",
            "movs {a2}, #0",
            "movs {a3}, #0",
            "mov {x}, {xb}",
            "ldr {g}, [sp, #4]",
            "cmp {g}, #0",
            "beq 4f",
            "2:",
            groups8!(),
            "subs {g}, {g}, #1",
            "bne 2b",
            "4:",
            "ldr {g}, [sp, #16]",
            "cmp {g}, #0",
            "beq 5f",
            "6:",
            group!(),
            group!(),
            "subs {g}, {g}, #1",
            "bne 6b",
            "5:",
            "ldr {t0}, [sp, #0]",
            "ldr {t1}, [sp, #8]",
            "str {a0}, [{t1}]",
            "str {a1}, [{t1}, {t0}]",
            "add {x0}, {t1}, {t0}, lsl #1",
            "str {a2}, [{x0}]",
            "str {a3}, [{x0}, {t0}]",
            "add {t1}, {t1}, #4",
            "str {t1}, [sp, #8]",
            "ldr {x1}, [sp, #12]",
            "subs {x1}, {x1}, #1",
            "str {x1}, [sp, #12]",
            "bne 3b",
            "add sp, sp, #24",
            w = inout(reg) w.as_ptr() => _,
            xb = in(reg) x.as_ptr(),
            x = out(reg) _,
            g = inout(reg) k % 32 / 8 => _,
            t0 = inout(reg) 4 * n => _,
            t1 = inout(reg) k / 32 => _,
            x0 = inout(reg) out.as_mut_ptr() => _,
            x1 = inout(reg) n => _,
            a0 = out(reg) _,
            a1 = out(reg) _,
            a2 = out(reg) _,
            a3 = out(reg) _,
        );
    }
    true
}

/// [`rows_i32`] with the fused epilogue: each column's accumulators start from its `Col`'s bias,
/// and each sum leaves as `ssat8((smmul(acc, mult) + addend) >> s)` (`Col::apply`), stored as a
/// byte into four rows of `out` at a stride of `stride` bytes (`out` starts at the first row's
/// first column; `params` holds one `Col` per row of `w`). `false` (nothing written) for other
/// lengths or alignments.
#[cfg(bino_dsp)]
pub(super) fn rows_requant(x: &[u32], w: &[i8], k: usize, params: &[Col], out: &mut [i8], stride: usize) -> bool {
    let n = params.len();
    if k == 0 || !k.is_multiple_of(8) || n == 0 || w.len() != n * k || stride < n {
        return false;
    }
    if out.len() < (ROWS - 1) * stride + n || x.len() < k / 4 * 2 * ROWS || !(w.as_ptr() as usize).is_multiple_of(4) {
        return false;
    }
    // SAFETY: per column `j` (`n` of them) the loop reads the `k` bytes of weight row `j` (word
    // loads: `w` is word-aligned and exactly `n * k` bytes, checked), the first `2 k` words of
    // `x` (checked) and the four words of `params[j]` (`repr(C)` `Col`: bias, mult, addend,
    // s), and writes bytes `j`, `stride + j`, `2 stride + j`, `3 stride + j` of `out` (checked:
    // `out` holds `3 stride + n` bytes); the two loops read `k` bytes of `w` and `2 k` words of
    // `x` together, as in `rows_i32`. The row stride, both loop counts, the parameter and
    // output pointers and the column count live in 24 bytes below `sp`, dropped before the
    // end. Only declared outputs are written; the flags are clobbered.
    unsafe {
        core::arch::asm!(
            "sub sp, sp, #24",
            "strd {t0}, {t1}, [sp]",
            "strd {x0}, {x1}, [sp, #8]",
            "strd {g}, {a0}, [sp, #16]",
            "3:",
            "ldr {t0}, [sp, #8]",
            "ldr {a0}, [{t0}]",
            "mov {a1}, {a0}",
            "mov {a2}, {a0}",
            "mov {a3}, {a0}",
            "mov {x}, {xb}",
            "ldr {g}, [sp, #4]",
            "cmp {g}, #0",
            "beq 4f",
            "2:",
            groups8!(),
            "subs {g}, {g}, #1",
            "bne 2b",
            "4:",
            "ldr {g}, [sp, #20]",
            "cmp {g}, #0",
            "beq 5f",
            "6:",
            group!(),
            group!(),
            "subs {g}, {g}, #1",
            "bne 6b",
            "5:",
            "ldr {t0}, [sp, #8]",
            "ldr {x0}, [{t0}, #4]",
            "ldr {x1}, [{t0}, #8]",
            "ldr {g}, [{t0}, #12]",
            "add {t0}, {t0}, #16",
            "str {t0}, [sp, #8]",
            "ldr {t0}, [sp, #16]",
            "ldr {t1}, [sp, #0]",
            "smmul {x}, {a0}, {x0}",
            "add {x}, {x}, {x1}",
            "asr {x}, {x}, {g}",
            "ssat {x}, #8, {x}",
            "strb {x}, [{t0}]",
            "smmul {x}, {a1}, {x0}",
            "add {x}, {x}, {x1}",
            "asr {x}, {x}, {g}",
            "ssat {x}, #8, {x}",
            "strb {x}, [{t0}, {t1}]",
            "add {a1}, {t0}, {t1}, lsl #1",
            "smmul {x}, {a2}, {x0}",
            "add {x}, {x}, {x1}",
            "asr {x}, {x}, {g}",
            "ssat {x}, #8, {x}",
            "strb {x}, [{a1}]",
            "smmul {x}, {a3}, {x0}",
            "add {x}, {x}, {x1}",
            "asr {x}, {x}, {g}",
            "ssat {x}, #8, {x}",
            "strb {x}, [{a1}, {t1}]",
            "add {t0}, {t0}, #1",
            "str {t0}, [sp, #16]",
            "ldr {x1}, [sp, #12]",
            "subs {x1}, {x1}, #1",
            "str {x1}, [sp, #12]",
            "bne 3b",
            "add sp, sp, #24",
            w = inout(reg) w.as_ptr() => _,
            xb = in(reg) x.as_ptr(),
            x = out(reg) _,
            g = inout(reg) out.as_mut_ptr() => _,
            t0 = inout(reg) stride => _,
            t1 = inout(reg) k / 32 => _,
            x0 = inout(reg) params.as_ptr() => _,
            x1 = inout(reg) n => _,
            a0 = inout(reg) k % 32 / 8 => _,
            a1 = out(reg) _,
            a2 = out(reg) _,
            a3 = out(reg) _,
        );
    }
    true
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

/// A softmax row on Cortex-M7, bit for bit
/// [`attention::softmax_row`](crate::kernels::attention::softmax_row): per score one `ldr`, the
/// gap, one `umull` by the multiplier with the gap's pre-shift folded in, the rounding add and
/// shift, `usat #12` into [`EXP2_NEG_U8_TABLE_4K`], the weight summed and stored as `w - 128`.
/// `None` (nothing written) unless `weights` is
/// as long as `scores` and the row's parameters allow the loop's shortcuts:
///
/// - the multiplier shifted by `pre` stays below `2^31`, so the product's high word plus the
///   rounding term cannot wrap and is the specification's `hi((gap << pre) mult) + round`;
/// - the gap [`EXP_Q32_MAX_GAP`] already maps to the table's last entry (weight 0): the index
///   grows with the gap, so gaps beyond it, which the specification clamps there, and scores
///   above `max` (wrapped gaps) give weight 0 as well, and no clamp of the gap is needed.
#[cfg(any(bino_dsp, test))]
pub(crate) fn softmax_row(e: &ExpQ32, max: i32, scores: &[i32], weights: &mut [u8]) -> Option<u32> {
    let n = scores.len();
    let (pre, round, post) = e.shifts();
    let mult = (e.mult() as u64) << pre;
    if n == 0 || weights.len() != n || mult >= 1 << 31 {
        return None;
    }
    let mult = mult as u32;
    let index = |gap: u32| ((((gap as u64 * mult as u64) >> 32) as u32) + round) >> post;
    if index(EXP_Q32_MAX_GAP) < EXP2_TABLE_LAST {
        return None;
    }
    Some(signed_weights(max, mult, round, post, scores, weights))
}

/// Four scores loaded by `ldm` into `r0`-`r3` and compared with `{m}` in turn.
#[cfg(bino_dsp)]
macro_rules! max_of_four {
    () => {
        concat!(
            "ldm {s}!, {{r0, r1, r2, r3}}\n",
            "cmp r0, {m}\n",
            "it gt\n",
            "movgt {m}, r0\n",
            "cmp r1, {m}\n",
            "it gt\n",
            "movgt {m}, r1\n",
            "cmp r2, {m}\n",
            "it gt\n",
            "movgt {m}, r2\n",
            "cmp r3, {m}\n",
            "it gt\n",
            "movgt {m}, r3\n",
        )
    };
}

/// The largest of `scores` on Cortex-M7 (lengths that are a multiple of 4): per eight scores two
/// `ldm` and eight compare-and-moves, then four more where the length is not a multiple of 8.
/// `None` (nothing read) for other lengths.
#[cfg(bino_dsp)]
pub(crate) fn row_max(scores: &[i32]) -> Option<i32> {
    let n = scores.len();
    if n == 0 || !n.is_multiple_of(4) {
        return None;
    }
    let mut max = i32::MIN;
    // SAFETY: the eight-score loop runs `n / 8` times (none when `n` is 4) and the four-score
    // step once more when `n % 8 == 4`: `n` words of `scores` (an `[i32]`, word-aligned for
    // `ldm`) in all. `r0`-`r3` are declared clobbered. Only declared outputs are written; the
    // flags are clobbered.
    unsafe {
        core::arch::asm!(
            "cmp {n}, #0",
            "beq 3f",
            "2:",
            max_of_four!(),
            max_of_four!(),
            "subs {n}, {n}, #1",
            "bne 2b",
            "3:",
            "cmp {odd}, #0",
            "beq 4f",
            max_of_four!(),
            "4:",
            s = inout(reg) scores.as_ptr() => _,
            n = inout(reg) n / 8 => _,
            odd = in(reg) n % 8,
            m = inout(reg) max,
            out("r0") _,
            out("r1") _,
            out("r2") _,
            out("r3") _,
            options(nostack, readonly),
        );
    }
    Some(max)
}

/// The loop of [`softmax_row`]: stores `w - 128` per score and returns the sum of the `w`.
#[cfg(bino_dsp)]
#[inline(always)]
fn signed_weights(max: i32, mult: u32, round: u32, post: u32, scores: &[i32], weights: &mut [u8]) -> u32 {
    let mut sum = 0u32;
    let n = scores.len().min(weights.len());
    // SAFETY: the loop runs `n / 2` times over two scores, then once more if `n` is odd: it
    // reads the first `n` words of `scores` (an `[i32]`, word-aligned) and writes the first `n`
    // bytes of `weights` (`n` is the shorter length); its table index is `usat`urated to
    // `0..=4095`, inside the 4,096-byte `EXP2_NEG_U8_TABLE_4K`. Only declared outputs are
    // written; the flags are clobbered.
    unsafe {
        core::arch::asm!(
            "cmp {n}, #0",
            "beq 3f",
            "2:",
            "ldr {t}, [{s}], #4",
            "sub {t}, {max}, {t}",
            "umull {lo}, {t}, {t}, {mult}",
            "add {t}, {t}, {round}",
            "lsr {t}, {t}, {post}",
            "usat {t}, #12, {t}",
            "ldrb {t}, [{table}, {t}]",
            "add {sum}, {sum}, {t}",
            "eor {t}, {t}, #128",
            "strb {t}, [{w}], #1",
            "ldr {t}, [{s}], #4",
            "sub {t}, {max}, {t}",
            "umull {lo}, {t}, {t}, {mult}",
            "add {t}, {t}, {round}",
            "lsr {t}, {t}, {post}",
            "usat {t}, #12, {t}",
            "ldrb {t}, [{table}, {t}]",
            "add {sum}, {sum}, {t}",
            "eor {t}, {t}, #128",
            "strb {t}, [{w}], #1",
            "subs {n}, {n}, #1",
            "bne 2b",
            "3:",
            "cmp {odd}, #0",
            "beq 4f",
            "ldr {t}, [{s}], #4",
            "sub {t}, {max}, {t}",
            "umull {lo}, {t}, {t}, {mult}",
            "add {t}, {t}, {round}",
            "lsr {t}, {t}, {post}",
            "usat {t}, #12, {t}",
            "ldrb {t}, [{table}, {t}]",
            "add {sum}, {sum}, {t}",
            "eor {t}, {t}, #128",
            "strb {t}, [{w}], #1",
            "4:",
            s = inout(reg) scores.as_ptr() => _,
            w = inout(reg) weights.as_mut_ptr() => _,
            n = inout(reg) n / 2 => _,
            odd = in(reg) n % 2,
            sum = inout(reg) sum,
            max = in(reg) max,
            mult = in(reg) mult,
            round = in(reg) round,
            post = in(reg) post,
            table = in(reg) EXP2_NEG_U8_TABLE_4K.as_ptr(),
            t = out(reg) _,
            lo = out(reg) _,
            options(nostack),
        );
    }
    sum
}

/// The portable twin of the Cortex-M7 softmax loop (host tests of its shortcuts).
#[cfg(all(test, not(bino_dsp)))]
fn signed_weights(max: i32, mult: u32, round: u32, post: u32, scores: &[i32], weights: &mut [u8]) -> u32 {
    let mut sum = 0u32;
    for (w, &s) in weights.iter_mut().zip(scores) {
        let gap = max.wrapping_sub(s) as u32;
        let index = ((((gap as u64 * mult as u64) >> 32) as u32 + round) >> post).min(4095);
        let t = EXP2_NEG_U8_TABLE_4K[index as usize];
        *w = t ^ 0x80;
        sum = sum.wrapping_add(t as u32);
    }
    sum
}

/// The first half of a pair of softmax weights: two scores by `ldrd`, their gaps to the row's
/// maximum by `qsub` (saturating: the maximum is the row's own, so a gap is never negative and
/// one of `2^31` or more, whose weight is 0 in any case, stays large), and by `smmla` the high
/// word of the gap times the multiplier plus the rounding term.
#[cfg(bino_dsp)]
macro_rules! weight_pair_head {
    () => {
        concat!(
            "ldrd {a}, {b}, [{s}], #8\n",
            "qsub {a}, {max}, {a}\n",
            "qsub {b}, {max}, {b}\n",
            "smmla {a}, {a}, {mult}, {round}\n",
            "smmla {b}, {b}, {mult}, {round}\n",
        )
    };
}

/// The second half: the weights from the 4,096-entry table (the index `usat`urated into it
/// before), stored as halfwords at the byte offsets `$o0` and `$o1` of `{p}`, and summed.
#[cfg(bino_dsp)]
macro_rules! weight_pair_tail {
    ($o0:literal, $o1:literal) => {
        concat!(
            "ldrb {a}, [{table}, {a}]\n",
            "ldrb {b}, [{table}, {b}]\n",
            "strh {a}, [{p}, #",
            $o0,
            "]\n",
            "strh {b}, [{p}, #",
            $o1,
            "]\n",
            "add {sum}, {sum}, {a}\n",
            "add {sum}, {sum}, {b}\n",
        )
    };
}

/// The loop of [`widened_weights`] for one right shift `$post` (an immediate of `usat`) and one
/// output stride `$stride` (bytes, the immediate of `strd`'s post-increment): per group of four
/// scores two `ldrd`, per score `qsub`, `smmla`, `usat`, `ldrb` and the sum's `add`, then the
/// four weights paired into the group's two words by `pkhbt` (elements 0 and 2 in the first,
/// 1 and 3 in the second, low halfword first) and one `strd`: 27 instructions per four weights.
#[cfg(bino_dsp)]
macro_rules! widened_weights_loop {
    ($post:literal, $stride:literal, $s:expr, $p:expr, $groups:expr, $sum:expr, $max:expr, $mult:expr, $round:expr) => {
        // SAFETY: see `widened_weights`.
        unsafe {
            core::arch::asm!(
                "2:",
                "ldrd {a}, {b}, [{s}], #8",
                "ldrd {c}, {d}, [{s}], #8",
                "qsub {a}, {max}, {a}",
                "qsub {b}, {max}, {b}",
                "qsub {c}, {max}, {c}",
                "qsub {d}, {max}, {d}",
                "smmla {a}, {a}, {mult}, {round}",
                "smmla {b}, {b}, {mult}, {round}",
                "smmla {c}, {c}, {mult}, {round}",
                "smmla {d}, {d}, {mult}, {round}",
                concat!("usat {a}, #12, {a}, asr #", $post),
                concat!("usat {b}, #12, {b}, asr #", $post),
                concat!("usat {c}, #12, {c}, asr #", $post),
                concat!("usat {d}, #12, {d}, asr #", $post),
                "ldrb {a}, [{table}, {a}]",
                "ldrb {b}, [{table}, {b}]",
                "ldrb {c}, [{table}, {c}]",
                "ldrb {d}, [{table}, {d}]",
                "add {sum}, {sum}, {a}",
                "add {sum}, {sum}, {b}",
                "add {sum}, {sum}, {c}",
                "add {sum}, {sum}, {d}",
                "pkhbt {a}, {a}, {c}, lsl #16",
                "pkhbt {b}, {b}, {d}, lsl #16",
                concat!("strd {a}, {b}, [{p}], #", $stride),
                "subs {cnt}, {cnt}, #1",
                "bne 2b",
                s = inout(reg) $s => _,
                p = inout(reg) $p => _,
                cnt = inout(reg) $groups => _,
                sum = inout(reg) $sum,
                max = in(reg) $max,
                mult = in(reg) $mult,
                round = in(reg) $round,
                table = in(reg) EXP2_NEG_U8_TABLE_4K.as_ptr(),
                a = out(reg) _,
                b = out(reg) _,
                c = out(reg) _,
                d = out(reg) _,
                options(nostack),
            );
        }
    };
}

/// One softmax row into the tile's widened layout (see [`widen`]), bit for bit
/// [`attention::softmax_row`](crate::kernels::attention::softmax_row) with `row.max` the row's
/// maximum: the weight of element `4g + e` goes, unsigned, to word `first + g stride + (e & 1)`,
/// its low halfword for `e < 2` and its high one else.
/// Returns the sum of the weights. The caller has checked the row's parameters
/// ([`softmax_weighted_sums`]); `scores.len()` a multiple of 4, `out` long enough, else nothing
/// is written and the sum is 0.
#[cfg(bino_dsp)]
fn widened_weights(row: &WeightRow, scores: &[i32], out: &mut [u32], first: usize, stride: usize) -> u32 {
    let groups = scores.len() / 4;
    if groups == 0 || !scores.len().is_multiple_of(4) || stride < 2 || out.len() < first + (groups - 1) * stride + 2 {
        return 0;
    }
    let (s, p) = (scores.as_ptr(), out.as_mut_ptr().wrapping_add(first));
    let (max, mult, round, post) = (row.max, row.mult, row.round, row.post);
    let mut sum = 0u32;
    let stride = 4 * stride;
    // SAFETY (every arm): the loop runs `groups >= 1` times; each pass reads four words of
    // `scores` (an `[i32]`, word-aligned for `ldrd`; `4 groups` words, checked) and writes the
    // four halfwords of words `first + g stride` and `first + g stride + 1` of `out` (the last
    // group's are `first + (groups - 1) stride + 1 < out.len()`, checked); its table index is
    // `usat`urated to `0..=4095`, inside the 4,096-byte `EXP2_NEG_U8_TABLE_4K`. Only declared
    // outputs are written; the flags are clobbered.
    match (post, stride) {
        (1, 32) => widened_weights_loop!(1, 32, s, p, groups, sum, max, mult, round),
        (2, 32) => widened_weights_loop!(2, 32, s, p, groups, sum, max, mult, round),
        (3, 32) => widened_weights_loop!(3, 32, s, p, groups, sum, max, mult, round),
        (4, 32) => widened_weights_loop!(4, 32, s, p, groups, sum, max, mult, round),
        (1, 16) => widened_weights_loop!(1, 16, s, p, groups, sum, max, mult, round),
        (2, 16) => widened_weights_loop!(2, 16, s, p, groups, sum, max, mult, round),
        (3, 16) => widened_weights_loop!(3, 16, s, p, groups, sum, max, mult, round),
        (4, 16) => widened_weights_loop!(4, 16, s, p, groups, sum, max, mult, round),
        // SAFETY: as above.
        _ => unsafe {
            core::arch::asm!(
                "2:",
                weight_pair_head!(),
                "asr {a}, {a}, {post}",
                "asr {b}, {b}, {post}",
                "usat {a}, #12, {a}",
                "usat {b}, #12, {b}",
                weight_pair_tail!(0, 4),
                weight_pair_head!(),
                "asr {a}, {a}, {post}",
                "asr {b}, {b}, {post}",
                "usat {a}, #12, {a}",
                "usat {b}, #12, {b}",
                weight_pair_tail!(2, 6),
                "add {p}, {p}, {stride}",
                "subs {cnt}, {cnt}, #1",
                "bne 2b",
                s = inout(reg) s => _,
                p = inout(reg) p => _,
                cnt = inout(reg) groups => _,
                sum = inout(reg) sum,
                max = in(reg) max,
                mult = in(reg) mult,
                round = in(reg) round,
                stride = in(reg) stride,
                post = in(reg) post,
                table = in(reg) EXP2_NEG_U8_TABLE_4K.as_ptr(),
                a = out(reg) _,
                b = out(reg) _,
                options(nostack),
            );
        },
    }
    sum
}

/// The portable twin of [`widened_weights`] (host tests of its arithmetic and layout): the
/// saturating gap, the signed high word plus the rounding term, the arithmetic shift, the
/// clamp to the table.
#[cfg(all(test, not(bino_dsp)))]
fn widened_weights(row: &WeightRow, scores: &[i32], out: &mut [u32], first: usize, stride: usize) -> u32 {
    let groups = scores.len() / 4;
    if groups == 0 || !scores.len().is_multiple_of(4) || stride < 2 || out.len() < first + (groups - 1) * stride + 2 {
        return 0;
    }
    let mut sum = 0u32;
    for (g, four) in scores.chunks_exact(4).enumerate() {
        let mut w = [0u32; 4];
        for (w, &s) in w.iter_mut().zip(four) {
            let gap = row.max.saturating_sub(s);
            let hi = ((gap as i64 * row.mult as i64) >> 32) as i32 + row.round as i32;
            *w = EXP2_NEG_U8_TABLE_4K[(hi >> row.post).clamp(0, 4095) as usize] as u32;
            sum = sum.wrapping_add(*w);
        }
        let at = first + g * stride;
        out[at] = w[0] | (w[2] << 16);
        out[at + 1] = w[1] | (w[3] << 16);
    }
    sum
}

/// A row's softmax parameters for [`widened_weights`]: its maximum, the multiplier with the
/// gap's pre-shift folded in (below `2^31`), the rounding term and the right shift.
#[cfg(any(bino_dsp, test))]
struct WeightRow {
    max: i32,
    mult: u32,
    round: u32,
    post: u32,
}

/// Attention's softmax and weighted sums (P·V) for four queries on Cortex-M7, bit for bit the
/// specification's (`attention::attend_block`'s general path): `scores` holds the four rows of
/// `n` scores; returns the four rows' weight totals and `acc[q][d] = sum_j w_qj v_dj`
/// (`values_t`: the `HEAD_DIM` value channels, `n` codes each), which lives in `scratch`.
///
/// The softmax writes each row's weights (unsigned, at most 255) straight into the tile's
/// widened 16-bit layout, so the weighted sums need neither a widening pass nor the offset of
/// int8 weights: rows 2 and 3 first into `scratch` (the block's softmax bytes, `n` words),
/// then rows 0 and 1 into the upper half of `scores` (rows 2 and 3, read by then), rows 2 and
/// 3 copied beside them, and the four-row block kernel against the value channels.
///
/// `None` (nothing written) unless `n` is a multiple of 8 and at least 128, the lengths match, `values_t` and
/// `scratch` are word-aligned and the parameters allow [`softmax_row`]'s shortcuts (with the
/// right shift of the index from the row's own maximum).
#[cfg(any(bino_dsp, test))]
pub(crate) fn softmax_weighted_sums<'s>(
    e: &ExpQ32,
    scores: &mut [i32],
    scratch: &'s mut [u8],
    values_t: &[i8],
) -> Option<([u32; ROWS], &'s [[i32; HEAD_DIM]; ROWS])> {
    let n = scores.len() / ROWS;
    if n < ROWS * HEAD_DIM || !n.is_multiple_of(8) || scores.len() != ROWS * n || values_t.len() != HEAD_DIM * n {
        return None;
    }
    if !(values_t.as_ptr() as usize).is_multiple_of(4) {
        return None;
    }
    let (mult, round, post) = weight_params(e)?;
    let temp: &mut [u32] = bytemuck::try_cast_slice_mut(scratch.get_mut(..4 * n)?).ok()?;
    let (low, high) = scores.split_at_mut(2 * n);
    let mut total = [0u32; ROWS];
    let row = |scores: &[i32]| WeightRow {
        max: row_max_of(scores),
        mult,
        round,
        post,
    };
    for (r, scores) in high.chunks_exact(n).enumerate() {
        total[2 + r] = widened_weights(&row(scores), scores, temp, 2 * r, 4);
    }
    let x: &mut [u32] = bytemuck::cast_slice_mut(high);
    for (r, scores) in low.chunks_exact(n).enumerate() {
        total[r] = widened_weights(&row(scores), scores, x, 2 * r, 2 * ROWS);
    }
    for (group, rows23) in x.chunks_exact_mut(2 * ROWS).zip(temp.chunks_exact(4)) {
        group[4..].copy_from_slice(rows23);
    }
    // The sums go to the softmax bytes, free again (`n >= 128` words: checked), so that no
    // zeroed array is needed for them.
    let sums: &mut [i32] = bytemuck::cast_slice_mut(temp);
    let (sums, _) = sums.as_chunks_mut::<HEAD_DIM>();
    let acc: &mut [[i32; HEAD_DIM]; ROWS] = sums.get_mut(..ROWS)?.try_into().ok()?;
    weighted_sums(x, values_t, n, acc);
    Some((total, acc))
}

/// The multiplier (pre-shift folded in), rounding term and right shift of [`widened_weights`],
/// where [`softmax_row`]'s shortcuts hold (see there); `None` elsewhere.
#[cfg(any(bino_dsp, test))]
fn weight_params(e: &ExpQ32) -> Option<(u32, u32, u32)> {
    let (pre, round, post) = e.shifts();
    let mult = (e.mult() as u64) << pre;
    if mult >= 1 << 31 {
        return None;
    }
    let mult = mult as u32;
    let index = |gap: u32| ((((gap as u64 * mult as u64) >> 32) as u32) + round) >> post;
    (index(EXP_Q32_MAX_GAP) >= EXP2_TABLE_LAST).then_some((mult, round, post))
}

/// One row of [`softmax_weighted_sums`]' softmax, as the block's row 0: its maximum, then its
/// weights into words `8g` and `8g + 1` of `x` (the widened layout); the sum of the weights.
/// `None` (nothing written) for rows not a multiple of 4 long, a short `x`, or parameters
/// outside the shortcuts. The kernel bench's measure of the engine's softmax on Cortex-M7.
#[cfg(any(bino_dsp, test))]
pub(crate) fn softmax_row_widened(e: &ExpQ32, scores: &[i32], x: &mut [u32]) -> Option<u32> {
    let n = scores.len();
    if n == 0 || !n.is_multiple_of(4) || x.len() < 2 * n {
        return None;
    }
    let (mult, round, post) = weight_params(e)?;
    let row = WeightRow {
        max: row_max_of(scores),
        mult,
        round,
        post,
    };
    Some(widened_weights(&row, scores, x, 0, 2 * ROWS))
}

/// A row's maximum (`n` a multiple of 4): the assembly loop on Cortex-M7.
#[cfg(any(bino_dsp, test))]
fn row_max_of(scores: &[i32]) -> i32 {
    #[cfg(bino_dsp)]
    if let Some(m) = row_max(scores) {
        return m;
    }
    scores.iter().fold(i32::MIN, |m, &s| m.max(s))
}

/// `acc[r][d]`: widened row `r` of `x` against value channel `d` (`n` codes each, `n` a
/// multiple of 8): the four-row block kernel, else the tile per channel.
#[cfg(any(bino_dsp, test))]
fn weighted_sums(x: &[u32], values_t: &[i8], n: usize, acc: &mut [[i32; HEAD_DIM]; ROWS]) {
    #[cfg(bino_dsp)]
    if rows_i32(x, values_t, n, acc.as_flattened_mut()) {
        return;
    }
    for (d, channel) in values_t.chunks_exact(n).enumerate() {
        for (acc_r, s) in acc.iter_mut().zip(tile(x, channel, [0; ROWS])) {
            acc_r[d] = s;
        }
    }
}

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
pub(crate) fn rope_rotate_half(v: &[i32; 16], angles: &crate::kernels::rope::Angles, out: &mut [i8; 16]) {
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
/// (`epilogue::residual_lanes`): per channel its ten parameters loaded once (`params`, see
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

/// Rows of int8 to the interleaved 16-bit layout: for group `g` and row `r`, word
/// `8g + 2r` holds elements `(4g, 4g + 2)` and word `8g + 2r + 1` holds `(4g + 1, 4g + 3)`,
/// low halfword first (what `sxtb16` makes of a weight word).
#[inline(always)]
fn widen(rows: [&[i8]; ROWS], x: &mut [u32]) {
    fn pair(lo: i8, hi: i8) -> u32 {
        (lo as i16 as u16 as u32) | ((hi as i16 as u16 as u32) << 16)
    }
    for (r, row) in rows.iter().enumerate() {
        if widen_row(row, x, r) {
            continue;
        }
        for (q, dst) in row.chunks_exact(4).zip(x.chunks_exact_mut(2 * ROWS)) {
            if let (Some(&[e0, e1, e2, e3]), Some(d)) = (q.first_chunk::<4>(), dst.get_mut(2 * r..2 * r + 2)) {
                d[0] = pair(e0, e2);
                d[1] = pair(e1, e3);
            }
        }
    }
}

/// Row `r` of [`widen`] on Cortex-M7: per four codes one word load, the two `sxtb16` a weight
/// word gets in the tile, and one `strd` (the portable loop spent about five instructions a
/// code). The row may sit at any address: Armv7-M's `ldr` takes unaligned words (with
/// `CCR.UNALIGN_TRP` clear, its reset value, which the compiler's own code for these targets
/// assumes too). `false` (nothing written) where `x` has fewer groups than the row: the
/// caller's loop then runs.
#[inline(always)]
fn widen_row(row: &[i8], x: &mut [u32], r: usize) -> bool {
    #[cfg(bino_dsp)]
    {
        let groups = row.len() / 4;
        if groups == 0 || x.len() < groups * 2 * ROWS || r >= ROWS {
            return false;
        }
        // SAFETY: the loop runs `groups >= 1` times; each pass reads one word of `row` (`ldr`,
        // any alignment, see above; `4 groups <= row.len()` bytes in all) and writes words `8g + 2r`
        // and `8g + 2r + 1` of `x` (`x` holds `8 groups` words, checked, and `r < 4`), an
        // `[u32]`, so word-aligned for `strd`. Only declared outputs are written; the flags are
        // clobbered.
        unsafe {
            core::arch::asm!(
                "2:",
                "ldr {t}, [{s}], #4",
                "sxtb16 {a}, {t}",
                "sxtb16 {b}, {t}, ror #8",
                "strd {a}, {b}, [{d}], #32",
                "subs {g}, {g}, #1",
                "bne 2b",
                s = inout(reg) row.as_ptr() => _,
                d = inout(reg) x.as_mut_ptr().wrapping_add(2 * r) => _,
                g = inout(reg) groups => _,
                t = out(reg) _,
                a = out(reg) _,
                b = out(reg) _,
                options(nostack),
            );
        }
        true
    }
    #[cfg(not(bino_dsp))]
    {
        let _ = (row, x, r);
        false
    }
}

/// `acc[r] + sum_t a_r[t] * w[t]` for the 4 widened rows of `x` against one weight row.
#[cfg(bino_dsp)]
#[inline(always)]
fn tile(x: &[u32], w: &[i8], acc: [i32; ROWS]) -> [i32; ROWS] {
    let groups = w.len() / 4;
    if groups == 0 || x.len() < groups * 2 * ROWS || !(w.as_ptr() as usize).is_multiple_of(4) {
        return acc;
    }
    let [mut a0, mut a1, mut a2, mut a3] = acc;
    if groups.is_multiple_of(8) {
        // SAFETY: as below, with the loop running `groups / 8 >= 1` times over eight groups
        // each (every encoder and attention dot product: k = 32, 128, 480, 960): the same
        // `4 * groups` bytes of `w` and `32 * groups` bytes of `x`.
        unsafe {
            core::arch::asm!(
                "2:",
                groups8!(),
                "subs {g}, {g}, #1",
                "bne 2b",
                w = inout(reg) w.as_ptr() => _,
                x = inout(reg) x.as_ptr() => _,
                g = inout(reg) groups / 8 => _,
                a0 = inout(reg) a0,
                a1 = inout(reg) a1,
                a2 = inout(reg) a2,
                a3 = inout(reg) a3,
                t0 = out(reg) _,
                t1 = out(reg) _,
                x0 = out(reg) _,
                x1 = out(reg) _,
                options(nostack, readonly, pure),
            );
        }
        return [a0, a1, a2, a3];
    }
    if groups.is_multiple_of(2) {
        // SAFETY: as below, with the loop running `groups / 2 >= 1` times over two groups
        // each: the same `4 * groups` bytes of `w` and `32 * groups` bytes of `x`.
        unsafe {
            core::arch::asm!(
                "2:",
                group!(),
                group!(),
                "subs {g}, {g}, #1",
                "bne 2b",
                w = inout(reg) w.as_ptr() => _,
                x = inout(reg) x.as_ptr() => _,
                g = inout(reg) groups / 2 => _,
                a0 = inout(reg) a0,
                a1 = inout(reg) a1,
                a2 = inout(reg) a2,
                a3 = inout(reg) a3,
                t0 = out(reg) _,
                t1 = out(reg) _,
                x0 = out(reg) _,
                x1 = out(reg) _,
                options(nostack, readonly, pure),
            );
        }
        return [a0, a1, a2, a3];
    }
    // SAFETY: the loop runs `groups >= 1` times and reads `4 * groups` bytes of `w` (checked
    // above to be in `w` and word-aligned) and `32 * groups` bytes of `x` (checked above; an
    // `[u32]`, so word-aligned for `ldrd`). It writes only its declared outputs and
    // temporaries, touches no stack (`nostack`) and clobbers the flags (not preserved).
    unsafe {
        core::arch::asm!(
            "2:",
            group!(),
            "subs {g}, {g}, #1",
            "bne 2b",
            w = inout(reg) w.as_ptr() => _,
            x = inout(reg) x.as_ptr() => _,
            g = inout(reg) groups => _,
            a0 = inout(reg) a0,
            a1 = inout(reg) a1,
            a2 = inout(reg) a2,
            a3 = inout(reg) a3,
            t0 = out(reg) _,
            t1 = out(reg) _,
            x0 = out(reg) _,
            x1 = out(reg) _,
            options(nostack, readonly, pure),
        );
    }
    [a0, a1, a2, a3]
}

/// The same sums as the assembly tile, in portable Rust (host tests of the driver and layout).
#[cfg(not(bino_dsp))]
fn tile(x: &[u32], w: &[i8], mut acc: [i32; ROWS]) -> [i32; ROWS] {
    fn smlad(acc: i32, x: u32, y: u32) -> i32 {
        let (xl, xh, yl, yh) = (
            x as i16 as i32,
            (x >> 16) as i16 as i32,
            y as i16 as i32,
            (y >> 16) as i16 as i32,
        );
        acc.wrapping_add(xl * yl).wrapping_add(xh * yh)
    }
    for (q, xs) in w.chunks_exact(4).zip(x.chunks_exact(2 * ROWS)) {
        let word = u32::from_le_bytes([q[0] as u8, q[1] as u8, q[2] as u8, q[3] as u8]);
        let even = (word as u8 as i8 as i16 as u16 as u32) | (((word >> 16) as u8 as i8 as i16 as u16 as u32) << 16);
        let odd =
            ((word >> 8) as u8 as i8 as i16 as u16 as u32) | (((word >> 24) as u8 as i8 as i16 as u16 as u32) << 16);
        for (r, a) in acc.iter_mut().enumerate() {
            *a = smlad(smlad(*a, xs[2 * r], even), xs[2 * r + 1], odd);
        }
    }
    acc
}
