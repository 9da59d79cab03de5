use super::*;
use crate::kernels::params::Uniform;
use crate::testutil::{requant_of, Rng};

fn factor(real: f64) -> (i32, u8) {
    let r = requant_of(real);
    (r.mult, r.shift as u8)
}

#[test]
fn residual_add_equals_the_per_channel_formula_across_chunks() {
    const N: usize = 130;
    let mut rng = Rng::new(13);
    for trial in 0..6 {
        let mult: [i32; N] = core::array::from_fn(|_| rng.range(1 << 30, i32::MAX as i64) as i32);
        let shift: [u8; N] = core::array::from_fn(|_| rng.range(20, 45) as u8);
        let cmult: [i32; N] = core::array::from_fn(|_| rng.range(1 << 30, i32::MAX as i64) as i32);
        let cshift: [u8; N] = core::array::from_fn(|_| rng.range(28, 34) as u8);
        let mut bias: [i32; N] = core::array::from_fn(|_| rng.range(-1 << 20, 1 << 20) as i32);
        let mut zero: [i32; N] = core::array::from_fn(|_| rng.range(-300, 300) as i32);
        if trial >= 3 {
            // Parameters no quantiser makes: those chunks take the saturating path.
            bias[70] = i32::MIN;
            zero[5] = i32::MAX;
        }
        let new_zero: [i32; N] = core::array::from_fn(|_| rng.range(-128, 127) as i32);
        let delta = ChannelRequant {
            bias: &bias,
            mult: &mult,
            shift: &shift,
        };
        let carry = ChannelRescale {
            zero: &zero,
            mult: &cmult,
            shift: &cshift,
        };
        let acc: [i32; 3 * N] = core::array::from_fn(|_| {
            if trial % 3 == 2 {
                rng.range(i32::MIN as i64, i32::MAX as i64) as i32
            } else {
                rng.range(-1 << 24, 1 << 24) as i32
            }
        });
        let mut x = [0i8; 3 * N];
        rng.fill_i8(&mut x);
        let before = x;
        residual_add(&mut x, &carry, &acc, &delta, &new_zero);
        for i in 0..3 * N {
            let c = i % N;
            let want = sat_i8_i64(carry.apply(c, before[i]) + delta.apply(c, acc[i]) + new_zero[c] as i64);
            assert_eq!(x[i], want, "trial {trial} index {i}");
        }
    }
}

#[test]
fn residual_lanes_equal_the_reference() {
    const N: usize = 128;
    const ROWS: usize = 8;
    let mut rng = Rng::new(77);
    for trial in 0..40 {
        let (lo, hi) = if trial % 5 == 4 { (10, 62) } else { (33, 62) };
        let mult: [i32; N] = core::array::from_fn(|_| rng.range(-(i32::MAX as i64), i32::MAX as i64) as i32);
        let shift: [u8; N] = core::array::from_fn(|_| rng.range(lo, hi) as u8);
        let cmult: [i32; N] = core::array::from_fn(|_| rng.range(-(i32::MAX as i64), i32::MAX as i64) as i32);
        // The carry's shifts from 18 (a format change near 1 has a shift near 31).
        let cshift: [u8; N] = core::array::from_fn(|_| rng.range(lo.min(18) + 8 * (trial % 2), hi) as u8);
        let bias: [i32; N] = core::array::from_fn(|_| rng.range(-(1 << 30) + 1, (1 << 30) - 1) as i32);
        let zero: [i32; N] = core::array::from_fn(|_| rng.range(-(1 << 15), 1 << 15) as i32);
        let new_zero: [i32; N] = core::array::from_fn(|_| {
            if trial % 7 == 6 {
                rng.range(-(1 << 29) + 1, (1 << 29) - 1) as i32
            } else {
                rng.range(-128, 127) as i32
            }
        });
        let delta = ChannelRequant {
            bias: &bias,
            mult: &mult,
            shift: &shift,
        };
        let carry = ChannelRescale {
            zero: &zero,
            mult: &cmult,
            shift: &cshift,
        };
        let acc: [i32; ROWS * N] = core::array::from_fn(|_| match trial % 4 {
            0 => rng.range(-(1 << 30) + 1, (1 << 30) - 1) as i32,
            1 => rng.range(i32::MIN as i64, i32::MAX as i64) as i32,
            _ => rng.range(-(1 << 22), 1 << 22) as i32,
        });
        let mut x = [0i8; ROWS * N];
        rng.fill_i8(&mut x);
        let mut want = x;
        // Where every identity holds, the lanes take the whole row block.
        if trial % 5 != 4 && trial % 4 != 1 {
            let mut lanes = x;
            for start in (0..N).step_by(CHANNEL_CHUNK) {
                let len = CHANNEL_CHUNK.min(N - start);
                let chunk = residual_lanes::Chunk {
                    n: N,
                    start,
                    len,
                    rows: ROWS,
                    small: residual_lanes::accumulators_fit(&acc),
                };
                assert!(residual_lanes::add_chunk(
                    &mut lanes, &acc, &chunk, &carry, &delta, &new_zero
                ));
            }
            residual_add_reference(&mut want, &carry, &acc, &delta, &new_zero);
            assert_eq!(lanes, want, "trial {trial}: lanes");
            want = x;
        }
        // With the parameters prepared once (where every channel is in the lanes' bounds).
        let mut storage = [0i32; N * residual_lanes::VECTORS];
        let prepared = PreparedResidual::new(&carry, &delta, &new_zero, ROWS, &mut storage);
        assert_eq!(prepared.is_some(), trial % 5 != 4, "trial {trial}: prepared");
        let mut with_prepared = x;
        residual_add_prepared(&mut with_prepared, &carry, &acc, &delta, &new_zero, prepared.as_ref());
        residual_add(&mut x, &carry, &acc, &delta, &new_zero);
        residual_add_reference(&mut want, &carry, &acc, &delta, &new_zero);
        assert_eq!(x, want, "trial {trial}");
        assert_eq!(with_prepared, want, "trial {trial}: prepared");
    }
}

