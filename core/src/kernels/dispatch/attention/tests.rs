use super::*;
use crate::fixed::Requant;
use crate::testutil::{requant_of, Rng};

fn exp(x: f64) -> f64 {
    // exp for tests without std: (1 + x/2^20)^(2^20) by squaring.
    let mut r = 1.0 + x / 1048576.0;
    for _ in 0..20 {
        r *= r;
    }
    r
}

/// Float attention on the dequantised codes.
fn reference(q: &[i8], keys: &[i8], values: &[i8], score_scale: f64, out: &mut [f64; HEAD_DIM]) {
    let n = keys.len() / HEAD_DIM;
    let mut s = [0f64; 64];
    for j in 0..n {
        s[j] = dot(q, &keys[j * HEAD_DIM..(j + 1) * HEAD_DIM]) as f64 * score_scale;
    }
    let max = s[..n].iter().cloned().fold(f64::MIN, f64::max);
    let w: [f64; 64] = core::array::from_fn(|j| if j < n { exp(s[j] - max) } else { 0.0 });
    let total: f64 = w.iter().sum();
    for d in 0..HEAD_DIM {
        out[d] = (0..n).map(|j| w[j] * values[j * HEAD_DIM + d] as f64).sum::<f64>() / total;
    }
}

#[test]
fn normalise_takes_the_lanes_for_real_averages_and_matches_the_specification() {
    let mut rng = Rng::new(81);
    let edges = [
        2u32,
        3,
        255,
        256,
        (1 << 17) - 1,
        1 << 17,
        (1 << 17) + 1,
        255 * 960,
        u32::MAX,
    ];
    let mut in_lanes = 0;
    for trial in 0..6000 {
        let total = match trial % 3 {
            0 => edges[trial / 3 % edges.len()],
            1 => rng.range(255, 255 * 960) as u32,
            _ => rng.range(2, 1 << 31) as u32,
        };
        let shift = rng.range(33, 62) as u32;
        let mult = rng.range(i32::MIN as i64, i32::MAX as i64) as i32;
        let p = AttentionQ {
            to_log2_q8: Requant { mult: 1, shift: 1 },
            out: Requant { mult, shift },
        };
        // An average of int8 values under weights summing to `total`: |a| <= 128 total.
        let bound = (128 * total as i64).min(i32::MAX as i64);
        let acc: [i32; HEAD_DIM] = core::array::from_fn(|d| match d {
            0 => bound as i32,
            1 => -(bound as i32),
            _ => rng.range(-bound, bound + 1) as i32,
        });
        let recip = reciprocal(total);
        let (mut lanes, mut want) = ([0i8; HEAD_DIM], [0i8; HEAD_DIM]);
        normalise_reference(&acc, recip, &p, &mut want);
        if normalise_in_lanes(&acc, recip, &p, &mut lanes) {
            in_lanes += 1;
            assert_eq!(lanes, want, "total {total} mult {mult} shift {shift}");
        } else {
            // Only where 128 total no longer fits beside the reciprocal (totals from 2^24).
            assert!(total >= 1 << 24, "declined total {total} shift {shift}");
        }
        let mut fast = [0i8; HEAD_DIM];
        normalise(&acc, total, &p, &mut fast);
        assert_eq!(fast, want, "total {total} mult {mult} shift {shift}");
    }
    assert!(in_lanes > 4000, "{in_lanes} of 6000 in lanes");
}

#[test]
fn normalise_equals_its_saturating_formula() {
    let mut rng = Rng::new(8);
    let extremes = [i32::MIN, i32::MIN + 1, -1, 0, 1, i32::MAX, 1 << 25, -(1 << 25)];
    for trial in 0..4000 {
        let total = match trial % 4 {
            0 => rng.range(1, 300) as u32,
            1 => rng.range(255, 1 << 20) as u32,
            2 => rng.range(1, u32::MAX as i64) as u32,
            _ => [1, 2, 255, u32::MAX][trial / 4 % 4],
        };
        let shift = if trial % 7 == 0 {
            rng.range(0, 64) as u32
        } else {
            rng.range(20, 62) as u32
        };
        let mult = if trial % 5 == 0 {
            [i32::MIN, i32::MAX, 1, -1][trial / 5 % 4]
        } else {
            rng.range(i32::MIN as i64, i32::MAX as i64) as i32
        };
        let p = AttentionQ {
            to_log2_q8: Requant { mult: 1, shift: 1 },
            out: Requant { mult, shift },
        };
        let acc: [i32; HEAD_DIM] = core::array::from_fn(|d| {
            if d < extremes.len() {
                extremes[d]
            } else {
                rng.range(-(1 << 26), 1 << 26) as i32
            }
        });
        let (mut fast, mut want) = ([0i8; HEAD_DIM], [0i8; HEAD_DIM]);
        normalise(&acc, total, &p, &mut fast);
        let recip = ((1u64 << 31) + total as u64 / 2) / total as u64;
        normalise_reference(&acc, recip, &p, &mut want);
        assert_eq!(fast, want, "total {total} mult {mult} shift {shift}");
    }
}

