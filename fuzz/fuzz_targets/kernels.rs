//! The integer kernels with arbitrary lengths and parameters: they compute fewer outputs for
//! lengths that do not fit, and never panic.
#![no_main]

use arbitrary::Arbitrary;
use bino_core::config::HEAD_DIM;
use bino_core::fixed::{isqrt_u64, round_shift, Requant};
use bino_core::kernels::dispatch::attention::{attend, attend_block, value_sums, AttentionQ, QUERY_BLOCK};
use bino_core::kernels::dispatch::epilogue::{requant_rows, ChannelRequant};
use bino_core::kernels::dispatch::layernorm::{layernorm_rows, LayerNormQ};
use bino_core::kernels::dispatch::matmul::{dot, matmul_i8};
use bino_core::kernels::exp::{exp_neg_u8, exp_neg_u8_u32, ExpQ32};
use bino_core::kernels::params::Uniform;
use libfuzzer_sys::fuzz_target;

#[derive(Debug, Arbitrary)]
struct Input {
    k: u16,
    lens: [u16; 4],
    codes: Vec<i8>,
    mult: i32,
    shift: u32,
    shifts: Vec<u8>,
    eps: i64,
    zero: i32,
    rel: i32,
    wide: i64,
}

fn codes(values: &[i8], len: usize) -> Vec<i8> {
    (0..len)
        .map(|i| values.get(i % values.len().max(1)).copied().unwrap_or(1))
        .collect()
}

fuzz_target!(|input: Input| {
    let [la, lw, lo, ln] = input.lens.map(|l| usize::from(l % 4096));
    let (a, w) = (codes(&input.codes, la), codes(&input.codes, lw));
    let mut out = vec![0i32; lo];
    matmul_i8(&a, &w, usize::from(input.k), &mut out);
    matmul_i8(&a, &w, usize::MAX, &mut out);
    let _ = dot(&a, &w);

    let rq = Requant {
        mult: input.mult,
        shift: input.shift,
    };
    let _ = rq.apply(input.mult);
    let _ = rq.apply_i64(input.wide);
    let _ = round_shift(input.wide, input.shift);
    let _ = isqrt_u64(input.wide as u64);
    let _ = exp_neg_u8(input.wide, rq);
    let _ = exp_neg_u8_u32(input.wide as u32, rq);
    if let Some(e) = ExpQ32::new(rq) {
        let _ = e.weight(input.wide as u32);
    }

    let p = AttentionQ {
        to_log2_q8: rq,
        out: rq,
    };
    let q = codes(&input.codes, HEAD_DIM);
    let (mut scores, mut weights) = (vec![0i32; ln], vec![0u8; lo]);
    let mut head_out = [0i8; HEAD_DIM];
    attend(&q, &a, &w, &p, &mut scores, &mut weights, &mut head_out);
    let queries = [[0i8; HEAD_DIM]; QUERY_BLOCK].map(|_| {
        let mut row = [0i8; HEAD_DIM];
        row.copy_from_slice(&q);
        row
    });
    let n = la / HEAD_DIM;
    let sums = value_sums(&w, n);
    let mut block_out = [[0i8; HEAD_DIM]; QUERY_BLOCK];
    attend_block(&queries, &a, &w, &sums, &p, &mut scores, &mut weights, &mut block_out);

    let dim = usize::from(input.k % 512);
    let norm = LayerNormQ {
        zero: &Uniform(input.zero),
        rel: &Uniform(input.rel),
        eps: input.eps,
        out: rq,
    };
    let mut normed = vec![0i8; lo];
    layernorm_rows(&a, dim, &norm, &mut normed);

    let bias = vec![input.zero; dim];
    let mult = vec![input.mult; dim];
    let shifts: Vec<u8> = (0..dim).map(|i| input.shifts.get(i).copied().unwrap_or(1)).collect();
    let channel = ChannelRequant {
        bias: bias.as_slice(),
        mult: mult.as_slice(),
        shift: &shifts,
    };
    let mut requantised = vec![0i8; ln];
    requant_rows(&out, &channel, &Uniform(input.zero), &mut requantised);
});
