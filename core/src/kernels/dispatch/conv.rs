//! The head's convolution epilogue: requantisation, ReLU, the carried input and the next
//! layer's zero point of every output of a hidden 3D convolution, in 32-bit lanes.

use crate::config::HEAD_HIDDEN;
use crate::fixed::Requant;
use crate::kernels::types::params::I32s;
use crate::kernels::types::requant::ChannelRequant;

/// The epilogue of a hidden 3D convolution (`HEAD_HIDDEN` outputs per candidate) in 32-bit
/// scalar lanes, bit for bit the head's 64-bit one (`model::head`):
/// `sat8(carry(x - zero) + max(rq(acc), 0) + next_zero)`.
///
/// As in `dispatch::residual::residual_lanes`: a rounded shift `(P + 2^(s-1)) >> s` of a product is
/// `(hi32(P 2^e) + 2^(s-33+e)) >> (s - 32 + e)` for `s - 32 + e >= 1`. The requantisation takes
/// `e = 0` (shifts from 33, `|acc + bias| < 2^31` for `|acc|, |bias| < 2^30`); the carry's
/// `x - zero`, below `2^16`, takes `e = 15` (shifts 18 to 47) or 0 (48 to 62). Each term is
/// then below `2^29` in magnitude and, with `|next_zero| < 2^29`, so is their sum's reach.
/// On the Cortex-M55 the cells with a carry run as a Helium kernel, on the Cortex-M7 every
/// cell as a DSP loop (`kernels::arch`).
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
        crate::kernels::arch::vectorised(
            #[inline(always)]
            || {
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
            },
        )
    }
}
