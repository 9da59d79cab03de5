//! The head's 3x3x3 convolutions over (row, disparity, column): one output row of a layer from
//! the three input rows its ring holds, each patch column's kernel inputs gathered, multiplied,
//! and requantised by the epilogue ([`ConvEpilogue`](crate::kernels::dispatch::ConvEpilogue) where the formats allow).

use super::super::ids::HEAD_CONVS;
use super::sizing::{conv_inputs, conv_outputs, ring_base, ring_row, TAPS};
use super::{HeadSink, HeadStream};
use crate::config::{HEAD_GROUPS, HEAD_HIDDEN};
use crate::fixed::{sat_i8_i64, Requant};
use crate::kernels::dispatch::matmul_i8;
use crate::kernels::dispatch::ConvEpilogue;
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
