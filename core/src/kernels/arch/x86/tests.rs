//! Checks the x86 kernels share between their instruction sets' tests (each against the
//! portable specification), called with a kernel that runs on this CPU.

use crate::config::DIM;
use crate::fixed::Requant;
use crate::kernels::arch::x86::vnni::layernorm::{NormLanes, ROWS};
use crate::kernels::arch::x86::vnni::rope::RopeParams;
use crate::kernels::dispatch::{rope_token, ChannelRequant};
use crate::kernels::reference::layernorm::layernorm_rows_reference;
use crate::kernels::types::layernorm::LayerNormQ;
use crate::kernels::types::rope::{Angles, PRE_ROPE_LIMIT};
use crate::testutil::Rng;

/// A token kernel: `false` where it declines.
pub(crate) type RopeKernel = fn(&RopeParams<'_>, &[i32; DIM], &Angles, &Angles, &mut [i8; DIM]) -> bool;

/// `RopeLanes::new`'s lanes of the shifts (32..=62) and biases (below 2^29) given.
struct Lanes {
    round: [i32; DIM],
    pre: [u8; DIM],
    post: [u8; DIM],
}

fn lanes(shift: &[u8; DIM]) -> Lanes {
    let pre: [u8; DIM] = core::array::from_fn(|c| (shift[c] == 32) as u8);
    Lanes {
        round: core::array::from_fn(|c| 1 << (shift[c] as u32 + pre[c] as u32 - 33)),
        post: core::array::from_fn(|c| shift[c] + pre[c] - 32),
        pre,
    }
}

/// A token kernel (`token_avx512`'s contract) against `rope_token`: random and extreme
/// accumulators, biases, multipliers, shifts and angles.
pub(crate) fn check_rope_against_rope_token(kernel: RopeKernel) {
    let mut rng = Rng::new(157);
    let top = (1i64 << 29) - 1;
    for trial in 0..600 {
        // Extremes every few trials: the largest accumulators and biases, the i16 ends of
        // the angles, the shifts' ends.
        let edge = trial % 3 == 0;
        let pick = |rng: &mut Rng, lo: i64, hi: i64| {
            if edge {
                if rng.range(0, 1) == 0 {
                    lo
                } else {
                    hi
                }
            } else {
                rng.range(lo, hi)
            }
        };
        let shift: [u8; DIM] = core::array::from_fn(|_| pick(&mut rng, 32, 62) as u8);
        let mult: [i32; DIM] = core::array::from_fn(|_| pick(&mut rng, i32::MIN as i64, i32::MAX as i64) as i32);
        let bias: [i32; DIM] = core::array::from_fn(|_| pick(&mut rng, -top, top) as i32);
        let acc: [i32; DIM] = core::array::from_fn(|_| match trial % 4 {
            0 | 1 => pick(&mut rng, -top, top) as i32,
            2 => rng.range(-(1 << 20), 1 << 20) as i32,
            _ => rng.range(-300, 300) as i32,
        });
        let angles = |rng: &mut Rng| Angles {
            cos: core::array::from_fn(|_| pick(rng, i16::MIN as i64, i16::MAX as i64) as i16),
            sin: core::array::from_fn(|_| pick(rng, i16::MIN as i64, i16::MAX as i64) as i16),
        };
        let (row, col) = (angles(&mut rng), angles(&mut rng));
        let l = lanes(&shift);
        let params = RopeParams {
            bias: &bias,
            mult: &mult,
            round: &l.round,
            pre: &l.pre,
            post: &l.post,
            limit: PRE_ROPE_LIMIT as i32,
        };
        let mut got = [0i8; DIM];
        assert!(kernel(&params, &acc, &row, &col, &mut got), "trial {trial}");
        let mut want = [0i8; DIM];
        let rq = ChannelRequant {
            bias: &bias,
            mult: &mult,
            shift: &shift,
        };
        rope_token(&acc, &rq, &row, &col, &mut want);
        assert_eq!(got, want, "trial {trial}");
    }
}

/// A token kernel declines accumulators from `2^29` in magnitude and writes nothing.
pub(crate) fn check_rope_declines(kernel: RopeKernel) {
    let (zeros, shifts) = ([0i32; DIM], lanes(&[40; DIM]));
    let params = RopeParams {
        bias: &zeros,
        mult: &zeros,
        round: &shifts.round,
        pre: &shifts.pre,
        post: &shifts.post,
        limit: PRE_ROPE_LIMIT as i32,
    };
    for bad in [1 << 29, -(1 << 29), i32::MIN, i32::MAX] {
        let mut acc = [5i32; DIM];
        acc[DIM - 3] = bad;
        let mut out = [7i8; DIM];
        let angles = Angles::default();
        assert!(!kernel(&params, &acc, &angles, &angles, &mut out));
        assert_eq!(out, [7; DIM]);
    }
}

/// A LayerNorm row kernel (`rows`' contract) against `layernorm_rows_reference`: formats
/// to the lanes' limit, tiny scales, rows it must decline (left untouched), partial blocks.
pub(crate) fn check_layernorm_rows(rows: fn(&NormLanes<'_>, &[i8], &mut [i8]) -> Option<u8>) {
    let mut rng = Rng::new(62);
    let (mut done, mut left) = (0, 0);
    for trial in 0..300 {
        // Formats from narrow to the lanes' limit (2^15), tiny scales (large left shifts),
        // and constant rows (zero variance: the reciprocal passes 2^23, the row is left).
        let wide = trial % 5 == 4;
        let zero: [i32; DIM] = core::array::from_fn(|_| {
            if wide {
                rng.range(-(1 << 15), 1 << 15) as i32
            } else {
                rng.range(-300, 300) as i32
            }
        });
        let rel: [i32; DIM] = core::array::from_fn(|_| match trial % 5 {
            4 => rng.range(-(1 << 15), 1 << 15) as i32,
            3 => rng.range(1, 3) as i32,
            _ => rng.range(1, 30_000) as i32,
        });
        // Rows the lanes decline: a constant row without eps (the reciprocal passes
        // 2^23), and values of +-2^30 (a shift of 14).
        let (zero, rel) = match trial % 11 {
            9 => ([0; DIM], [1; DIM]),
            10 => (
                core::array::from_fn(|c| if c % 2 == 0 { 1 << 15 } else { -(1 << 15) }),
                [1 << 15; DIM],
            ),
            _ => (zero, rel),
        };
        let (eps, mult, shift) = (
            if trial % 11 == 9 { 0 } else { rng.range(0, 1 << 24) },
            rng.range(1 << 30, i32::MAX as i64) as i32,
            rng.range(33, 62) as u32,
        );
        let count = 1 + trial % ROWS;
        let mut x = [0i8; ROWS * DIM];
        rng.fill_i8(&mut x[..count * DIM]);
        match trial % 7 {
            5 => x[..DIM].fill(-128),
            6 => x[DIM..2 * DIM].fill(127),
            _ => {}
        }
        if trial % 11 == 9 {
            x[..DIM].fill(5);
        }
        let x = &x[..count * DIM];
        let p = NormLanes {
            zero: &zero,
            rel: &rel,
            eps,
            mult,
            shift,
        };
        let mut got = [55i8; ROWS * DIM];
        let mask = rows(&p, x, &mut got[..count * DIM]).expect("the kernels run");
        let q = LayerNormQ {
            zero: &zero,
            rel: &rel,
            eps,
            out: Requant { mult, shift },
        };
        let mut want = [0i8; ROWS * DIM];
        layernorm_rows_reference(x, DIM, &q, &mut want[..count * DIM]);
        for r in 0..count {
            let span = r * DIM..(r + 1) * DIM;
            if mask & (1 << r) == 0 {
                assert_eq!(got[span.clone()], want[span], "trial {trial} row {r}");
                done += 1;
            } else {
                assert!(got[span].iter().all(|&b| b == 55), "trial {trial} row {r} written");
                left += 1;
            }
        }
        assert_eq!(u32::from(mask) >> count, 0, "trial {trial}: rows past the input");
    }
    assert!(done > 1000 && left > 0, "{done} done, {left} left");
}
