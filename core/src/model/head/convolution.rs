//! The head's 3x3x3 convolutions over (row, disparity, column): one output row of a layer from
//! the three input rows its ring holds, each patch column's kernel inputs gathered, multiplied,
//! and requantised by the epilogue ([`ConvEpilogue`] where the formats allow).

use super::super::ids::HEAD_CONVS;
use super::sizing::{conv_inputs, conv_outputs, ring_base, ring_row, TAPS};
use super::{HeadSink, HeadStream};
use crate::config::{HEAD_GROUPS, HEAD_HIDDEN};
use crate::fixed::{sat_i8_i64, Requant};
use crate::kernels::epilogue::ChannelRequant;
use crate::kernels::matmul::matmul_i8;
use crate::kernels::I32s;
use crate::Error;

impl HeadStream<'_, '_> {
    /// Output row `m` of convolution `layer` from its input rows `m - 1 ..= m + 1`.
    pub(super) fn conv_row(&mut self, layer: usize, m: usize, sink: &mut impl HeadSink) -> Result<(), Error> {
        let conv = self.w.conv(layer)?;
        let (cols, nd) = (self.cols, self.candidates);
        let cin = conv_inputs(layer);
        let cout = conv_outputs(layer);
        let rows_in = self.pushed[layer];
        let base = ring_base(layer, cols, nd);
        let (lower, upper) = self
            .rings
            .split_at_mut(ring_base(layer + 1, cols, nd).min(self.rings.len()));
        let input = lower.get(base..).unwrap_or(&[]);
        let slot_of = |r: isize| -> Option<&[i8]> {
            let r = usize::try_from(r).ok().filter(|&r| r < rows_in)?;
            let len = ring_row(layer, cols, nd);
            input.get((r % 3) * len..(r % 3 + 1) * len)
        };
        let rows = [slot_of(m as isize - 1), slot_of(m as isize), slot_of(m as isize + 1)];
        let zero = self.w.zeros.get(layer).copied().unwrap_or(0);
        let out_len = ring_row(layer + 1, cols, nd);
        let out_slot = if layer + 1 < HEAD_CONVS {
            let next = self.pushed[layer + 1];
            upper.get_mut((next % 3) * out_len..(next % 3 + 1) * out_len)
        } else {
            None
        };
        let k = TAPS * cin;
        let rq = conv.requant();
        // The epilogue in 32-bit lanes where the formats allow (quantiser-made ones do).
        let lanes = if layer + 1 < HEAD_CONVS && cout == HEAD_HIDDEN {
            let carry = layer.checked_sub(1).and_then(|l| self.w.carries.get(l).copied());
            let next_zero = self.w.zeros.get(layer + 1).copied().unwrap_or(0);
            ConvEpilogue::new(&rq, carry, zero, next_zero)
        } else {
            None
        };
        let mut out_slot = out_slot;
        for p in 0..cols {
            let gathered = self.gathered.get_mut(..nd * k).unwrap_or(&mut []);
            gather(&rows, (p, cols, nd), cin, zero as i8, gathered);
            let acc = self.acc.get_mut(..nd * cout).unwrap_or(&mut []);
            matmul_i8(gathered, conv.weight, k, acc);
            if layer + 1 == HEAD_CONVS {
                for (d, &a) in self.acc.iter().take(nd).enumerate() {
                    if let Some(l) = self.logits.get_mut(p * nd + d) {
                        *l = if d <= p {
                            a.saturating_add(conv.bias.at(0))
                        } else {
                            i32::MIN
                        };
                    }
                }
                continue;
            }
            let Some(out) = out_slot.as_deref_mut() else { continue };
            let out_cell = out.get_mut(p * nd * cout..(p + 1) * nd * cout).unwrap_or(&mut []);
            let next_zero = self.w.zeros.get(layer + 1).copied().unwrap_or(0) as i64;
            let center = rows[1].and_then(|r| r.get(p * nd * cin..(p + 1) * nd * cin));
            let acc = self.acc.get(..nd * cout).unwrap_or(&[]);
            if lanes.as_ref().is_some_and(|l| l.apply(acc, center, out_cell)) {
                continue;
            }
            for (i, (o, &a)) in out_cell.iter_mut().zip(self.acc.iter()).enumerate() {
                let relu = rq.apply(i % cout, a).max(0);
                let carried = match (layer, center) {
                    (0, _) => 0,
                    (l, Some(x)) => {
                        let carry = self
                            .w
                            .carries
                            .get(l - 1)
                            .copied()
                            .unwrap_or(Requant { mult: 0, shift: 1 });
                        carry.apply_i64(x.get(i).copied().unwrap_or(0) as i64 - zero as i64)
                    }
                    (_, None) => 0,
                };
                *o = sat_i8_i64(carried + relu + next_zero);
            }
        }
        if layer + 1 == HEAD_CONVS {
            self.emit(m, sink);
        }
        Ok(())
    }
}

