use super::fused::{matmul_prepared_with, matmul_requant_with, Col};
use super::*;
use crate::kernels::reference::gemm::matmul_requant_reference;
use crate::kernels::reference::matmul::matmul_i8_reference;
use crate::kernels::types::requant::ChannelRequant;
use crate::testutil::Rng;

type Driver = fn(&[i8], &[i8], usize, usize, &mut fused::Fused<'_>) -> bool;
type StoreDriver = fn(&[i8], &[i8], usize, usize, &mut Store<'_>) -> bool;
const DRIVERS: [(&str, StoreDriver, Driver); 2] = [
    (
        "dsp",
        |a, w, k, m, e| dsp::gemm(a, w, k, m, e),
        |a, w, k, m, e| dsp::gemm(a, w, k, m, e),
    ),
    // The Helium row drivers: whole rows of column triples per kernel call.
    (
        "mve",
        |a, w, k, m, e| mve::gemm_i32(a, w, k, m, e.n, e.out),
        mve::gemm_fused,
    ),
];

#[test]
fn drivers_with_portable_tiles_match_the_reference() {
    // The drivers' blocking, leftover rows and columns and the DSP scratch layout, on the
    // host (the firmware's kernel-tests check the assembly tiles themselves).
    let mut rng = Rng::new(21);
    let mut a = [0i8; 5 * 132];
    let mut w = [0i8; 131 * 132];
    for (m, n, k) in [
        (1, 1, 4),
        (2, 3, 8),
        (3, 4, 12),
        (4, 5, 20),
        (5, 7, 132),
        (5, 131, 36),
        (4, 2, 17),
    ] {
        rng.fill_i8(&mut a[..m * k]);
        rng.fill_i8(&mut w[..n * k]);
        let (a, w) = (&a[..m * k], &w[..n * k]);
        let mut want = [0i32; 5 * 131];
        matmul_i8_reference(a, w, k, &mut want[..m * n]);
        let bias: [i32; 131] = core::array::from_fn(|_| rng.range(-1 << 20, 1 << 20) as i32);
        let mult: [i32; 131] = core::array::from_fn(|_| rng.range(1 << 30, i32::MAX as i64) as i32);
        let shift: [u8; 131] = core::array::from_fn(|_| rng.range(33, 40) as u8);
        let zero: [i32; 131] = core::array::from_fn(|_| rng.range(-128, 127) as i32);
        let rq = ChannelRequant {
            bias: &bias[..n],
            mult: &mult[..n],
            shift: &shift[..n],
        };
        let mut want8 = [0i8; 5 * 131];
        matmul_requant_reference(a, w, k, &rq, &zero[..n], &mut want8[..m * n]);
        for (name, store, fused) in DRIVERS {
            let takes = name == "mve" || k % 4 == 0;
            let mut got = [0i32; 5 * 131];
            let took = store(a, w, k, m, &mut Store { out: &mut got, n });
            assert_eq!(took, takes, "{name} m={m} n={n} k={k}");
            if took {
                assert_eq!(got[..m * n], want[..m * n], "{name} m={m} n={n} k={k}");
            }
            let mut got8 = [0i8; 5 * 131];
            let took = matmul_requant_with(a, w, k, &rq, &zero[..n], &mut got8[..m * n], fused);
            assert_eq!(took, takes, "{name} fused m={m} n={n} k={k}");
            if took {
                assert_eq!(got8[..m * n], want8[..m * n], "{name} fused m={m} n={n} k={k}");
            }
            // The same columns prepared once.
            let mut storage = [0i32; 4 * 131];
            let prepared = PreparedRequant::new(&rq, &zero[..n], &mut storage).expect("columns in range");
            let mut got8 = [0i8; 5 * 131];
            let took = matmul_prepared_with(a, w, k, &prepared, &mut got8[..m * n], fused);
            assert_eq!(took, takes, "{name} prepared m={m} n={n} k={k}");
            if took {
                assert_eq!(got8[..m * n], want8[..m * n], "{name} prepared m={m} n={n} k={k}");
            }
            if name == "mve" {
                // The Cortex-M55's prepared path: every accumulator, then two rows at a time.
                let (mut got8, mut acc) = ([0i8; 5 * 131], [0i32; 5 * 131]);
                let took = mve::gemm_prepared(a, w, k, prepared.records(), &mut acc, &mut got8[..m * n]);
                assert!(took, "mve gemm_prepared m={m} n={n} k={k}");
                assert_eq!(got8[..m * n], want8[..m * n], "mve gemm_prepared m={m} n={n} k={k}");
                let short = mve::gemm_prepared(a, w, k, prepared.records(), &mut acc[..m * n - 1], &mut got8[..m * n]);
                assert!(!short, "an accumulator scratch shorter than the output is declined");
            }
        }
    }
}

#[test]
fn dsp_rows_with_a_lent_scratch_match_the_reference() {
    let mut rng = Rng::new(36);
    let mut scratch = [0u32; 2 * 960];
    for (m, n, k) in [(1usize, 1usize, 4usize), (3, 5, 36), (4, 32, 960), (4, 3, 128)] {
        let mut a = [0i8; 4 * 960];
        let mut w = [0i8; 32 * 960];
        rng.fill_i8(&mut a[..m * k]);
        rng.fill_i8(&mut w[..n * k]);
        let (mut got, mut want) = ([0i32; 4 * 32], [0i32; 4 * 32]);
        let took = dsp::gemm_rows_in(
            &a[..m * k],
            &w[..n * k],
            k,
            m,
            &mut Store { out: &mut got, n },
            &mut scratch,
        );
        assert!(took, "m={m} n={n} k={k}");
        matmul_i8_reference(&a[..m * k], &w[..n * k], k, &mut want[..m * n]);
        assert_eq!(got[..m * n], want[..m * n], "m={m} n={n} k={k}");
    }
    // Five rows, or a scratch short of k / 2 words, are declined.
    let (a, w) = ([1i8; 5 * 8], [1i8; 8]);
    assert!(!dsp::gemm_rows_in(
        &a,
        &w,
        8,
        5,
        &mut Store { out: &mut [0; 5], n: 1 },
        &mut scratch
    ));
    assert!(!dsp::gemm_rows_in(
        &a[..8],
        &w,
        8,
        1,
        &mut Store { out: &mut [0; 1], n: 1 },
        &mut [0u32; 3]
    ));
}

#[test]
fn dsp_scores_layout_matches_the_reference() {
    // The Cortex-M7 scores kernel's widening and row-strided stores, through its portable
    // twin (the kernel test firmware checks the assembly on 1 to 960 keys).
    let mut rng = Rng::new(34);
    for (n, extreme) in [(1usize, false), (2, true), (7, false), (33, false), (33, true)] {
        let mut queries = [[0i8; HEAD_DIM]; 4];
        let mut keys = [0i8; 33 * HEAD_DIM];
        if extreme {
            queries = [[-128; HEAD_DIM]; 4];
            keys.fill(-128);
            keys[..HEAD_DIM].fill(127);
        } else {
            queries.iter_mut().for_each(|q| rng.fill_i8(q));
            rng.fill_i8(&mut keys);
        }
        let keys = &keys[..n * HEAD_DIM];
        let (mut got, mut want) = ([0i32; 4 * 33], [0i32; 4 * 33]);
        assert!(dsp::attention_scores(&queries, keys, &mut got[..4 * n]));
        crate::kernels::reference::attention::scores_block_reference(&queries, keys, &mut want[..4 * n]);
        assert_eq!(got[..4 * n], want[..4 * n], "n {n}");
    }
    assert!(!dsp::attention_scores(&[[0; HEAD_DIM]; 4], &[0; HEAD_DIM], &mut [0; 3]));
}

#[test]
fn dsp_softmax_shortcuts_match_the_specification() {
    use crate::fixed::Requant;
    use crate::kernels::reference::softmax::softmax_row as specification;
    let mut rng = Rng::new(35);
    let mut taken = 0;
    for trial in 0..3000 {
        let shift = rng.range(22, 40) as u32;
        let mult = if trial % 4 == 0 {
            rng.range(1, 1 << 20) as i32
        } else {
            rng.range(1 << 29, i32::MAX as i64) as i32
        };
        let Some(e) = ExpQ32::new(Requant { mult, shift }) else {
            continue;
        };
        let n = rng.range(1, 40) as usize;
        let mut scores = [0i32; 40];
        for s in scores[..n].iter_mut() {
            *s = rng.range(-(1 << 19), 1 << 19) as i32;
        }
        // Mostly the row's true maximum; sometimes one below a score (wrapped gaps) or
        // far above every score (gaps past the clamp).
        let top = scores[..n].iter().copied().max().unwrap_or(0);
        let max = match trial % 5 {
            0 => top - 1,
            1 => top + (1 << 21),
            _ => top,
        };
        let (mut got, mut want) = ([0u8; 40], [0u8; 40]);
        let want_sum = specification(&e, max, &scores[..n], &mut want[..n]);
        if let Some(sum) = dsp::softmax_row(&e, max, &scores[..n], &mut got[..n]) {
            taken += 1;
            assert_eq!((got, sum), (want, want_sum), "mult {mult} shift {shift} max {max}");
        } else {
            assert_eq!(got, [0; 40], "declined rows are not written");
        }
    }
    assert!(taken > 1000, "{taken} rows taken");
}

#[test]
fn dsp_softmax_into_the_widened_rows_matches_the_specification() {
    use crate::fixed::Requant;
    use crate::kernels::reference::softmax::softmax_row as specification;
    let mut rng = Rng::new(36);
    let mut taken = 0;
    for trial in 0..600 {
        let shift = rng.range(22, 40) as u32;
        let mult = rng.range(1 << 29, i32::MAX as i64) as i32;
        let Some(e) = ExpQ32::new(Requant { mult, shift }) else {
            continue;
        };
        // Rows of 8 to 256 keys: the band's, and a token row's (attention within the row).
        let n = 8 * rng.range(1, 32) as usize;
        let mut scores = [0i32; 4 * 256];
        // Attention's range, and every fifth block the extremes of i32 (gaps past 2^31,
        // which the kernel saturates).
        let span = if trial % 5 == 0 { i32::MAX as i64 } else { 1 << 19 };
        for s in scores[..4 * n].iter_mut() {
            *s = rng.range(-span, span) as i32;
        }
        if trial % 5 == 0 {
            scores[0] = i32::MIN;
            scores[1] = i32::MAX;
        }
        let mut values_t = [0i8; HEAD_DIM * 256];
        for v in values_t[..HEAD_DIM * n].iter_mut() {
            *v = rng.range(-128, 127) as i8;
        }
        let mut want_acc = [[0i32; HEAD_DIM]; 4];
        let mut want_total = [0u32; 4];
        for (q, row) in scores[..4 * n].chunks_exact(n).enumerate() {
            let max = row.iter().copied().max().unwrap_or(0);
            let mut w = [0u8; 256];
            want_total[q] = specification(&e, max, row, &mut w[..n]);
            for (d, channel) in values_t[..HEAD_DIM * n].chunks_exact(n).enumerate() {
                // The specification stores `w ^ 0x80`.
                want_acc[q][d] = channel
                    .iter()
                    .zip(&w[..n])
                    .map(|(&v, &w)| v as i32 * (w ^ 0x80) as i32)
                    .sum();
            }
        }
        let mut scratch = [0u32; 256];
        let scratch: &mut [u8] = bytemuck::cast_slice_mut(&mut scratch[..]);
        let before = scores;
        match dsp::softmax_weighted_sums(
            &e,
            &mut scores[..4 * n],
            &mut scratch[..4 * n.max(4 * HEAD_DIM)],
            &values_t[..HEAD_DIM * n],
        ) {
            Some((total, acc)) => {
                taken += 1;
                assert_eq!((total, *acc), (want_total, want_acc), "mult {mult} shift {shift} n {n}");
            }
            None => assert_eq!(scores, before, "declined blocks are not written"),
        }
    }
    assert!(taken > 200, "{taken} blocks taken");
    // Rows of a length the four-row kernel does not take are declined.
    let e = ExpQ32::new(Requant {
        mult: 1 << 30,
        shift: 34,
    })
    .unwrap();
    assert!(dsp::softmax_weighted_sums(&e, &mut [0; 16], &mut [0; 16], &[0; HEAD_DIM * 4]).is_none());
    // And softmax bytes too short to hold the sums (fewer than 128 words).
    assert!(dsp::softmax_weighted_sums(&e, &mut [0; 4 * 120], &mut [0; 4 * 120], &[0; HEAD_DIM * 120]).is_none());
}

#[test]
fn dsp_softmax_row_into_the_widened_layout_matches_the_specification() {
    use crate::fixed::Requant;
    use crate::kernels::reference::softmax::softmax_row as specification;
    let mut rng = Rng::new(37);
    let e = ExpQ32::new(Requant {
        mult: 1_431_142_052,
        shift: 34,
    })
    .unwrap();
    for n in [4usize, 8, 36, 960] {
        let scores: [i32; 960] = core::array::from_fn(|_| rng.range(-(1 << 19), 1 << 19) as i32);
        let (scores, mut x) = (&scores[..n], [0u32; 2 * 960]);
        let max = scores.iter().copied().max().unwrap_or(0);
        let mut want = [0u8; 960];
        let want_sum = specification(&e, max, scores, &mut want[..n]);
        assert_eq!(dsp::softmax_row_widened(&e, scores, &mut x), Some(want_sum), "n {n}");
        for (j, &w) in want[..n].iter().enumerate() {
            let word = x[8 * (j / 4) + (j & 1)];
            let got = if j % 4 < 2 { word & 0xFFFF } else { word >> 16 };
            assert_eq!(got, (w ^ 0x80) as u32, "n {n} score {j}");
        }
    }
    assert_eq!(dsp::softmax_row_widened(&e, &[0; 6], &mut [0; 16]), None);
}

#[test]
fn fused_epilogue_equals_the_64_bit_formula_in_its_range() {
    let mut rng = Rng::new(5);
    for _ in 0..20_000 {
        let shift = rng.range(33, 62) as u8;
        let (mult, zero) = (
            rng.range(i32::MIN as i64, i32::MAX as i64) as i32,
            rng.range(-300, 300) as i32,
        );
        let bias = rng.range(-(1 << 30) + 1, (1 << 30) - 1) as i32;
        let Some(col) = Col::new(bias, mult, shift, zero) else {
            continue;
        };
        let acc = rng.range(-(1 << 29), 1 << 29) as i32;
        let rq = ChannelRequant {
            bias: &[bias][..],
            mult: &[mult][..],
            shift: &[shift][..],
        };
        let want = crate::fixed::sat_i8_i64(rq.apply(0, acc) + zero as i64);
        assert_eq!(
            col.apply(acc + bias),
            want,
            "acc {acc} bias {bias} mult {mult} shift {shift} zero {zero}"
        );
    }
    // Outside the range the kernels decline.
    assert!(Col::new(1 << 30, 1, 40, 0).is_none());
    assert!(Col::new(0, 1, 32, 0).is_none());
    assert!(Col::new(0, 1, 62, 1).is_none());
}

#[test]
fn shapes_outside_the_kernels_are_declined() {
    assert_eq!(shape(&[0; 8], &[0; 8], 0, 4), None);
    assert_eq!(shape(&[0; 8], &[0; 8], MAX_K + 1, 4), None);
    assert_eq!(shape(&[0; 8], &[0; 8], 4, 3), None);
    assert_eq!(shape(&[0; 3], &[0; 8], 4, 4), None);
    assert_eq!(shape(&[0; 8], &[0; 8], 4, 4), Some((2, 2)));
}

#[cfg(target_arch = "x86_64")]
#[test]
fn x86_prepared_requantisation_matches_the_reference() {
    // The x86 matrix multiplies, then the prepared columns in AVX2 lanes (eight columns a step
    // and a scalar tail), against the reference GEMM and requantisation.
    let mut rng = Rng::new(41);
    let mut a = [0i8; 9 * 480];
    let mut w = [0i8; 131 * 480];
    for (m, n, k) in [
        (1, 1, 16),
        (8, 128, 128),
        (5, 131, 32),
        (8, 13, 480),
        (3, 8, 48),
        (4, 9, 17),
    ] {
        rng.fill_i8(&mut a[..m * k]);
        rng.fill_i8(&mut w[..n * k]);
        if n == 13 {
            a.fill(-128);
            w.fill(-128);
        }
        let (a, w) = (&a[..m * k], &w[..n * k]);
        let bias: [i32; 131] = core::array::from_fn(|_| rng.range(-(1 << 30) + 1, 1 << 30) as i32);
        let mult: [i32; 131] = core::array::from_fn(|_| rng.range(i32::MIN as i64, i32::MAX as i64) as i32);
        let shift: [u8; 131] = core::array::from_fn(|_| rng.range(33, 53) as u8);
        let zero: [i32; 131] = core::array::from_fn(|_| rng.range(-128, 128) as i32);
        let rq = ChannelRequant {
            bias: &bias[..n],
            mult: &mult[..n],
            shift: &shift[..n],
        };
        let mut want = [0i8; 9 * 131];
        matmul_requant_reference(a, w, k, &rq, &zero[..n], &mut want[..m * n]);
        let mut storage = [0i32; 4 * 131];
        let prepared = PreparedRequant::new(&rq, &zero[..n], &mut storage).expect("columns in range");
        let (mut got, mut acc) = ([0i8; 9 * 131], [0i32; 9 * 131]);
        let took = x86::matmul_requant_prepared(a, w, k, prepared.records(), &mut acc, &mut got[..m * n]);
        let takes = k % 16 == 0 && x86::avx2();
        assert_eq!(took, takes, "m={m} n={n} k={k}");
        if took {
            assert_eq!(got[..m * n], want[..m * n], "m={m} n={n} k={k}");
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[test]
fn x86_prepared_requantisation_declines_accumulators_out_of_range() {
    let mut rng = Rng::new(43);
    let n = 11;
    let cols: [[i32; 4]; 11] = core::array::from_fn(|_| {
        let (bias, mult) = (
            rng.range(-(1 << 20), 1 << 20) as i32,
            rng.range(1 << 30, i32::MAX as i64) as i32,
        );
        Col::new(bias, mult, rng.range(33, 45) as u8, rng.range(-128, 128) as i32)
            .expect("in range")
            .to_words()
    });
    let edges = [(1 << 30) - 1, -(1 << 30), 0, -1, 12345, -999_999];
    for bad in [
        None,
        Some((3, 1 << 30)),
        Some((9, -(1 << 30) - 1)),
        Some((26, i32::MAX)),
    ] {
        let mut acc: [i32; 3 * 11] = core::array::from_fn(|i| edges[i % edges.len()]);
        if let Some((at, v)) = bad {
            acc[at] = v;
        }
        let mut out = [0i8; 3 * 11];
        let took = x86::avx2::requant_prepared(&cols, &acc, &mut out);
        assert_eq!(took, bad.is_none() && x86::avx2(), "{bad:?}");
        if took {
            for (i, (&a, &o)) in acc.iter().zip(&out).enumerate() {
                let col = Col::from_words(&cols[i % n]);
                assert_eq!(o, col.apply(a + col.bias), "index {i}");
            }
        }
    }
}
