use super::*;
use crate::kernels::params::Uniform;
use crate::kernels::reference::layernorm::layernorm_row_unbuffered;
use crate::testutil::Rng;

/// sqrt for tests, without std: Newton's method.
fn sqrt(x: f64) -> f64 {
    let mut r = if x > 1.0 { x } else { 1.0 };
    for _ in 0..200 {
        r = 0.5 * (r + x / r);
    }
    r
}

fn float_layernorm(real: &[f64], eps: f64, out_scale: f64, out: &mut [f64]) {
    let n = real.len() as f64;
    let mean = real.iter().sum::<f64>() / n;
    let var = real.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / n;
    for (o, v) in out.iter_mut().zip(real) {
        *o = ((v - mean) / sqrt(var + eps) / out_scale).clamp(-128.0, 127.0);
    }
}

#[test]
fn buffered_rows_equal_the_unbuffered_path() {
    const D: usize = 128;
    let mut rng = Rng::new(3);
    for trial in 0..40 {
        // Ordinary formats, then extreme ones (saturation must agree too).
        let wide = trial >= 30;
        let zero: [i32; D] = core::array::from_fn(|_| {
            if wide {
                rng.range(i32::MIN as i64, i32::MAX as i64) as i32
            } else {
                rng.range(-600, 600) as i32
            }
        });
        // Trials 20..30 have small scales: the centred values are left-shifted up to 24 bits.
        let rel: [i32; D] = core::array::from_fn(|_| {
            if wide {
                rng.range(0, i32::MAX as i64) as i32
            } else if trial >= 20 {
                rng.range(1, 4) as i32
            } else {
                rng.range(1, 40_000) as i32
            }
        });
        let p = LayerNormQ {
            zero: &zero,
            rel: &rel,
            eps: rng.range(0, 1 << 20),
            out: Requant {
                mult: rng.range(1 << 30, i32::MAX as i64) as i32,
                shift: rng.range(20, 50) as u32,
            },
        };
        let mut x = [0i8; D];
        rng.fill_i8(&mut x);
        let (mut fast, mut slow) = ([0i8; D], [0i8; D]);
        layernorm_row(&x, &p, &mut fast);
        layernorm_row_unbuffered(&x, &p, &mut slow);
        assert_eq!(fast, slow, "trial {trial}");
    }
}

#[test]
fn narrow_rows_equal_the_unbuffered_path() {
    const D: usize = 128;
    const ROWS: usize = 6;
    let mut rng = Rng::new(29);
    for trial in 0..60 {
        let limit = NARROW_LIMIT as i64;
        // Quantiser-like formats, then the largest the narrow path accepts.
        let (zero_max, rel_lo) = if trial < 30 { (600, 1) } else { (limit, limit - 50) };
        let zero: [i32; D] = core::array::from_fn(|_| rng.range(-zero_max, zero_max) as i32);
        let rel: [i32; D] = core::array::from_fn(|c| {
            if trial % 7 == 3 {
                rng.range(1, 4) as i32 // small scales: left shifts
            } else if trial % 5 == 1 && c % 3 == 0 {
                -(rng.range(rel_lo, limit) as i32)
            } else {
                rng.range(rel_lo, limit) as i32
            }
        });
        let p = LayerNormQ {
            zero: &zero,
            rel: &rel,
            eps: if trial % 4 == 0 { 0 } else { rng.range(0, 1 << 40) },
            out: Requant {
                mult: rng.range(1 << 30, i32::MAX as i64) as i32,
                shift: rng.range(20, 62) as u32,
            },
        };
        assert!(NarrowParams::decode(&p, D, &mut [0; 2 * D]).is_some());
        let mut x = [0i8; D * ROWS];
        rng.fill_i8(&mut x);
        x[..D].fill(if trial % 2 == 0 { -128 } else { 127 }); // a constant row
        x[D..2 * D]
            .iter_mut()
            .enumerate()
            .for_each(|(c, v)| *v = if c % 2 == 0 { -128 } else { 127 });
        let mut fast = [0i8; D * ROWS];
        layernorm_rows(&x, D, &p, &mut fast);
        for r in 0..ROWS {
            let mut slow = [0i8; D];
            layernorm_row_unbuffered(&x[r * D..(r + 1) * D], &p, &mut slow);
            assert_eq!(fast[r * D..(r + 1) * D], slow, "trial {trial} row {r}");
        }
    }
}