/// The 27 kernel inputs of every one of the `nd` disparities of column `p` (positions ordered
/// row, disparity, column; channels innermost); outside the volume they are the input's zero
/// point.
pub(super) fn gather(rows: &[Option<&[i8]>; 3], at: (usize, usize, usize), cin: usize, zero: i8, out: &mut [i8]) {
    // The model's widths as constants: each tap is then a fixed-size copy (a few loads and
    // stores) instead of a `memcpy` call, which cost as much as the copy itself.
    match cin {
        HEAD_GROUPS => gather_fixed::<HEAD_GROUPS>(rows, at, zero, out),
        HEAD_HIDDEN => gather_fixed::<HEAD_HIDDEN>(rows, at, zero, out),
        _ => gather_any(rows, at, cin, zero, out),
    }
}

/// The epilogue of a hidden 3D convolution (`HEAD_HIDDEN` outputs per candidate) in 32-bit
/// scalar lanes, bit for bit `HeadStream::conv_row`'s 64-bit one:
/// `sat8(carry(x - zero) + max(rq(acc), 0) + next_zero)`.
///
/// As in `epilogue::residual_lanes`: a rounded shift `(P + 2^(s-1)) >> s` of a product is
/// `(hi32(P 2^e) + 2^(s-33+e)) >> (s - 32 + e)` for `s - 32 + e >= 1`. The requantisation takes
/// `e = 0` (shifts from 33, `|acc + bias| < 2^31` for `|acc|, |bias| < 2^30`); the carry's
/// `x - zero`, below `2^16`, takes `e = 15` (shifts 18 to 47) or 0 (48 to 62). Each term is
/// then below `2^29` in magnitude and, with `|next_zero| < 2^29`, so is their sum's reach.
/// On the Cortex-M55 the cells with a carry run as a Helium kernel (`kernels::arch`).
pub struct ConvEpilogue {
    bias: [i32; HEAD_HIDDEN],
    mult: [i32; HEAD_HIDDEN],
    round: [i32; HEAD_HIDDEN],
    post: [u8; HEAD_HIDDEN],
    /// The Helium kernel's parameters: bias, multiplier, rounding term and negated right
    /// shift, each `HEAD_HIDDEN` words.
    #[cfg(bino_mve)]
    lanes: [i32; 4 * HEAD_HIDDEN],
    /// The carry's multiplier, left shift, rounding term and right shift (none at layer 0).
    carry: Option<(i32, u32, i32, u32)>,
    zero: i32,
    next_zero: i32,
    /// The Cortex-M7 kernel's parameters: per channel bias, multiplier, rounding term, right
    /// shift.
    #[cfg(bino_dsp)]
    channel_params: [[i32; 4]; HEAD_HIDDEN],
    /// The carry of each input code `q` plus the next zero point, at `q + 128` (the next zero
    /// point alone without a carry), for the Cortex-M7 kernel.
    #[cfg(bino_dsp)]
    carried: [i32; 256],
}