#[test]
fn matches_float_softmax_attention() {
    let mut rng = Rng::new(21);
    const N: usize = 64;
    let mut keys = [0i8; N * HEAD_DIM];
    let mut values = [0i8; N * HEAD_DIM];
    let mut q = [0i8; HEAD_DIM];
    for score_scale in [1e-4, 1e-3, 4e-3] {
        rng.fill_i8(&mut keys);
        rng.fill_i8(&mut values);
        rng.fill_i8(&mut q);
        // gap * score_scale * log2(e) * 256 as mult / 2^shift.
        let p = AttentionQ {
            to_log2_q8: requant_of(score_scale * core::f64::consts::LOG2_E * 256.0),
            out: Requant {
                mult: 1 << 30,
                shift: 31 + AVG_FRAC_BITS - 1,
            },
        };
        let mut scores = [0i32; N];
        let mut weights = [0u8; N];
        let mut out = [0i8; HEAD_DIM];
        attend(&q, &keys, &values, &p, &mut scores, &mut weights, &mut out);
        let mut want = [0f64; HEAD_DIM];
        reference(&q, &keys, &values, score_scale, &mut want);
        for d in 0..HEAD_DIM {
            // 8-bit weights: a fraction of an output code on average, at most ~1.5.
            assert!(
                (out[d] as f64 - want[d]).abs() <= 1.5,
                "scale {score_scale} d {d}: {} vs {}",
                out[d],
                want[d]
            );
        }
    }
}

#[test]
fn block_is_bit_identical_to_single_queries() {
    let mut rng = Rng::new(5);
    const N: usize = 37;
    let mut keys = [0i8; N * HEAD_DIM];
    let mut values = [0i8; N * HEAD_DIM];
    let mut queries = [[0i8; HEAD_DIM]; QUERY_BLOCK];
    for score_scale in [1e-4, 2e-3, 3e-2, 300.0] {
        rng.fill_i8(&mut keys);
        rng.fill_i8(&mut values);
        queries.iter_mut().for_each(|q| rng.fill_i8(q));
        let p = AttentionQ {
            to_log2_q8: requant_of(score_scale * core::f64::consts::LOG2_E * 256.0),
            out: requant_of(1.0 / 65536.0),
        };
        let (mut scores, mut weights) = ([0i32; QUERY_BLOCK * N], [0u8; QUERY_BLOCK * N]);
        let mut out = [[0i8; HEAD_DIM]; QUERY_BLOCK];
        let values_t: [i8; N * HEAD_DIM] = core::array::from_fn(|i| values[(i % N) * HEAD_DIM + i / N]);
        let sums = value_sums(&values_t, N);
        attend_block(
            &queries,
            &keys,
            &values_t,
            &sums,
            &p,
            &mut scores,
            &mut weights,
            &mut out,
        );
        for (q, got) in queries.iter().zip(&out) {
            let mut want = [0i8; HEAD_DIM];
            attend(q, &keys, &values, &p, &mut scores[..N], &mut weights[..N], &mut want);
            assert_eq!(*got, want, "scale {score_scale}");
        }
    }
}

#[test]
fn every_softmax_path_equals_the_specification() {
    let mut rng = Rng::new(29);
    for (case, n) in [1usize, 3, 4, 5, 17, 64, 960, 80, 127]
        .into_iter()
        .cycle()
        .take(36)
        .enumerate()
    {
        let spread = [6u32, 14, 20, 31][case % 4];
        let scores: [i32; 960] = core::array::from_fn(|_| match rng.next_u64() % 16 {
            0 => i32::MIN,
            1 => i32::MAX,
            r => ((rng.next_u64() as i64 % (1i64 << spread)) as i32).wrapping_mul(r as i32 % 2 * 2 - 1),
        });
        let scores = &scores[..n];
        let max = scores
            .iter()
            .fold(i32::MIN, |m, &v| m.max(v))
            .wrapping_sub((case % 3) as i32 * 77);
        let shift = 22 + (case as u32 * 5) % 41;
        let e = ExpQ32::new(Requant {
            mult: (rng.next_u64() >> 33) as i32,
            shift,
        })
        .expect("shift >= 22");
        let (mut want, mut by_table, mut fastest) = ([0u8; 960], [0u8; 960], [0u8; 960]);
        let sum = softmax_row(&e, max, scores, &mut want[..n]);
        assert_eq!(softmax_row_by_table(&e, max, scores, &mut by_table[..n]), sum, "{case}");
        assert_eq!(softmax_row_fastest(&e, max, scores, &mut fastest[..n]), sum, "{case}");
        assert_eq!(by_table, want, "{case}");
        assert_eq!(fastest, want, "{case}");
    }
}