#[test]
fn prepared_parameters_give_the_same_rows() {
    const D: usize = LANE_DIM;
    let mut rng = Rng::new(43);
    for trial in 0..50 {
        let zero: [i32; D] = core::array::from_fn(|_| rng.range(-600, 600) as i32);
        let rel: [i32; D] = core::array::from_fn(|_| rng.range(1, 30_000) as i32);
        let p = LayerNormQ {
            zero: &zero,
            rel: &rel,
            eps: rng.range(0, 1 << 30),
            out: Requant {
                mult: rng.range(1 << 30, i32::MAX as i64) as i32,
                shift: rng.range(33, 50) as u32,
            },
        };
        let mut x = [0i8; 3 * D];
        rng.fill_i8(&mut x);
        let (mut want, mut got) = ([0i8; 3 * D], [0i8; 3 * D]);
        layernorm_rows(&x, D, &p, &mut want);
        let mut storage = [0i32; PreparedLayerNorm::storage_words(D)];
        let mut prepared = PreparedLayerNorm::new(&p, D, &mut storage).expect("narrow formats");
        layernorm_rows_prepared(&x, &mut prepared, &mut got);
        assert_eq!(got, want, "trial {trial}");
    }
    // Too little storage: not prepared.
    let p = LayerNormQ {
        zero: &[0; D],
        rel: &[1; D],
        eps: 0,
        out: Requant {
            mult: 1 << 30,
            shift: 40,
        },
    };
    assert!(PreparedLayerNorm::new(&p, D, &mut [0; 2 * D]).is_none());
}

#[test]
fn lanes_equal_the_unbuffered_path_in_every_shift_class() {
    const D: usize = LANE_DIM;
    let mut rng = Rng::new(41);
    // Rows taken by the lanes, per class of the row's shift: <= 0, 1..=7, 8..=13.
    let mut taken = [0usize; 3];
    for trial in 0..600 {
        let limit = NARROW_LIMIT as i64;
        let rel_max = [4, 300, 6_000, 30_000, limit][trial % 5];
        let zero: [i32; D] = core::array::from_fn(|_| rng.range(-600, 600) as i32);
        let rel: [i32; D] = core::array::from_fn(|c| {
            let r = rng.range(1, rel_max) as i32;
            if trial % 3 == 1 && c % 4 == 0 {
                -r
            } else {
                r
            }
        });
        let p = LayerNormQ {
            zero: &zero,
            rel: &rel,
            eps: if trial % 4 == 0 { 0 } else { rng.range(0, 1 << 40) },
            out: Requant {
                mult: rng.range(-(i32::MAX as i64), i32::MAX as i64) as i32,
                shift: rng.range(30, 62) as u32,
            },
        };
        let mut storage = [0i32; 2 * D];
        let Some(narrow) = NarrowParams::decode(&p, D, &mut storage) else {
            panic!("trial {trial}: {:?} {:?} {}", p.out, &rel[..4], p.eps);
        };
        let mut x = [0i8; D];
        match trial % 11 {
            0 => x.fill(-128),
            1 => x
                .iter_mut()
                .enumerate()
                .for_each(|(c, v)| *v = if c % 2 == 0 { -128 } else { 127 }),
            2 => x[7] = 100,
            _ => rng.fill_i8(&mut x),
        }
        let (mut lanes, mut slow) = ([0i8; D], [0i8; D]);
        layernorm_row_unbuffered(&x, &p, &mut slow);
        let (mut values, mut normalised) = ([0i32; LANE_DIM], [0i32; LANE_DIM]);
        let mut scratch = LaneScratch {
            values: &mut values,
            normalised: &mut normalised,
        };
        if narrow.row_in_lanes(&x, &mut lanes, &mut scratch) {
            assert_eq!(lanes, slow, "trial {trial}");
            let v: [i64; D] = core::array::from_fn(|c| (x[c] as i64 - zero[c] as i64) * rel[c] as i64);
            let sum: i64 = v.iter().sum();
            let max_dev = v
                .iter()
                .map(|&v| (v * D as i64 - sum).unsigned_abs())
                .max()
                .unwrap_or(0);
            let shift = bit_length(max_dev) as i32 - WORK_BITS;
            taken[match shift {
                ..=0 => 0,
                1..=7 => 1,
                _ => 2,
            }] += 1;
        } else {
            assert!(
                p.out.shift < 33 || trial % 11 != 3,
                "trial {trial}: declined an ordinary row"
            );
        }
    }
    assert!(taken.iter().all(|&t| t >= 10), "rows per shift class: {taken:?}");
}

