use super::*;
use crate::kernels::reference::matmul::dot;
use crate::testutil::Rng;

#[test]
fn the_word_cubic_equals_the_exp_table_for_every_exponent() {
    if !supported() {
        return; // the softmax row never takes this path here
    }
    let e = ExpQ32::new(crate::fixed::Requant {
        mult: 1 << 30,
        shift: 30,
    })
    .expect("shift >= 22");
    let exponents: [u16; 2 * 1184] = core::array::from_fn(|x| x.min(EXP2_TABLE_LAST as usize) as u16);
    for chunk in exponents.chunks_exact(32) {
        let x: [u16; 32] = chunk.try_into().expect("32 words");
        // SAFETY: `supported()` saw every feature these functions are compiled for.
        #[allow(unsafe_code)]
        let weights: [u16; 32] = unsafe { must_cast(ExpLanes::new(&e, 0).cubic16(must_cast(x))) };
        for (&x, &w) in x.iter().zip(&weights) {
            assert_eq!(
                w,
                u16::from(crate::kernels::types::exp::EXP2_NEG_U8_TABLE[x as usize]),
                "x = {x}"
            );
        }
    }
}

// One test: switching the kernels off is process-wide, and a second test doing it would
// race this one.
#[test]
fn the_kernels_match_plain_dots_where_the_cpu_has_vnni_and_decline_when_off() {
    let was = available();
    assert!(!enable(false));
    assert!(!matmul_i32(&[1; 64], &[1; 64], 32, &mut [0; 4]));
    assert!(!scores4(&[[1; HEAD]; 4], &[1; HEAD], 1, &mut [0; 4]));
    assert_eq!(enable(true), was);
    if !was {
        return; // nothing more to check on this CPU: the callers fall back (tested there)
    }
    let mut rng = Rng::new(41);
    let mut a = [0i8; 17 * 480];
    let mut w = [0i8; 21 * 480];
    let shapes = [
        (4, 4, 32),
        (9, 7, 64),
        (5, 3, 128),
        (8, 7, 480),
        (1, 1, 32),
        (3, 6, 96),
        (17, 21, 128),
        (8, 16, 480),
    ];
    for (m, n, k) in shapes {
        rng.fill_i8(&mut a[..m * k]);
        rng.fill_i8(&mut w[..n * k]);
        if k == 480 {
            a[..m * k].fill(-128);
            w[..n * k].fill(-128);
        }
        let mut out = [i32::MIN; 17 * 21];
        assert!(matmul_i32(&a[..m * k], &w[..n * k], k, &mut out[..m * n]));
        for i in 0..m {
            for j in 0..n {
                let want = dot(&a[i * k..(i + 1) * k], &w[j * k..(j + 1) * k]);
                assert_eq!(out[i * n + j], want, "m={m} n={n} k={k} ({i}, {j})");
            }
        }
    }
    for n in [1, 8, 13, 16, 48, 64, 80, 960] {
        let mut keys = [0i8; 960 * HEAD];
        let mut values_t = [0i8; 960 * HEAD];
        let mut weights = [0i8; 4 * 960];
        let mut queries = [[0i8; HEAD]; 4];
        rng.fill_i8(&mut keys[..n * HEAD]);
        rng.fill_i8(&mut values_t[..n * HEAD]);
        rng.fill_i8(&mut weights[..4 * n]);
        queries.iter_mut().for_each(|q| rng.fill_i8(q));
        if n == 960 {
            keys.fill(-128);
            values_t.fill(127);
            weights.fill(-128);
            queries = [[-128; HEAD]; 4];
        }
        let mut scores = [i32::MIN; 4 * 960];
        if n % 8 == 0 {
            // The transposed layout gives the same scores.
            let mut keys_t = [0i8; 960 * HEAD];
            for (t, key) in keys[..n * HEAD].chunks_exact(HEAD).enumerate() {
                crate::kernels::dispatch::attention::store_key(
                    crate::kernels::dispatch::attention::KeyLayout::Transposed,
                    key,
                    &mut keys_t[..n * HEAD],
                    t,
                );
            }
            assert!(scores4_transposed(
                &queries,
                &keys_t[..n * HEAD],
                n,
                &mut scores[..4 * n]
            ));
            for (q, row) in queries.iter().zip(scores.chunks_exact(n)) {
                for (j, &s) in row.iter().enumerate() {
                    assert_eq!(s, dot(q, &keys[j * HEAD..(j + 1) * HEAD]), "transposed n={n} key {j}");
                }
            }
            scores.fill(i32::MIN);
        }
        assert!(scores4(&queries, &keys[..n * HEAD], n, &mut scores[..4 * n]));
        for (q, row) in queries.iter().zip(scores.chunks_exact(n)) {
            for (j, &s) in row.iter().enumerate() {
                assert_eq!(s, dot(q, &keys[j * HEAD..(j + 1) * HEAD]), "n={n} key {j}");
            }
        }
        let sums = crate::kernels::dispatch::attention::value_sums(&values_t[..n * HEAD], n);
        let mut acc = [[0i32; HEAD]; 4];
        let taken = weighted_sums4(&weights[..4 * n], &values_t[..HEAD * n], n, &sums, &mut acc);
        assert_eq!(taken, n % (STEP / 2) == 0, "n={n}");
        if taken {
            for (q, acc_q) in acc.iter().enumerate() {
                for (d, &s) in acc_q.iter().enumerate() {
                    let want = dot(&weights[q * n..(q + 1) * n], &values_t[d * n..(d + 1) * n]);
                    assert_eq!(s, want, "n={n} query {q} channel {d}");
                }
            }
        }
    }
}

#[test]
fn empty_operands_are_declined_not_a_panic() {
    // Found by the `kernels` fuzz target: a weight slice shorter than one row gave n = 0.
    let a = [1i8; 64];
    assert!(!matmul_i32(&a, &[2i8; 31], 32, &mut []));
    assert!(!matmul_i32(&[], &a, 32, &mut []));
    assert!(!super::super::avx2::matmul_i32(&a, &[2i8; 15], 16, &mut []));
    assert!(!super::super::avx2::matmul_i32(&[], &a, 16, &mut []));
}