impl ConvEpilogue {
    /// The epilogue of a convolution with `HEAD_HIDDEN` output channels requantised by `rq`,
    /// adding `carry` of its input (zero point `zero`; none at layer 0) and the next layer's
    /// zero point; `None` for formats outside the 32-bit identities (see the type).
    pub fn new<B: I32s + ?Sized, M: I32s + ?Sized>(
        rq: &ChannelRequant<'_, B, M>,
        carry: Option<Requant>,
        zero: i32,
        next_zero: i32,
    ) -> Option<Self> {
        if rq.channels() != HEAD_HIDDEN || zero.unsigned_abs() >= 1 << 15 || next_zero.unsigned_abs() >= 1 << 29 {
            return None;
        }
        let mut e = ConvEpilogue {
            bias: [0; HEAD_HIDDEN],
            mult: [0; HEAD_HIDDEN],
            round: [0; HEAD_HIDDEN],
            post: [1; HEAD_HIDDEN],
            #[cfg(bino_mve)]
            lanes: [0; 4 * HEAD_HIDDEN],
            carry: None,
            zero,
            next_zero,
            #[cfg(bino_dsp)]
            channel_params: [[0; 4]; HEAD_HIDDEN],
            #[cfg(bino_dsp)]
            carried: [next_zero; 256],
        };
        for c in 0..HEAD_HIDDEN {
            let (bias, shift) = (rq.bias.at(c), rq.shift.get(c).copied().unwrap_or(0) as u32);
            if !(33..=62).contains(&shift) || bias.unsigned_abs() >= 1 << 30 {
                return None;
            }
            (e.bias[c], e.mult[c]) = (bias, rq.mult.at(c));
            e.round[c] = 1 << (shift - 33);
            e.post[c] = (shift - 32) as u8;
        }
        #[cfg(bino_mve)]
        for (c, lane) in e.lanes.iter_mut().enumerate() {
            let (part, i) = (c / HEAD_HIDDEN, c % HEAD_HIDDEN);
            *lane = match part {
                0 => e.bias[i],
                1 => e.mult[i],
                2 => e.round[i],
                _ => -(e.post[i] as i32),
            };
        }
        if let Some(r) = carry {
            if !(18..=62).contains(&r.shift) {
                return None;
            }
            let pre = if r.shift <= 47 { 15 } else { 0 };
            e.carry = Some((r.mult, pre, 1 << (r.shift + pre - 33), r.shift + pre - 32));
        }
        #[cfg(bino_dsp)]
        {
            for (c, p) in e.channel_params.iter_mut().enumerate() {
                *p = [e.bias[c], e.mult[c], e.round[c], e.post[c] as i32];
            }
            if let Some(carry) = e.carry {
                let carried: [i32; 256] =
                    core::array::from_fn(|i| e.carry_of(carry, (i as i32 - 128) as i8) + next_zero);
                e.carried = carried;
            }
        }
        Some(e)
    }

    /// The carry of one input code: `(hi32(((q - zero) << pre) mult) + round) >> post`.
    #[inline(always)]
    fn carry_of(&self, (mult, pre, round, post): (i32, u32, i32, u32), q: i8) -> i32 {
        let high = ((((q as i32 - self.zero) << (pre & 31)) as i64 * mult as i64) >> 32) as i32;
        (high + round) >> (post & 31)
    }

    /// The outputs of one cell (`acc` and `out`: candidates x `HEAD_HIDDEN`; `center`: the
    /// cell's input, whose codes the carry adds); `false` for accumulators from `2^30` in
    /// magnitude or lengths that do not match: nothing written (on Cortex-M7, codes written
    /// beside an accumulator past the bound, which the caller then recomputes, every one).
    pub fn apply(&self, acc: &[i32], center: Option<&[i8]>, out: &mut [i8]) -> bool {
        if out.len() != acc.len() || acc.iter().fold(0u32, |m, &a| m.max(a.unsigned_abs())) >= 1 << 30 {
            return false;
        }
        // Cortex-M7: one assembly loop (which reads the bound's bits as it goes; past it the
        // codes are recomputed by the caller, which writes every one).
        #[cfg(bino_dsp)]
        if self.carry.is_none() || center.is_some() {
            let x = center.filter(|_| self.carry.is_some());
            if let Some(bits) =
                crate::kernels::arch::dsp::conv_epilogue(acc, x, &self.channel_params, &self.carried, out)
            {
                return bits < 1 << 30;
            }
        }
        let high = |a: i32, b: i32| ((a as i64 * b as i64) >> 32) as i32;
        let params = self.bias.iter().zip(&self.mult).zip(self.round.iter().zip(&self.post));
        // `max(rq(acc), 0)` of one channel (`|acc|, |bias| < 2^30`: the sum does not wrap).
        let relu = |a: i32, ((&bias, &mult), (&round, &post)): ((&i32, &i32), (&i32, &u8))| {
            ((high(a.wrapping_add(bias), mult) + round) >> (post & 31)).max(0)
        };
        // Each case its own loop over whole cells, so that the channels' loop has no branch or
        // bounds check left and vectorises (MVE on the Cortex-M55).
        match self.carry.zip(center) {
            None => {
                let cells = out.chunks_exact_mut(HEAD_HIDDEN).zip(acc.chunks_exact(HEAD_HIDDEN));
                for (outs, accs) in cells {
                    for ((o, &a), p) in outs.iter_mut().zip(accs).zip(params.clone()) {
                        *o = (relu(a, p) + self.next_zero).clamp(-128, 127) as i8;
                    }
                }
            }
            Some((carry, x)) => {
                #[cfg(bino_mve)]
                let (mult, pre, round, post) = carry;
                let carried = |q: i8| self.carry_of(carry, q);
                let add = |o: &mut i8, a: i32, p, q: i8| {
                    *o = (carried(q) + relu(a, p) + self.next_zero).clamp(-128, 127) as i8;
                };
                #[cfg(bino_mve)]
                if x.len() >= acc.len()
                    && crate::kernels::arch::mve::conv_epilogue(
                        acc,
                        x,
                        &self.lanes,
                        (mult, pre as i32, round, -(post as i32)),
                        self.zero,
                        self.next_zero,
                        out,
                    )
                {
                    return true;
                }
                let cells = out.chunks_exact_mut(HEAD_HIDDEN).zip(acc.chunks_exact(HEAD_HIDDEN));
                if x.len() >= acc.len() {
                    for ((outs, accs), xs) in cells.zip(x.chunks_exact(HEAD_HIDDEN)) {
                        for (((o, &a), p), &q) in outs.iter_mut().zip(accs).zip(params.clone()).zip(xs) {
                            add(o, a, p, q);
                        }
                    }
                } else {
                    // A short `center` (not reached: the stream passes whole rows): missing
                    // codes count as 0.
                    for (cell, (outs, accs)) in cells.enumerate() {
                        for (c, ((o, &a), p)) in outs.iter_mut().zip(accs).zip(params.clone()).enumerate() {
                            add(o, a, p, x.get(cell * HEAD_HIDDEN + c).copied().unwrap_or(0));
                        }
                    }
                }
            }
        }
        true
    }
}