#[test]
fn matches_float_layernorm_with_channel_formats() {
    const D: usize = 128;
    let mut rng = Rng::new(11);
    let out_scale = 4.0 / 127.0;
    // 1 / (out_scale * 2^16) as mult / 2^shift.
    let factor = 1.0 / (out_scale * 65536.0);
    let shift = 40u32;
    let out = Requant {
        mult: (factor * (1u64 << shift) as f64) as i32,
        shift,
    };
    let mut zero = [0i32; D];
    let mut rel = [0i32; D];
    let mut scale = [0f64; D];
    for c in 0..D {
        // Channel scales over two decades, offsets far from zero (a shared "common vector").
        scale[c] = 0.002 * (1 + rng.range(0, 100)) as f64;
        zero[c] = rng.range(-600, 600) as i32;
    }
    let unit = scale.iter().cloned().fold(0.0, f64::max) / 32768.0;
    for c in 0..D {
        rel[c] = (scale[c] / unit) as i32;
    }
    let eps_real = 1e-5;
    let p = LayerNormQ {
        zero: &zero,
        rel: &rel,
        eps: (eps_real / (unit * unit)) as i64,
        out,
    };
    for trial in 0..50 {
        let mut x = [0i8; D];
        rng.fill_i8(&mut x);
        if trial == 0 {
            x = [5; D]; // constant codes, channel formats differ: still a real distribution
        }
        let mut got = [0i8; D];
        layernorm_rows(&x, D, &p, &mut got);
        let real: [f64; D] = core::array::from_fn(|c| (x[c] as f64 - zero[c] as f64) * rel[c] as f64 * unit);
        let mut want = [0f64; D];
        float_layernorm(&real, eps_real, out_scale, &mut want);
        for c in 0..D {
            assert!(
                (got[c] as f64 - want[c]).abs() <= 0.51,
                "trial {trial} c {c}: {} vs {}",
                got[c],
                want[c]
            );
        }
    }
}

#[test]
fn constant_row_gives_zeros() {
    let out = Requant {
        mult: 1 << 30,
        shift: 31,
    };
    let p = LayerNormQ {
        zero: &Uniform(0),
        rel: &Uniform(1 << 15),
        eps: 1 << 20,
        out,
    };
    let mut got = [9i8; 16];
    layernorm_rows(&[77i8; 16], 16, &p, &mut got);
    assert_eq!(got, [0; 16]);
}

#[test]
fn extreme_parameters_do_not_panic() {
    let out = Requant {
        mult: i32::MAX,
        shift: 1,
    };
    let p = LayerNormQ {
        zero: &Uniform(i32::MIN),
        rel: &Uniform(i32::MAX),
        eps: i64::MAX,
        out,
    };
    let mut got = [0i8; 8];
    layernorm_rows(&[-128, 127, 0, 1, -1, 5, 6, 7], 8, &p, &mut got);
    let p = LayerNormQ {
        zero: &Uniform(0),
        rel: &Uniform(0),
        eps: 0,
        out,
    };
    layernorm_rows(&[-128, 127, 0, 1, -1, 5, 6, 7], 8, &p, &mut got);
    assert_eq!(got, [0; 8]);
}