#[test]
fn diffuse_attention_keeps_its_mass() {
    // 512 equal keys: every float weight is 1/512, far below an 8-bit probability step.
    const N: usize = 512;
    let keys = [0i8; N * HEAD_DIM];
    let values: [i8; N * HEAD_DIM] = core::array::from_fn(|i| if (i / HEAD_DIM).is_multiple_of(2) { 100 } else { 50 });
    let p = AttentionQ {
        to_log2_q8: Requant {
            mult: 1 << 30,
            shift: 31,
        },
        out: Requant {
            mult: 1 << 30,
            shift: 31 + AVG_FRAC_BITS - 1,
        },
    };
    let (mut scores, mut weights, mut out) = ([0i32; N], [0u8; N], [0i8; HEAD_DIM]);
    attend(&[3; HEAD_DIM], &keys, &values, &p, &mut scores, &mut weights, &mut out);
    assert_eq!(out, [75; HEAD_DIM]);
}

/// A block scorer of keys stored in some layout: `(queries, keys, n, scores)`.
type LayoutScores = fn(&[[i8; HEAD_DIM]; QUERY_BLOCK], &[i8], usize, &mut [i32]);

/// Keys stored in `layout` score as the rows do, by this core's kernel (`fast`) and by the
/// portable reading of the layout (`reference`), for `n` keys each (the last all -128, with a
/// query of -128: the largest products).
fn layout_scores_as_the_rows(
    layout: KeyLayout,
    seed: u64,
    sizes: &[usize],
    fast: LayoutScores,
    reference: LayoutScores,
) {
    let mut rng = Rng::new(seed);
    for &n in sizes {
        let mut keys = [0i8; 960 * HEAD_DIM];
        rng.fill_i8(&mut keys[..n * HEAD_DIM]);
        let mut queries = [[0i8; HEAD_DIM]; QUERY_BLOCK];
        queries.iter_mut().for_each(|q| rng.fill_i8(q));
        if n == 960 {
            keys.fill(-128);
            queries[0] = [-128; HEAD_DIM];
        }
        let mut stored = [0i8; 960 * HEAD_DIM];
        for (t, key) in keys[..n * HEAD_DIM].chunks_exact(HEAD_DIM).enumerate() {
            store_key(layout, key, &mut stored[..n * HEAD_DIM], t);
        }
        let mut want = [0i32; QUERY_BLOCK * 960];
        scores_block_reference(&queries, &keys[..n * HEAD_DIM], &mut want[..QUERY_BLOCK * n]);
        for (name, scorer) in [("fast", fast), ("reference", reference)] {
            let mut got = [i32::MIN; QUERY_BLOCK * 960];
            scorer(&queries, &stored[..n * HEAD_DIM], n, &mut got[..QUERY_BLOCK * n]);
            assert_eq!(
                got[..QUERY_BLOCK * n],
                want[..QUERY_BLOCK * n],
                "{layout:?} n={n} {name}"
            );
        }
    }
}

#[test]
fn transposed_keys_score_as_the_rows() {
    let sizes = [8, 16, 120, 960];
    layout_scores_as_the_rows(
        KeyLayout::Transposed,
        64,
        &sizes,
        scores_block_transposed,
        scores_block_transposed_reference,
    );
    // The rows layout stores the key as it is.
    let keys: [i8; HEAD_DIM] = core::array::from_fn(|i| i as i8 - 16);
    let mut rows = [0i8; 2 * HEAD_DIM];
    store_key(KeyLayout::Rows, &keys, &mut rows, 1);
    assert_eq!(rows[HEAD_DIM..], keys);
}

#[test]
fn paired_keys_score_as_the_rows() {
    layout_scores_as_the_rows(
        KeyLayout::Paired,
        65,
        &[16, 48, 960],
        scores_block_paired,
        scores_block_paired_reference,
    );
}

#[test]
fn empty_and_short_inputs_do_not_panic() {
    let p = AttentionQ {
        to_log2_q8: Requant { mult: 1, shift: 1 },
        out: Requant { mult: 1, shift: 1 },
    };
    let mut out = [7i8; HEAD_DIM];
    attend(&[1; HEAD_DIM], &[], &[], &p, &mut [], &mut [], &mut out);
    assert_eq!(out, [0; HEAD_DIM]);
    attend(&[1; 3], &[1; 100], &[1; 10], &p, &mut [0; 1], &mut [0; 0], &mut out);
    let mut block_out = [[7i8; HEAD_DIM]; QUERY_BLOCK];
    let queries = [[1i8; HEAD_DIM]; QUERY_BLOCK];
    attend_block(
        &queries,
        &[1; 100],
        &[1; 10],
        &[0; HEAD_DIM],
        &p,
        &mut [0; 3],
        &mut [0; 9],
        &mut block_out,
    );
    assert_eq!(block_out, [[0; HEAD_DIM]; QUERY_BLOCK]);
}
