//! Tests of the head's convolution epilogue and gathers against their plain forms.

use super::convolution::{gather, gather_any};
use super::sizing::TAPS;
use super::ConvEpilogue;
use crate::config::{HEAD_GROUPS, HEAD_HIDDEN};
use crate::fixed::{sat_i8_i64, Requant};
use crate::kernels::dispatch::ChannelRequant;
use crate::testutil::Rng;

#[test]
fn conv_epilogue_lanes_equal_the_64_bit_formula() {
    let mut rng = Rng::new(17);
    let nd = 12;
    let mut taken = 0;
    for trial in 0..120 {
        let lo = if trial % 10 == 9 { 20 } else { 33 };
        let bias: [i32; HEAD_HIDDEN] = core::array::from_fn(|_| rng.range(-(1 << 30) + 1, (1 << 30) - 1) as i32);
        let mult: [i32; HEAD_HIDDEN] = core::array::from_fn(|_| rng.range(-(i32::MAX as i64), i32::MAX as i64) as i32);
        let shift: [u8; HEAD_HIDDEN] = core::array::from_fn(|_| rng.range(lo, 62) as u8);
        let rq = ChannelRequant {
            bias: &bias,
            mult: &mult,
            shift: &shift,
        };
        let carry = (trial % 3 != 0).then(|| Requant {
            mult: rng.range(-(i32::MAX as i64), i32::MAX as i64) as i32,
            shift: rng.range(18, 62) as u32,
        });
        let zero = rng.range(-(1 << 15) + 1, (1 << 15) - 1) as i32;
        let next_zero = rng.range(-(1 << 29) + 1, (1 << 29) - 1) as i32;
        let mut acc = [0i32; 12 * HEAD_HIDDEN];
        for a in acc.iter_mut() {
            *a = match trial % 4 {
                0 => rng.range(-(1 << 30) + 1, (1 << 30) - 1) as i32,
                1 => rng.range(i32::MIN as i64, i32::MAX as i64) as i32,
                _ => rng.range(-(1 << 23), 1 << 23) as i32,
            };
        }
        let mut center = [0i8; 12 * HEAD_HIDDEN];
        rng.fill_i8(&mut center);
        // Every seventh trial a center shorter than the cells (its missing codes count as 0).
        let center_len = if trial % 7 == 6 {
            5 * HEAD_HIDDEN + 7
        } else {
            center.len()
        };
        let center = (trial % 5 != 4).then_some(&center[..center_len]);
        let mut want = [0i8; 12 * HEAD_HIDDEN];
        for (i, (o, &a)) in want.iter_mut().zip(&acc).enumerate().take(nd * HEAD_HIDDEN) {
            let relu = rq.apply(i % HEAD_HIDDEN, a).max(0);
            let carried = match (carry, center) {
                (Some(r), Some(x)) => r.apply_i64(x.get(i).copied().unwrap_or(0) as i64 - zero as i64),
                _ => 0,
            };
            *o = sat_i8_i64(carried + relu + next_zero as i64);
        }
        match ConvEpilogue::new(&rq, carry, zero, next_zero) {
            Some(e) => {
                let mut got = [0i8; 12 * HEAD_HIDDEN];
                if e.apply(&acc, center, &mut got) {
                    assert_eq!(got, want, "trial {trial}");
                    taken += 1;
                } else {
                    assert_eq!(trial % 4, 1, "trial {trial}: declined small accumulators");
                }
            }
            None => assert_eq!(trial % 10, 9, "trial {trial}: declined ordinary formats"),
        }
    }
    assert!(taken >= 60, "{taken}");
}

#[test]
fn fixed_width_gather_equals_the_general_one() {
    let mut rng = Rng::new(3);
    let (cols, nd) = (5, 4);
    for cin in [HEAD_GROUPS, HEAD_HIDDEN] {
        let mut ring = [[0i8; 5 * 4 * HEAD_HIDDEN]; 3];
        for r in ring.iter_mut() {
            rng.fill_i8(r);
        }
        let len = cols * nd * cin;
        for missing in [None, Some(0), Some(2)] {
            let rows: [Option<&[i8]>; 3] = core::array::from_fn(|i| (Some(i) != missing).then(|| &ring[i][..len]));
            for p in 0..cols {
                let mut fixed = [0i8; 4 * TAPS * HEAD_HIDDEN];
                let mut any = [1i8; 4 * TAPS * HEAD_HIDDEN];
                gather(&rows, (p, cols, nd), cin, -7, &mut fixed[..nd * TAPS * cin]);
                gather_any(&rows, (p, cols, nd), cin, -7, &mut any[..nd * TAPS * cin]);
                assert_eq!(
                    fixed[..nd * TAPS * cin],
                    any[..nd * TAPS * cin],
                    "cin {cin} p {p} {missing:?}"
                );
            }
        }
    }
}
