//! Attention's softmax and weighted sums (P·V) for four queries on Cortex-M7: each row's
//! weights written straight into the tile's widened layout, then the four-row block kernel
//! against the value channels ([`softmax_weighted_sums`]); one such softmax row alone for the
//! kernel bench ([`softmax_row_widened`]).

#[cfg(bino_dsp)]
use super::gemm::rows_i32;
#[cfg(bino_dsp)]
use super::softmax::row_max;
use super::tile::tile;
use super::ROWS;
use crate::config::HEAD_DIM;
use crate::kernels::types::exp::{ExpQ32, EXP2_NEG_U8_TABLE_4K, EXP2_TABLE_LAST, EXP_Q32_MAX_GAP};

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

/// One softmax row into the tile's widened layout (see [`widen`](super::tile::widen)), bit for bit
/// [`attention::softmax_row`](crate::kernels::reference::softmax::softmax_row) with `row.max` the row's
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
/// int8 weights: rows 2 and 3 first into `scratch` (the softmax bytes, `n` words), then rows
/// 0 and 1 into the upper half of `scores` (rows 2 and 3, read by then), rows 2 and 3 copied
/// beside them, and the four-row block kernel against the value channels; the sums then go to
/// `scratch` (`4 x HEAD_DIM` words), so it holds at least `max(n, 128)` words.
///
/// `None` (nothing written) unless `n` is a multiple of 8, the lengths match, `values_t` and
/// `scratch` are word-aligned, `scratch` is long enough and the parameters allow
/// [`softmax_row`](super::softmax_row)'s shortcuts (with the right shift of the index from the
/// row's own maximum).
#[cfg(any(bino_dsp, test))]
pub(crate) fn softmax_weighted_sums<'s>(
    e: &ExpQ32,
    scores: &mut [i32],
    scratch: &'s mut [u8],
    values_t: &[i8],
) -> Option<([u32; ROWS], &'s [[i32; HEAD_DIM]; ROWS])> {
    let n = scores.len() / ROWS;
    if n == 0 || !n.is_multiple_of(8) || scores.len() != ROWS * n || values_t.len() != HEAD_DIM * n {
        return None;
    }
    if !(values_t.as_ptr() as usize).is_multiple_of(4) {
        return None;
    }
    let (mult, round, post) = weight_params(e)?;
    // Rows 2 and 3's weights (`n` words), later the sums (`ROWS x HEAD_DIM` words).
    let temp: &mut [u32] = bytemuck::try_cast_slice_mut(scratch.get_mut(..4 * n.max(ROWS * HEAD_DIM))?).ok()?;
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
    // The sums go to the softmax bytes, free again (at least 128 words: checked), so that no
    // zeroed array is needed for them.
    let sums: &mut [i32] = bytemuck::cast_slice_mut(temp);
    let (sums, _) = sums.as_chunks_mut::<HEAD_DIM>();
    let acc: &mut [[i32; HEAD_DIM]; ROWS] = sums.get_mut(..ROWS)?.try_into().ok()?;
    weighted_sums(x, values_t, n, acc);
    Some((total, acc))
}

/// The multiplier (pre-shift folded in), rounding term and right shift of [`widened_weights`],
/// where [`softmax_row`](super::softmax_row)'s shortcuts hold (see there); `None` elsewhere.
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
