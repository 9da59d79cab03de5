//! Attention's softmax row on Cortex-M7 (bit for bit the specification's, through the
//! 4,096-entry exp table where the row's parameters allow the loop's shortcuts) and the
//! largest score of a row.

use crate::kernels::types::exp::{ExpQ32, EXP2_NEG_U8_TABLE_4K, EXP2_TABLE_LAST, EXP_Q32_MAX_GAP};

/// A softmax row on Cortex-M7, bit for bit
/// [`attention::softmax_row`](crate::kernels::reference::softmax::softmax_row): per score one `ldr`, the
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