// The fixed-width gathers copy words.
const _: () = assert!(HEAD_GROUPS.is_multiple_of(4) && HEAD_HIDDEN.is_multiple_of(4));

/// [`gather`] for `CIN` input channels (a multiple of 4): the nine (row, column) blocks of the
/// patch column's neighbourhood (`nd` candidates of `CIN` codes each, or `None` outside the
/// band) looked up once per column, then per candidate and tap a copy word by word (a copy of 4
/// bytes is always inlined: one load, one store; a whole-array copy became a `memcpy` call).
fn gather_fixed<const CIN: usize>(
    rows: &[Option<&[i8]>; 3],
    (p, cols, nd): (usize, usize, usize),
    zero: i8,
    out: &mut [i8],
) {
    let block = nd * CIN;
    let blocks: [[Option<&[i8]>; 3]; 3] = core::array::from_fn(|r| {
        core::array::from_fn(|k| {
            let pp = (p + k).checked_sub(1).filter(|&pp| pp < cols)?;
            rows[r]?.get(pp * block..(pp + 1) * block)
        })
    });
    for (d, taps) in out.chunks_exact_mut(TAPS * CIN).enumerate() {
        let mut chunks = taps.chunks_exact_mut(CIN);
        for row_blocks in &blocks {
            for dd in [d.wrapping_sub(1), d, d + 1] {
                // Candidate `dd` of a block: `None` past its ends (`d - 1` wraps to a huge
                // offset, `d + 1 = nd` starts at the block's end).
                let at = dd.wrapping_mul(CIN);
                for b in row_blocks {
                    let Some(dst) = chunks.next().and_then(|c| c.first_chunk_mut::<CIN>()) else {
                        return;
                    };
                    match b.and_then(|b| b.get(at..)).and_then(|s| s.first_chunk::<CIN>()) {
                        Some(s) => {
                            for (d, s) in dst.chunks_exact_mut(4).zip(s.chunks_exact(4)) {
                                d.copy_from_slice(s);
                            }
                        }
                        None => dst.fill(zero),
                    }
                }
            }
        }
    }
}

/// [`gather`] for any channel count.
pub(super) fn gather_any(
    rows: &[Option<&[i8]>; 3],
    (p, cols, nd): (usize, usize, usize),
    cin: usize,
    zero: i8,
    out: &mut [i8],
) {
    for (d, taps) in out.chunks_exact_mut(TAPS * cin).enumerate() {
        let mut chunks = taps.chunks_exact_mut(cin);
        for row in rows {
            for dd in [d.wrapping_sub(1), d, d + 1] {
                for pp in [p.wrapping_sub(1), p, p + 1] {
                    let Some(dst) = chunks.next() else { return };
                    let src = match row {
                        Some(r) if dd < nd && pp < cols => r.get((pp * nd + dd) * cin..(pp * nd + dd + 1) * cin),
                        _ => None,
                    };
                    match src {
                        Some(s) => dst.copy_from_slice(s),
                        None => dst.fill(zero),
                    }
                }
            }
        }
    }
}