#[test]
fn residual_add_changes_format_and_adds() {
    let (cm, cs) = factor(0.5);
    let (dm, ds) = factor(0.25);
    let carry = ChannelRescale {
        zero: &Uniform(10),
        mult: &[cm; 2],
        shift: &[cs; 2],
    };
    let delta = ChannelRequant {
        bias: &Uniform(4),
        mult: &[dm; 2],
        shift: &[ds; 2],
    };
    let mut x = [30i8, -10, 127, -128];
    let acc = [36, -4, 1000, -1000];
    residual_add(&mut x, &carry, &acc, &delta, &Uniform(-5));
    // (30-10)/2 + (36+4)/4 - 5 = 15; (-10-10)/2 + 0 - 5 = -15; saturated; saturated.
    assert_eq!(x, [15, -15, 127, -128]);
}

#[cfg(target_arch = "x86_64")]
#[test]
fn x86_lanes_take_prepared_blocks_within_their_bound_and_equal_the_reference() {
    use crate::kernels::arch::x86::{avx2, avx2::residual::residual_rows};
    const N: usize = 128;
    let mut rng = Rng::new(79);
    for trial in 0..60 {
        let rows = 1 + trial % 9;
        let mult: [i32; N] = core::array::from_fn(|_| rng.range(-(i32::MAX as i64), i32::MAX as i64) as i32);
        let shift: [u8; N] = core::array::from_fn(|c| [33, 62, 40, 51][(c + trial) % 4]);
        let cmult: [i32; N] = core::array::from_fn(|_| rng.range(-(i32::MAX as i64), i32::MAX as i64) as i32);
        let cshift: [u8; N] = core::array::from_fn(|c| [18, 47, 48, 62, 31][(c + trial) % 5]);
        let bias: [i32; N] = core::array::from_fn(|_| rng.range(-(1 << 30) + 1, (1 << 30) - 1) as i32);
        let zero: [i32; N] = core::array::from_fn(|_| rng.range(-(1 << 15), 1 << 15) as i32);
        let new_zero: [i32; N] = core::array::from_fn(|_| rng.range(-(1 << 29) + 1, (1 << 29) - 1) as i32);
        let delta = ChannelRequant {
            bias: &bias,
            mult: &mult,
            shift: &shift,
        };
        let carry = ChannelRescale {
            zero: &zero,
            mult: &cmult,
            shift: &cshift,
        };
        let mut acc = [0i32; 9 * N];
        for a in acc.iter_mut() {
            *a = match trial % 3 {
                0 => rng.range(-(1 << 30) + 1, (1 << 30) - 1) as i32,
                _ => rng.range(-(1 << 20), 1 << 20) as i32,
            };
        }
        // Every third trial one accumulator at the bound: declined, nothing written.
        let outside = trial % 3 == 2;
        if outside {
            acc[(rows - 1) * N + trial % N] = if trial % 2 == 0 { 1 << 30 } else { -(1 << 30) };
        }
        let mut x = [0i8; 9 * N];
        rng.fill_i8(&mut x[..rows * N]);
        match trial % 4 {
            1 => x[..N].fill(-128),
            3 => x[..N].fill(127),
            _ => {}
        }
        let mut storage = [0i32; N * residual_lanes::VECTORS];
        let prepared =
            PreparedResidual::new(&carry, &delta, &new_zero, rows, &mut storage).expect("in the lanes' bounds");
        let (acc, x) = (&acc[..rows * N], &x[..rows * N]);
        let mut got = [0i8; 9 * N];
        got[..rows * N].copy_from_slice(x);
        let took = residual_rows(&mut got[..rows * N], acc, N, rows, prepared.params);
        assert_eq!(took, !outside && avx2(), "trial {trial}");
        let mut want = [0i8; 9 * N];
        want[..rows * N].copy_from_slice(x);
        if took {
            residual_add_reference(&mut want[..rows * N], &carry, acc, &delta, &new_zero);
        }
        assert_eq!(got[..rows * N], want[..rows * N], "trial {trial}");
    }
}
