//! Kernel test firmware: property tests of every assembly kernel of `bino_core::kernels::arch`
//! against its portable reference, on this core under QEMU (`scripts/firmware.sh` runs it on
//! both), bit for bit.
//!
//! Random inputs and shapes (1 to 8 rows, `k` from 1 to 512 including values that are not
//! multiples of 16, channel counts across the fused epilogue's 128-channel chunks), extreme
//! values (all -128, all 127, alternating), every rounding case of the requantisation
//! (`(acc + bias) / 2^s` at, below and above each half, both signs, at the saturation edges),
//! and parameters the kernels must decline; the softmax row of each core's fastest path against
//! the portable one. Also the sharpness-equalised refinement (portable code, no assembly) on a
//! half-defocused pair against the host's CRC (`src/equalise_case.rs`, baked in by `build.rs`):
//! the main firmware's band blurs no row. Prints `index / found / expected` on the first
//! mismatch of a case and exits non-zero if any case fails.
#![no_std]
#![no_main]

use bino_core::kernels::arch::{self, MAX_K};
use core::sync::atomic::{AtomicU32, Ordering};

use bino_core::kernels::dispatch::epilogue::{requant_rows, ChannelRequant};
use bino_core::kernels::dispatch::gemm::{matmul_requant_i8, matmul_requant_i8_prepared, matmul_requant_reference};
use bino_core::kernels::dispatch::matmul::{matmul_i8, matmul_i8_portable, matmul_i8_reference};
use bino_core::testutil::Rng;
use cortex_m as _;
use cortex_m_rt::entry;
use cortex_m_semihosting::debug::{exit, EXIT_FAILURE, EXIT_SUCCESS};
use defmt_semihosting as _;

#[path = "../equalise_case.rs"]
mod equalise_case;

/// The host's figures for `equalise_case`.
mod host {
    include!(concat!(env!("OUT_DIR"), "/equalised.rs"));
}

#[cfg(board = "an547")]
const BOARD: &str = "mps3-an547 (Cortex-M55)";
#[cfg(board = "an500")]
const BOARD: &str = "mps2-an500 (Cortex-M7)";

/// Largest shapes of the random cases.
const MAX_M: usize = 8;
const MAX_N: usize = 130;
/// Outputs of the largest case: the bench's 8 x 480.
const MAX_OUT: usize = MAX_M * 480;

/// Word-aligned buffers (the Cortex-M7 kernel takes word-aligned weights only).
#[repr(C, align(4))]
struct Aligned<T>(T);

/// The inputs' patterns on the project's one test PRNG ([`Rng`]: deterministic, so a failure
/// reproduces).
trait Fill {
    /// Random codes, or one of the extreme patterns.
    fn fill(&mut self, x: &mut [i8], pattern: u32);
}

impl Fill for Rng {
    fn fill(&mut self, x: &mut [i8], pattern: u32) {
        for (i, v) in x.iter_mut().enumerate() {
            *v = match pattern {
                0 => -128,
                1 => 127,
                2 => [-128, 127][i % 2],
                _ => self.next_u64() as i8,
            };
        }
    }
}

struct Tally {
    cases: usize,
    failed: usize,
    asm_cases: usize,
}

impl Tally {
    /// Compares `found` with `expected`; prints the first difference.
    fn check<T: PartialEq + Copy + defmt::Format>(
        &mut self,
        what: &str,
        shape: [usize; 3],
        found: &[T],
        expected: &[T],
    ) {
        self.cases += 1;
        if let Some(i) = found.iter().zip(expected).position(|(f, e)| f != e) {
            self.failed += 1;
            defmt::println!(
                "kernel-tests mismatch kernel={=str} m={=usize} n={=usize} k={=usize} index={=usize} found={} expected={}",
                what, shape[0], shape[1], shape[2], i, found[i], expected[i]
            );
        }
    }
}

/// Per-channel parameters of one fused case.
struct Params {
    bias: [i32; MAX_N],
    mult: [i32; MAX_N],
    shift: [u8; MAX_N],
    zero: [i32; MAX_N],
}

impl Params {
    /// Random parameters in the fused kernels' range, scaled so that outputs spread over the
    /// int8 range and past it (`log2_acc`: magnitude of typical accumulators).
    fn random(rng: &mut Rng, n: usize, log2_acc: i64) -> Params {
        let mut p = Params {
            bias: [0; MAX_N],
            mult: [0; MAX_N],
            shift: [40; MAX_N],
            zero: [0; MAX_N],
        };
        for c in 0..n {
            p.mult[c] = match rng.range(0, 9) {
                0 => i32::MIN,
                1 => i32::MAX,
                2 => -(rng.range(1 << 30, i32::MAX as i64) as i32),
                _ => rng.range(1 << 30, i32::MAX as i64) as i32,
            };
            p.shift[c] = (log2_acc + 31 - 7 + rng.range(-3, 3)).clamp(33, 62) as u8;
            p.bias[c] = match rng.range(0, 9) {
                0 => (1 << 30) - 1,
                1 => -(1 << 30) + 1,
                _ => rng.range(-(1 << log2_acc), 1 << log2_acc) as i32,
            };
            p.zero[c] = rng.range(-128, 127) as i32;
        }
        p
    }

    fn requant(&self, n: usize) -> ChannelRequant<'_, [i32], [i32]> {
        ChannelRequant {
            bias: &self.bias[..n],
            mult: &self.mult[..n],
            shift: &self.shift[..n],
        }
    }
}

/// Whether this core's kernels take `k` with word-aligned weights.
fn takes(k: usize) -> bool {
    let m7 = cfg!(board = "an500");
    (1..=MAX_K).contains(&k) && (!m7 || k.is_multiple_of(4))
}

/// The random cases' buffers (in `.bss`: too large for the stack).
struct Buffers {
    a: Aligned<[i8; MAX_M * MAX_K]>,
    w: Aligned<[i8; MAX_N * MAX_K]>,
    found: [i32; MAX_OUT],
    expected: [i32; MAX_OUT],
    found8: [i8; MAX_OUT],
    expected8: [i8; MAX_OUT],
    acc: [i32; MAX_OUT],
    weights: Aligned<[u8; MAX_OUT]>,
    /// The softmax bench's widened weights on Cortex-M7 (two words per four scores of a row,
    /// at a stride of eight words).
    widened: [u32; 2 * 960],
}

fn random_cases(t: &mut Tally, rng: &mut Rng, b: &mut Buffers) {
    let ks = [
        1, 3, 4, 8, 12, 16, 17, 20, 28, 32, 36, 60, 100, 127, 128, 132, 200, 480, 512, 960, 1024,
    ];
    for (case, &k) in ks.iter().cycle().take(3 * ks.len()).enumerate() {
        for m in [1, 2, 3, 4, 5, 8] {
            let n = [1, 2, 3, 4, 5, 7, 130][(case + m) % 7];
            let pattern = if case % 5 == 4 { (m % 3) as u32 } else { 3 };
            rng.fill(&mut b.a.0[..m * k], pattern);
            rng.fill(&mut b.w.0[..n * k], if pattern == 2 { 1 } else { pattern });
            let (a, w) = (&b.a.0[..m * k], &b.w.0[..n * k]);
            let shape = [m, n, k];

            // The i32 kernel against the reference.
            let (found, expected) = (&mut b.found, &mut b.expected);
            matmul_i8_reference(a, w, k, &mut expected[..m * n]);
            let took = arch::matmul_i32(a, w, k, &mut found[..m * n]);
            if took != takes(k) {
                defmt::println!(
                    "kernel-tests wrong-path kernel=matmul_i32 k={=usize} took={=bool}",
                    k,
                    took
                );
                t.failed += 1;
            }
            t.asm_cases += usize::from(took);
            if took {
                t.check("matmul_i32", shape, &found[..m * n], &expected[..m * n]);
            }
            matmul_i8(a, w, k, &mut found[..m * n]);
            t.check("matmul_i8", shape, &found[..m * n], &expected[..m * n]);

            // The fused kernel against the reference.
            let log2_acc = (64 - ((k as u64) << 14).leading_zeros() as i64) / 2 + 7;
            let p = Params::random(rng, n, log2_acc);
            let rq = p.requant(n);
            let (found, expected) = (&mut b.found8, &mut b.expected8);
            matmul_requant_reference(a, w, k, &rq, &p.zero[..n], &mut expected[..m * n]);
            let took = arch::matmul_requant(a, w, k, &rq, &p.zero[..n], &mut found[..m * n]);
            if took != takes(k) {
                defmt::println!(
                    "kernel-tests wrong-path kernel=matmul_requant k={=usize} took={=bool}",
                    k,
                    took
                );
                t.failed += 1;
            }
            t.asm_cases += usize::from(took);
            if took {
                t.check("matmul_requant", shape, &found[..m * n], &expected[..m * n]);
            }
            matmul_requant_i8(a, w, k, &rq, &p.zero[..n], &mut b.acc, &mut found[..m * n]);
            t.check("matmul_requant_i8", shape, &found[..m * n], &expected[..m * n]);

            // The same columns prepared once (the engine's values and MLP-up GEMMs).
            let mut storage = [0i32; 4 * MAX_N];
            if let Some(prepared) = arch::PreparedRequant::new(&rq, &p.zero[..n], &mut storage) {
                let took = arch::matmul_requant_prepared(a, w, k, &prepared, &mut b.acc, &mut found[..m * n]);
                if took != takes(k) {
                    defmt::println!(
                        "kernel-tests wrong-path kernel=matmul_requant_prepared k={=usize} took={=bool}",
                        k,
                        took
                    );
                    t.failed += 1;
                }
                t.asm_cases += usize::from(took);
                if took {
                    t.check("matmul_requant_prepared", shape, &found[..m * n], &expected[..m * n]);
                }
            }
        }
    }
}

/// Every rounding case: one channel, `k = 4` (`a = [v, 0, 0, 0]`, `w = [1, 0, 0, 0]`), so
/// `acc = v` for every code `v`; multipliers that make `(v + bias) * mult / 2^shift` land on,
/// just below and just above each half, both signs, and biases that push results across
/// the saturation edges.
fn rounding_cases(t: &mut Tally) {
    const M: usize = 256;
    let mut a = Aligned([0i8; M * 4]);
    for (v, row) in a.0.chunks_exact_mut(4).enumerate() {
        row[0] = (v as i32 - 128) as i8;
    }
    let w = Aligned([1i8, 0, 0, 0]);
    let mut found = [0i8; M];
    let mut expected = [0i8; M];
    for shift in [33u8, 34, 35, 36, 40, 47, 55, 62] {
        // mult / 2^(shift - 32) = 2^-s * {1/2, 1 - 2^-31 (just below 1), 3/4, -1/2}.
        for mult in [1 << 30, i32::MAX, 3 << 29, -(1 << 30), i32::MIN] {
            for bias in [0, 1, -1, 255, -255, 1 << 20, -(1 << 20), (1 << 30) - 1, -(1 << 30) + 1] {
                for zero in [0, 5, -7, 127, -128] {
                    let bias_a = [bias];
                    let mult_a = [mult];
                    let rq = ChannelRequant {
                        bias: &bias_a[..],
                        mult: &mult_a[..],
                        shift: &[shift][..],
                    };
                    let z = [zero];
                    matmul_requant_reference(&a.0, &w.0, 4, &rq, &z[..], &mut expected);
                    let took = arch::matmul_requant(&a.0, &w.0, 4, &rq, &z[..], &mut found);
                    let in_range = (1i64 << (shift - 33)) + ((zero as i64) << (shift - 32));
                    let should = in_range.abs() < 1 << 30;
                    if took != should {
                        defmt::println!(
                            "kernel-tests wrong-path kernel=matmul_requant shift={=u8} zero={=i32} took={=bool}",
                            shift,
                            zero,
                            took
                        );
                        t.failed += 1;
                    }
                    t.asm_cases += usize::from(took);
                    if took {
                        t.check("matmul_requant/rounding", [M, 1, 4], &found, &expected);
                    }
                }
            }
        }
    }
    // Parameters outside the kernels' range: they decline, the public function still agrees.
    for (bias, shift) in [(1 << 30, 40u8), (0, 32), (0, 20), (-(1 << 30), 40)] {
        let (bias_a, mult_a) = ([bias], [1 << 30]);
        let rq = ChannelRequant {
            bias: &bias_a[..],
            mult: &mult_a[..],
            shift: &[shift][..],
        };
        if arch::matmul_requant(&a.0, &w.0, 4, &rq, &[0][..], &mut found) {
            defmt::println!(
                "kernel-tests wrong-path kernel=matmul_requant shift={=u8} took=true",
                shift
            );
            t.failed += 1;
        }
        matmul_requant_reference(&a.0, &w.0, 4, &rq, &[0][..], &mut expected);
        let mut acc = [0i32; M];
        matmul_requant_i8(&a.0, &w.0, 4, &rq, &[0][..], &mut acc, &mut found);
        t.check("matmul_requant_i8/declined", [M, 1, 4], &found, &expected);
    }
}

/// The attention kernel of the engine (four queries at once: scores and weighted sums through
/// the GEMM tiles on Cortex-M7) against the single-query reference `attend`, bit for bit.
fn attention_cases(t: &mut Tally, rng: &mut Rng, b: &mut Buffers) {
    use bino_core::config::HEAD_DIM;
    use bino_core::fixed::Requant;
    use bino_core::kernels::dispatch::attention::{attend, attend_block, value_sums, AttentionQ, QUERY_BLOCK};
    for (case, n) in [5usize, 36, 200, 960, 960].into_iter().enumerate() {
        let (keys, rest) = b.w.0.split_at_mut(n * HEAD_DIM);
        let (values, rest) = rest.split_at_mut(n * HEAD_DIM);
        let values_t = &mut rest[..n * HEAD_DIM];
        rng.fill(keys, if case == 4 { 0 } else { 3 });
        rng.fill(values, 3);
        for (i, v) in values_t.iter_mut().enumerate() {
            *v = values[(i % n) * HEAD_DIM + i / n];
        }
        let mut queries = [[0i8; HEAD_DIM]; QUERY_BLOCK];
        for q in queries.iter_mut() {
            rng.fill(q, 3);
        }
        let sums = value_sums(values_t, n);
        for shift in [33u32, 34, 35, 36, 37, 40, 46] {
            let p = AttentionQ {
                to_log2_q8: Requant { mult: 1 << 30, shift },
                out: Requant {
                    mult: 1 << 30,
                    shift: 46,
                },
            };
            let mut out = [[0i8; HEAD_DIM]; QUERY_BLOCK];
            let (scores, weights) = (&mut b.found[..QUERY_BLOCK * n], &mut b.weights.0[..QUERY_BLOCK * n]);
            attend_block(&queries, keys, values_t, &sums, &p, scores, weights, &mut out);
            for (q, got) in queries.iter().zip(&out) {
                let mut want = [0i8; HEAD_DIM];
                attend(q, keys, values, &p, &mut scores[..n], &mut weights[..n], &mut want);
                t.check("attend_block", [QUERY_BLOCK, HEAD_DIM, n], got, &want);
            }
        }
    }
}

/// Attention scores of four queries on this core's fastest path (`scores_block`: the GEMM tile
/// on Cortex-M7, the Helium score kernel on Cortex-M55) against the portable
/// `scores_block_reference`: 1 to 960 keys, random and extreme codes.
fn scores_cases(t: &mut Tally, rng: &mut Rng, b: &mut Buffers) {
    use bino_core::config::HEAD_DIM;
    use bino_core::kernels::dispatch::attention::{scores_block, scores_block_reference, QUERY_BLOCK};
    let lens = [1usize, 2, 3, 5, 16, 37, 200, 960];
    for (case, &n) in lens.iter().cycle().take(4 * lens.len()).enumerate() {
        let pattern = [3u32, 0, 1, 2][case / lens.len()];
        let keys = &mut b.w.0[..n * HEAD_DIM];
        rng.fill(keys, pattern);
        let mut queries = [[0i8; HEAD_DIM]; QUERY_BLOCK];
        for q in queries.iter_mut() {
            rng.fill(q, if case % 2 == 0 { pattern } else { 3 });
        }
        let (found, expected) = (&mut b.found[..QUERY_BLOCK * n], &mut b.expected[..QUERY_BLOCK * n]);
        scores_block(&queries, keys, n, found);
        scores_block_reference(&queries, keys, expected);
        t.check("scores_block", [QUERY_BLOCK, n, HEAD_DIM], found, expected);
        t.asm_cases += 1;
    }
}

/// A LayerNorm of random per-channel formats, quantiser-like or at the narrow path's limits.
struct LayerNormCase {
    zero: [i32; 256],
    rel: [i32; 256],
}

impl LayerNormCase {
    fn random(rng: &mut Rng, case: usize) -> LayerNormCase {
        let rel_max = [4i64, 300, 6_000, 30_000, 1 << 15, 1 << 20][case % 6];
        let zero_max = if case % 6 == 5 { 1 << 20 } else { 600 };
        let mut c = LayerNormCase {
            zero: [0; 256],
            rel: [0; 256],
        };
        for (i, (z, r)) in c.zero.iter_mut().zip(c.rel.iter_mut()).enumerate() {
            *z = rng.range(-zero_max, zero_max) as i32;
            let m = rng.range(1, rel_max) as i32;
            *r = if case % 3 == 1 && i % 4 == 0 { -m } else { m };
        }
        c
    }

    fn params(
        &self,
        eps: i64,
        mult: i32,
        shift: u32,
    ) -> bino_core::kernels::dispatch::layernorm::LayerNormQ<'_, [i32], [i32]> {
        bino_core::kernels::dispatch::layernorm::LayerNormQ {
            zero: &self.zero[..],
            rel: &self.rel[..],
            eps,
            out: bino_core::fixed::Requant { mult, shift },
        }
    }
}

/// LayerNorm rows on this core's fastest path (`layernorm_rows`: Helium lane loops on
/// Cortex-M55 for 128-channel rows, the narrow scalar rows elsewhere) against the saturating
/// reference `layernorm_rows_reference`: widths 128 (and 64, 96, 256, which other paths take),
/// constant and alternating rows, formats across every shift class of the row and past the
/// narrow path's limits, output shifts on both sides of 33.
fn layernorm_cases(t: &mut Tally, rng: &mut Rng, b: &mut Buffers) {
    use bino_core::kernels::dispatch::layernorm::{layernorm_rows, layernorm_rows_reference};
    const ROWS: usize = 4;
    for case in 0..72 {
        let dim = [128usize, 128, 128, 64, 96, 256][case % 6];
        let formats = LayerNormCase::random(rng, case / 6);
        let eps = if case % 4 == 0 { 0 } else { rng.range(0, 1 << 40) };
        let mult = match case % 5 {
            0 => i32::MAX,
            1 => -(rng.range(1 << 30, i32::MAX as i64) as i32),
            _ => rng.range(1 << 30, i32::MAX as i64) as i32,
        };
        let shift = [40u32, 33, 32, 45, 62, 20][(case + case / 6) % 6];
        let p = formats.params(eps, mult, shift);
        let x = &mut b.a.0[..ROWS * dim];
        rng.fill(x, 3);
        match case % 7 {
            0 => x[..dim].fill(-128),
            1 => x[..dim]
                .iter_mut()
                .enumerate()
                .for_each(|(c, v)| *v = [-128, 127][c % 2]),
            2 => x[..dim].fill(5),
            _ => {}
        }
        let (found, expected) = (&mut b.found8[..ROWS * dim], &mut b.expected8[..ROWS * dim]);
        layernorm_rows(x, dim, &p, found);
        layernorm_rows_reference(x, dim, &p, expected);
        t.check("layernorm_rows", [ROWS, dim, 0], found, expected);
        if cfg!(board = "an547") && dim == 128 {
            t.asm_cases += 1;
        }
    }
}

/// Per-channel parameters of a residual add: the carry's and the delta's.
struct ResidualCase {
    cmult: [i32; 130],
    cshift: [u8; 130],
    czero: [i32; 130],
    mult: [i32; 130],
    shift: [u8; 130],
    bias: [i32; 130],
    zero: [i32; 130],
}

impl ResidualCase {
    /// Delta shifts in `lo..=62` (from 33 the Helium lanes take a chunk), carry shifts from
    /// 18 or `lo` (the lanes take 18 to 62), large new zero points on request.
    fn random(rng: &mut Rng, lo: i64, wide_zero: bool) -> ResidualCase {
        let mut c = ResidualCase {
            cmult: [0; 130],
            cshift: [40; 130],
            czero: [0; 130],
            mult: [0; 130],
            shift: [40; 130],
            bias: [0; 130],
            zero: [0; 130],
        };
        for i in 0..130 {
            c.cmult[i] = rng.range(-(i32::MAX as i64), i32::MAX as i64) as i32;
            c.mult[i] = rng.range(-(i32::MAX as i64), i32::MAX as i64) as i32;
            // The carry's shifts from 18 (a format change near 1 has a shift near 31).
            c.cshift[i] = rng.range(lo.min(18), 62) as u8;
            c.shift[i] = rng.range(lo, 62) as u8;
            c.czero[i] = rng.range(-(1 << 15), 1 << 15) as i32;
            c.bias[i] = rng.range(-(1 << 30) + 1, (1 << 30) - 1) as i32;
            c.zero[i] = if wide_zero {
                rng.range(-(1 << 29) + 1, (1 << 29) - 1) as i32
            } else {
                rng.range(-128, 127) as i32
            };
        }
        c
    }

    fn run(&self, n: usize, x: &mut [i8], acc: &[i32], reference: bool) {
        use bino_core::kernels::dispatch::epilogue::{
            residual_add, residual_add_reference, ChannelRequant, ChannelRescale,
        };
        let carry = ChannelRescale {
            zero: &self.czero[..n],
            mult: &self.cmult[..n],
            shift: &self.cshift[..n],
        };
        let delta = ChannelRequant {
            bias: &self.bias[..n],
            mult: &self.mult[..n],
            shift: &self.shift[..n],
        };
        if reference {
            residual_add_reference(x, &carry, acc, &delta, &self.zero[..n]);
        } else {
            residual_add(x, &carry, acc, &delta, &self.zero[..n]);
        }
    }
}

/// The residual add on this core's fastest path (`residual_add`: Helium lanes per chunk on
/// Cortex-M55 where both shifts are at least 33, the decoded scalar chunks elsewhere) against
/// the saturating `residual_add_reference`: 1 to 130 channels (chunks of 64 and tails of every
/// length mod 4), accumulators up to and past 2^30, shifts on both sides of 33.
/// The rotary embedding in 32-bit lanes (`RopeLanes::token`: its requantisation pass is a
/// Helium kernel on the Cortex-M55) against the 64-bit `rope_token`, on one token of `DIM`
/// channels: shifts 32 to 62 (32 takes the lanes' extra left shift), biases and accumulators up
/// to the lanes' 2^29 bound, clamped pre-rotation values, any cosine and sine.
fn rope_cases(t: &mut Tally, rng: &mut Rng) {
    use bino_core::config::DIM;
    use bino_core::kernels::dispatch::rope::{rope_token, Angles, RopeLanes};
    let mut taken = 0;
    for case in 0..40 {
        let bias: [i32; DIM] = core::array::from_fn(|_| rng.range(-(1 << 29) + 1, (1 << 29) - 1) as i32);
        let mult: [i32; DIM] = core::array::from_fn(|_| match case % 3 {
            0 => rng.range(1 << 30, i32::MAX as i64) as i32,
            _ => rng.range(i32::MIN as i64 + 1, i32::MAX as i64) as i32,
        });
        // Shifts of 32 (a left shift first) in some channels, in all, in none, or anywhere.
        let shift: [u8; DIM] = core::array::from_fn(|c| match (case % 4, c % 7) {
            (0, 0) => 32,
            (1, _) => 32,
            (2, _) => rng.range(33, 62) as u8,
            _ => rng.range(32, 62) as u8,
        });
        let rq = ChannelRequant {
            bias: &bias,
            mult: &mult,
            shift: &shift,
        };
        let acc: [i32; DIM] = core::array::from_fn(|c| match (case % 5, c % 11) {
            (0, 0) => (1 << 29) - 1,
            (0, 1) => -(1 << 29) + 1,
            (2, 0) => -(1 << 29),
            (1, _) => rng.range(-(1 << 29) + 1, (1 << 29) - 1) as i32,
            _ => rng.range(-(1 << 20), 1 << 20) as i32,
        });
        let angles = |rng: &mut Rng| Angles {
            cos: core::array::from_fn(|_| rng.next_u64() as i16),
            sin: core::array::from_fn(|_| rng.next_u64() as i16),
        };
        let (row, col) = (angles(rng), angles(rng));
        let (mut found, mut want) = ([0i8; DIM], [0i8; DIM]);
        rope_token(&acc, &rq, &row, &col, &mut want);
        let Some(mut lanes) = RopeLanes::new(&rq) else { continue };
        if lanes.token(&acc, &row, &col, &mut found) {
            taken += 1;
            t.check("rope_token", [1, DIM, 0], &found, &want);
        }
    }
    if taken > 0 && cfg!(any(board = "an547", board = "an500")) {
        t.asm_cases += taken;
    }
}

/// The head's hidden-convolution epilogue (`ConvEpilogue::apply`: a Helium kernel on the
/// Cortex-M55 for cells with a carry) against its 64-bit formula, on 12 cells of
/// `HEAD_HIDDEN` channels: shifts 33 to 61, biases and accumulators up to the 2^30 bound,
/// carry shifts 18 to 61 (both of the carry's left shifts), any multipliers and zero points.
fn conv_epilogue_cases(t: &mut Tally, rng: &mut Rng) {
    use bino_core::config::HEAD_HIDDEN;
    use bino_core::fixed::{sat_i8_i64, Requant};
    use bino_core::model::head::ConvEpilogue;
    const N: usize = 12 * HEAD_HIDDEN;
    let mut taken = 0;
    for case in 0..40 {
        let bias: [i32; HEAD_HIDDEN] = core::array::from_fn(|_| rng.range(-(1 << 30) + 1, (1 << 30) - 1) as i32);
        let mult: [i32; HEAD_HIDDEN] = core::array::from_fn(|_| rng.range(-(i32::MAX as i64), i32::MAX as i64) as i32);
        let shift: [u8; HEAD_HIDDEN] = core::array::from_fn(|_| rng.range(33, 61) as u8);
        let rq = ChannelRequant {
            bias: &bias,
            mult: &mult,
            shift: &shift,
        };
        let carry = Requant {
            mult: rng.range(-(i32::MAX as i64), i32::MAX as i64) as i32,
            shift: match case % 5 {
                4 => rng.range(18, 61) as u32,
                edge => [18, 47, 48, 61][edge],
            },
        };
        let zero = rng.range(-(1 << 15) + 1, (1 << 15) - 1) as i32;
        let next_zero = rng.range(-(1 << 29) + 1, (1 << 29) - 1) as i32;
        let acc: [i32; N] = core::array::from_fn(|i| match (case % 3, i % 13) {
            (0, 0) => (1 << 30) - 1,
            (0, 1) => -(1 << 30) + 1,
            (1, _) => rng.range(-(1 << 30) + 1, (1 << 30) - 1) as i32,
            _ => rng.range(-(1 << 23), 1 << 23) as i32,
        });
        let mut center = [0i8; N];
        rng.fill(&mut center, (case % 4) as u32);
        // Every seventh case as the stem layer: no carry, no input codes.
        let stem = case % 7 == 6;
        let mut want = [0i8; N];
        for (i, (o, &a)) in want.iter_mut().zip(&acc).enumerate() {
            let relu = rq.apply(i % HEAD_HIDDEN, a).max(0);
            let carried = if stem {
                0
            } else {
                carry.apply_i64(center[i] as i64 - zero as i64)
            };
            *o = sat_i8_i64(carried + relu + next_zero as i64);
        }
        let Some(e) = ConvEpilogue::new(&rq, (!stem).then_some(carry), zero, next_zero) else {
            continue;
        };
        let mut found = [0i8; N];
        if e.apply(&acc, (!stem).then_some(&center[..]), &mut found) {
            taken += 1;
            t.check("conv_epilogue", [12, HEAD_HIDDEN, 0], &found, &want);
        }
    }
    if taken > 0 && cfg!(any(board = "an547", board = "an500")) {
        t.asm_cases += taken;
    }
}

fn residual_cases(t: &mut Tally, rng: &mut Rng, b: &mut Buffers) {
    const ROWS: usize = 8;
    for case in 0..40 {
        let n = [128usize, 128, 1, 3, 5, 64, 66, 130][case % 8];
        let params = ResidualCase::random(rng, if case % 5 == 4 { 20 } else { 33 }, case % 7 == 6);
        let acc = &mut b.acc[..ROWS * n];
        for a in acc.iter_mut() {
            *a = match case % 4 {
                0 => rng.range(-(1 << 30) + 1, (1 << 30) - 1) as i32,
                1 => rng.next_u64() as i32,
                _ => rng.range(-(1 << 22), 1 << 22) as i32,
            };
        }
        let x = &mut b.found8[..ROWS * n];
        rng.fill(x, 3);
        let want = &mut b.expected8[..ROWS * n];
        want.copy_from_slice(x);
        params.run(n, x, acc, false);
        params.run(n, want, acc, true);
        t.check("residual_add", [ROWS, n, 0], x, want);
        if cfg!(board = "an547") {
            t.asm_cases += 1;
        }
    }
}

/// A row's maximum, as the engine takes it before its softmax.
fn row_max(scores: &[i32]) -> i32 {
    scores.iter().fold(i32::MIN, |m, &v| m.max(v))
}

/// The engine's row maximum (`attention::row_max`: the Cortex-M7's assembly loop on lengths
/// that are a multiple of 4) against the fold, on the softmax cases' rows.
fn row_max_case(t: &mut Tally, scores: &[i32]) {
    let found = bino_core::kernels::dispatch::attention::row_max(scores);
    t.check("row_max", [1, scores.len(), 0], &[found], &[row_max(scores)]);
    if (cfg!(board = "an500") && scores.len().is_multiple_of(4))
        || (cfg!(board = "an547") && scores.len().is_multiple_of(16))
    {
        t.asm_cases += 1;
    }
}

/// The values' channel-major scatter (`arch::scatter_channels`, Cortex-M55) against its
/// definition over the whole store: channel counts of 8 to 128 and some it declines, token
/// counts up to the 16-bit offsets' limit and one past it, the first, a middle and the last
/// token; every byte the scatter must not write keeps its value.
fn scatter_cases(t: &mut Tally, rng: &mut Rng, b: &mut Buffers) {
    let cases = [
        (128usize, 960usize),
        (128, 8),
        (8, 1),
        (8, 9362),
        (24, 100),
        (12, 40),
        (8, 9363),
    ];
    let pattern = |pos: usize| (pos.wrapping_mul(31) ^ (pos >> 7)) as i8;
    for (n, tokens) in cases {
        for at in [0, tokens / 2, tokens - 1] {
            rng.fill(&mut b.a.0[..n], 3);
            let token = &b.a.0[..n];
            let store = &mut b.w.0[..n * tokens];
            for (pos, v) in store.iter_mut().enumerate() {
                *v = pattern(pos);
            }
            let took = bino_core::kernels::arch::scatter_channels(token, store, tokens, at);
            let takes = cfg!(board = "an547") && n % 8 == 0 && 7 * tokens <= u16::MAX as usize;
            if took != takes {
                defmt::println!(
                    "kernel-tests wrong-path kernel=scatter_channels n={=usize} tokens={=usize} took={=bool}",
                    n,
                    tokens,
                    took
                );
                t.failed += 1;
            }
            if !took {
                continue;
            }
            t.asm_cases += 1;
            let wrong = store.iter().enumerate().position(|(pos, &v)| {
                let want = if pos % tokens == at {
                    token[pos / tokens]
                } else {
                    pattern(pos)
                };
                v != want
            });
            let (found, expected) = match wrong {
                Some(pos) => (
                    store[pos],
                    if pos % tokens == at {
                        token[pos / tokens]
                    } else {
                        pattern(pos)
                    },
                ),
                None => (0, 0),
            };
            t.check("scatter_channels", [1, n, tokens], &[found], &[expected]);
        }
    }
}

/// The softmax row on this core's fastest path (`softmax_row_fastest`: the Helium assembly on
/// Cortex-M55, the DSP row or the byte table on Cortex-M7) against the portable `softmax_row`,
/// bit for bit:
/// rows of 1 to 960 scores (every tail length of a 4-lane step), spreads from a few codes to
/// 2^31, the extreme scores (gaps that wrap, or pass the 2^20 clamp), a maximum below the
/// row's own (negative gaps), and the shifts and multipliers an attention can hold.
fn softmax_cases(t: &mut Tally, rng: &mut Rng, b: &mut Buffers) {
    use bino_core::fixed::Requant;
    use bino_core::kernels::dispatch::attention::{softmax_row, softmax_row_fastest};
    use bino_core::kernels::exp::ExpQ32;
    let lens = [1usize, 2, 3, 4, 5, 6, 7, 8, 9, 15, 16, 17, 33, 100, 255, 960];
    for (case, &n) in lens.iter().cycle().take(3 * lens.len()).enumerate() {
        let spread = [4, 10, 16, 21, 31][case % 5];
        let extremes = case % 3 == 0;
        let scores = &mut b.found[..n];
        for s in scores.iter_mut() {
            *s = match rng.range(0, 15) {
                0 if extremes => i32::MIN,
                1 if extremes => i32::MAX,
                _ => rng.range(-(1 << spread), 1 << spread) as i32,
            };
        }
        row_max_case(t, scores);
        let max = match case % 4 {
            3 => row_max(scores).wrapping_sub(rng.range(1, 1 << 12) as i32),
            _ => row_max(scores),
        };
        let shift = [22u32, 30, 33, 34, 40, 46, 62][case % 7];
        let mult = match case % 4 {
            0 => 1 << 30,
            1 => i32::MAX,
            2 => rng.range(0, 1 << 16) as i32,
            _ => rng.range(1, i32::MAX as i64) as i32,
        };
        let Some(e) = ExpQ32::new(Requant { mult, shift }) else {
            defmt::println!("kernel-tests mismatch kernel=softmax shift={=u32} rejected", shift);
            t.failed += 1;
            continue;
        };
        let (found, rest) = b.weights.0.split_at_mut(n);
        let expected = &mut rest[..n];
        let sum_found = softmax_row_fastest(&e, max, scores, found);
        let sum_expected = softmax_row(&e, max, scores, expected);
        t.check("softmax_row", [1, n, 0], found, expected);
        t.check("softmax_row/sum", [1, n, 0], &[sum_found], &[sum_expected]);
        // On the Cortex-M7 the assembly row takes the rows whose parameters allow its
        // shortcuts (`softmax_row_fastest` above ran it); the rest run the table loop.
        let mut probe = [0u8; 1];
        let assembly = cfg!(board = "an547")
            || (cfg!(board = "an500")
                && bino_core::kernels::arch::softmax_row(&e, max, &scores[..1], &mut probe).is_some());
        if assembly {
            t.asm_cases += 1;
        }
    }
}

/// Attention's softmax and weighted sums of four queries on this core's assembly path
/// (`arch::softmax_weighted_sums`: on Cortex-M7 the softmax written into the DSP tile's widened
/// rows) against the portable `softmax_row` of each row and the plain weighted sums: 128 to
/// 960 keys (8 keys: declined), spreads up to the extremes of i32 (gaps past 2^31, which the kernel saturates), each
/// right shift of the index it specialises and one it does not.
fn softmax_block_cases(t: &mut Tally, rng: &mut Rng, b: &mut Buffers) {
    use bino_core::config::HEAD_DIM;
    use bino_core::fixed::Requant;
    use bino_core::kernels::dispatch::attention::softmax_row;
    use bino_core::kernels::exp::ExpQ32;
    for (case, n) in [8usize, 128, 136, 200, 960, 960].into_iter().enumerate() {
        for shift in [33u32, 34, 35, 36, 38] {
            let extremes = case % 2 == 1;
            let scores = &mut b.found[..4 * n];
            for s in scores.iter_mut() {
                *s = match rng.range(0, 15) {
                    0 if extremes => i32::MIN,
                    1 if extremes => i32::MAX,
                    _ => rng.range(-(1 << 19), 1 << 19) as i32,
                };
            }
            let values_t = &mut b.w.0[..HEAD_DIM * n];
            rng.fill(values_t, 3);
            let mult = if case % 3 == 0 { i32::MAX } else { 1 << 30 };
            let Some(e) = ExpQ32::new(Requant { mult, shift }) else {
                continue;
            };
            let mut expected = [[0i32; HEAD_DIM]; 4];
            let mut totals = [0u32; 4];
            for (q, row) in scores.chunks_exact(n).enumerate() {
                let w = &mut b.weights.0[..n];
                totals[q] = softmax_row(&e, row_max(row), row, w);
                for (d, channel) in values_t.chunks_exact(n).enumerate() {
                    expected[q][d] = channel
                        .iter()
                        .zip(w.iter())
                        .map(|(&v, &w)| v as i32 * (w ^ 0x80) as i32)
                        .sum();
                }
            }
            let scratch = &mut b.weights.0[..4 * n];
            let Some((found_totals, found)) =
                bino_core::kernels::arch::softmax_weighted_sums(&e, scores, scratch, values_t)
            else {
                // The kernel keeps the sums in the softmax bytes: rows of 128 keys at least.
                if cfg!(board = "an500") && n >= 128 {
                    defmt::println!(
                        "kernel-tests mismatch kernel=softmax_block n={=usize} shift={=u32} declined",
                        n,
                        shift
                    );
                    t.failed += 1;
                }
                continue;
            };
            t.check(
                "softmax_block",
                [4, n, HEAD_DIM],
                found.as_flattened(),
                expected.as_flattened(),
            );
            t.check("softmax_block/totals", [4, n, 0], &found_totals, &totals);
            t.asm_cases += 1;
        }
    }
}

/// Weights at an odd address: the Cortex-M7 kernel declines, the results still agree.
fn unaligned_cases(t: &mut Tally, rng: &mut Rng) {
    let mut a = Aligned([0i8; 4 * 32]);
    let mut w = Aligned([0i8; 3 * 32 + 1]);
    rng.fill(&mut a.0, 3);
    rng.fill(&mut w.0, 3);
    let w_odd = &w.0[1..];
    let mut found = [0i32; 12];
    let mut expected = [0i32; 12];
    matmul_i8_reference(&a.0, w_odd, 32, &mut expected);
    let took = arch::matmul_i32(&a.0, w_odd, 32, &mut found);
    if cfg!(board = "an500") && took {
        defmt::println!("kernel-tests wrong-path kernel=matmul_i32 unaligned took=true");
        t.failed += 1;
    }
    matmul_i8(&a.0, w_odd, 32, &mut found);
    t.check("matmul_i8/unaligned", [4, 3, 32], &found, &expected);
}

/// The stage the instruction-count plugin attributes work to (written by the markers).
static CURRENT: AtomicU32 = AtomicU32::new(0);

macro_rules! markers {
    ($($name:ident = $id:expr;)*) => {
        $(
            #[no_mangle]
            #[inline(never)]
            #[doc = "Marker the instruction-count plugin watches (`scripts/firmware.sh --kernels`)."]
            pub extern "C" fn $name() {
                CURRENT.store($id, Ordering::SeqCst);
            }
        )*
    };
}

markers! {
    bino_mark_qkv_fused = 1;
    bino_mark_qkv_reference = 2;
    bino_mark_mlp_up_fused = 3;
    bino_mark_mlp_up_reference = 4;
    bino_mark_mlp_down_fused = 5;
    bino_mark_mlp_down_reference = 6;
    bino_mark_mlp_down_i32 = 7;
    bino_mark_mlp_down_i32_reference = 8;
    bino_mark_softmax_fast = 9;
    bino_mark_softmax_reference = 10;
    bino_mark_scores_fast = 11;
    bino_mark_scores_reference = 12;
    bino_mark_pv_fast = 13;
    bino_mark_pv_reference = 14;
    bino_mark_layernorm_fast = 15;
    bino_mark_layernorm_reference = 16;
    bino_mark_residual_fast = 17;
    bino_mark_residual_reference = 18;
    bino_mark_end = 0xFFFF;
}

/// Calls per measured kernel: the engine's blocks of 8 tokens, 120 of them (960 tokens).
const BENCH_CALLS: usize = 120;

/// The GEMMs of the encoder as the engine calls them (8 token rows at a time, 960 tokens):
/// each kernel between markers, the assembly one and the portable path (the two passes
/// `matmul_i8_portable` + `requant_rows`). `scripts/firmware.sh --kernels` divides the
/// plugin's counts by the MACs logged here.
fn bench(rng: &mut Rng, b: &mut Buffers) {
    type Mark = extern "C" fn();
    let shapes: [(&str, usize, usize, Mark, Mark); 3] = [
        ("qkv", 128, 384, bino_mark_qkv_fused, bino_mark_qkv_reference),
        ("mlp_up", 128, 480, bino_mark_mlp_up_fused, bino_mark_mlp_up_reference),
        (
            "mlp_down",
            480,
            128,
            bino_mark_mlp_down_fused,
            bino_mark_mlp_down_reference,
        ),
    ];
    const M: usize = 8;
    for (name, k, n, fused, reference) in shapes {
        rng.fill(&mut b.a.0[..M * k], 3);
        rng.fill(&mut b.w.0[..n * k], 3);
        let (a, w) = (&b.a.0[..M * k], &b.w.0[..n * k]);
        let p = Params::random(rng, n.min(MAX_N), 18);
        // Channel parameters repeat past MAX_N (the table holds MAX_N).
        let bias: [i32; 480] = core::array::from_fn(|c| p.bias[c % MAX_N]);
        let mult: [i32; 480] = core::array::from_fn(|c| p.mult[c % MAX_N]);
        let shift: [u8; 480] = core::array::from_fn(|c| p.shift[c % MAX_N]);
        let zero: [i32; 480] = core::array::from_fn(|c| p.zero[c % MAX_N]);
        let rq = ChannelRequant {
            bias: &bias[..n],
            mult: &mult[..n],
            shift: &shift[..n],
        };
        let (out, want, acc) = (&mut b.found8, &mut b.expected8, &mut b.acc);
        // The columns prepared once, as the engine prepares them once per pass.
        let mut storage = [0i32; 4 * 480];
        let prepared = arch::PreparedRequant::new(&rq, &zero[..n], &mut storage);
        fused();
        for _ in 0..BENCH_CALLS {
            matmul_requant_i8_prepared(a, w, k, prepared.as_ref(), &rq, &zero[..n], acc, &mut out[..M * n]);
        }
        reference();
        for _ in 0..BENCH_CALLS {
            matmul_i8_portable(a, w, k, &mut acc[..M * n]);
            requant_rows(&acc[..M * n], &rq, &zero[..n], &mut want[..M * n]);
        }
        bino_mark_end();
        if name == "mlp_down" {
            // The engine's fc2 keeps i32 accumulators for the residual add.
            let acc2 = &mut b.found;
            bino_mark_mlp_down_i32();
            for _ in 0..BENCH_CALLS {
                matmul_i8(a, w, k, &mut acc2[..M * n]);
            }
            bino_mark_mlp_down_i32_reference();
            for _ in 0..BENCH_CALLS {
                matmul_i8_portable(a, w, k, &mut acc[..M * n]);
            }
            bino_mark_end();
        }
        // Reading the markers' variable keeps their stores (and so the markers) distinct.
        let last_mark = CURRENT.load(Ordering::SeqCst);
        let same = out[..M * n] == want[..M * n] && last_mark == 0xFFFF;
        defmt::println!(
            "kernel-bench kernel={=str} m={=usize} k={=usize} n={=usize} calls={=usize} macs={=usize} same={=bool}",
            name,
            M,
            k,
            n,
            BENCH_CALLS,
            BENCH_CALLS * M * k * n,
            same
        );
    }
}

/// Softmax rows as attention computes them (the row maximum, then the weights and their sum),
/// this core's fastest path (on Cortex-M7 the engine's, into the DSP tile's widened layout)
/// and the portable reference between markers; rows of 960 scores, a band's tokens, spread
/// like the products of 32 int8 pairs.
fn bench_softmax(rng: &mut Rng, b: &mut Buffers) {
    use bino_core::fixed::Requant;
    use bino_core::kernels::dispatch::attention::{softmax_row, softmax_row_fastest};
    use bino_core::kernels::exp::ExpQ32;
    const N: usize = 960;
    const ROWS: usize = 16;
    for s in b.found[..N].iter_mut() {
        *s = rng.range(-(1 << 15), 1 << 15) as i32;
    }
    // The shipped blob's first block (every block's shift is 33-36): the Cortex-M7 row's
    // shortcuts need a gap of 2^20 to reach the table's zero, as real attention scales do.
    let Some(e) = ExpQ32::new(Requant {
        mult: 1_431_142_052,
        shift: 34,
    }) else {
        defmt::println!("kernel-bench kernel=softmax rejected");
        return;
    };
    let (scores, (fast, rest)) = (&b.found[..N], b.weights.0.split_at_mut(N));
    let reference = &mut rest[..N];
    let (mut sum_fast, mut sum_reference) = (0u32, 0u32);
    // Cortex-M7: the engine's softmax (into the DSP tile's widened layout).
    let widened = &mut b.widened;
    bino_mark_softmax_fast();
    for _ in 0..ROWS {
        let into_tile = if cfg!(board = "an500") {
            bino_core::kernels::arch::softmax_row_widened(&e, scores, widened)
        } else {
            None
        };
        sum_fast = sum_fast.wrapping_add(match into_tile {
            Some(sum) => sum,
            None => {
                let m = bino_core::kernels::dispatch::attention::row_max(scores);
                softmax_row_fastest(&e, m, scores, fast)
            }
        });
    }
    if cfg!(board = "an500") {
        // The weights back to the bytes `softmax_row` stores (`w ^ 0x80`).
        for (g, four) in fast.chunks_exact_mut(4).enumerate() {
            let (lo, hi) = (widened[8 * g], widened[8 * g + 1]);
            let w = [lo & 0xFFFF, hi & 0xFFFF, lo >> 16, hi >> 16];
            for (f, w) in four.iter_mut().zip(w) {
                *f = (w as u8) ^ 0x80;
            }
        }
    }
    bino_mark_softmax_reference();
    for _ in 0..ROWS {
        let m = row_max(scores);
        sum_reference = sum_reference.wrapping_add(softmax_row(&e, m, scores, reference));
    }
    bino_mark_end();
    let same = fast == reference && sum_fast == sum_reference && CURRENT.load(Ordering::SeqCst) == 0xFFFF;
    defmt::println!(
        "kernel-bench-rows kernel=softmax rows={=usize} n={=usize} elements={=usize} same={=bool}",
        ROWS,
        N,
        ROWS * N,
        same
    );
}

/// Attention scores as the engine computes them (four queries against a band's 960 keys, 240
/// blocks: one head of one layer), this core's fastest path and the portable reference
/// between markers. Printed as a GEMM (`m` queries, `k` the head size, `n` keys).
fn bench_scores(rng: &mut Rng, b: &mut Buffers) {
    use bino_core::config::HEAD_DIM;
    use bino_core::kernels::dispatch::attention::{scores_block, scores_block_reference, QUERY_BLOCK};
    const N: usize = 960;
    const CALLS: usize = 240;
    rng.fill(&mut b.w.0[..N * HEAD_DIM], 3);
    let mut queries = [[0i8; HEAD_DIM]; QUERY_BLOCK];
    for q in queries.iter_mut() {
        rng.fill(q, 3);
    }
    let keys = &b.w.0[..N * HEAD_DIM];
    let (found, expected) = (&mut b.found[..QUERY_BLOCK * N], &mut b.expected[..QUERY_BLOCK * N]);
    bino_mark_scores_fast();
    for _ in 0..CALLS {
        scores_block(&queries, keys, N, found);
    }
    bino_mark_scores_reference();
    for _ in 0..CALLS {
        scores_block_reference(&queries, keys, expected);
    }
    bino_mark_end();
    let same = found == expected && CURRENT.load(Ordering::SeqCst) == 0xFFFF;
    defmt::println!(
        "kernel-bench kernel=scores m={=usize} k={=usize} n={=usize} calls={=usize} macs={=usize} same={=bool}",
        QUERY_BLOCK,
        HEAD_DIM,
        N,
        CALLS,
        CALLS * QUERY_BLOCK * HEAD_DIM * N,
        same
    );
}

/// Attention's weighted sums (P·V) as the engine computes them: four rows of 960 softmax
/// weights (as int8) against the 32 value channels (transposed, 960 each), 240 blocks, through
/// `matmul_i8` (this core's GEMM tile; on Cortex-M7 the block kernel on rows the softmax
/// already widened) and the portable reference between markers.
fn bench_pv(rng: &mut Rng, b: &mut Buffers) {
    use bino_core::config::HEAD_DIM;
    use bino_core::kernels::dispatch::attention::QUERY_BLOCK;
    const N: usize = 960;
    const CALLS: usize = 240;
    rng.fill(&mut b.a.0[..QUERY_BLOCK * N], 3);
    rng.fill(&mut b.w.0[..HEAD_DIM * N], 3);
    let (weights, values_t) = (&b.a.0[..QUERY_BLOCK * N], &b.w.0[..HEAD_DIM * N]);
    let (found, expected) = (
        &mut b.found[..QUERY_BLOCK * HEAD_DIM],
        &mut b.expected[..QUERY_BLOCK * HEAD_DIM],
    );
    // Cortex-M7: the engine's softmax leaves the weights widened, so its weighted sums are
    // the block kernel alone; the rows are widened here, outside the markers.
    if cfg!(board = "an500") {
        for (r, row) in weights.chunks_exact(N).enumerate() {
            for (g, q) in row.chunks_exact(4).enumerate() {
                let pair = |lo: i8, hi: i8| (lo as i16 as u16 as u32) | ((hi as i16 as u16 as u32) << 16);
                b.widened[8 * g + 2 * r] = pair(q[0], q[2]);
                b.widened[8 * g + 2 * r + 1] = pair(q[1], q[3]);
            }
        }
    }
    let mut block = [[0i32; HEAD_DIM]; QUERY_BLOCK];
    bino_mark_pv_fast();
    for _ in 0..CALLS {
        if !(cfg!(board = "an500")
            && bino_core::kernels::arch::weighted_sums_widened(&b.widened, values_t, N, &mut block))
        {
            matmul_i8(weights, values_t, N, found);
        }
    }
    if cfg!(board = "an500") {
        found.copy_from_slice(block.as_flattened());
    }
    bino_mark_pv_reference();
    for _ in 0..CALLS {
        matmul_i8_reference(weights, values_t, N, expected);
    }
    bino_mark_end();
    let same = found == expected && CURRENT.load(Ordering::SeqCst) == 0xFFFF;
    defmt::println!(
        "kernel-bench kernel=pv m={=usize} k={=usize} n={=usize} calls={=usize} macs={=usize} same={=bool}",
        QUERY_BLOCK,
        N,
        HEAD_DIM,
        CALLS,
        CALLS * QUERY_BLOCK * HEAD_DIM * N,
        same
    );
}

/// LayerNorm as the engine calls it (blocks of 8 tokens of 128 channels, 120 blocks: one
/// LayerNorm of a band), with quantiser-like formats: `layernorm_rows` and the reference
/// between markers. Counted per element.
fn bench_layernorm(rng: &mut Rng, b: &mut Buffers) {
    use bino_core::kernels::dispatch::layernorm::{layernorm_rows, layernorm_rows_reference};
    const DIM: usize = 128;
    const ROWS: usize = 8;
    const CALLS: usize = 120;
    let formats = LayerNormCase::random(rng, 3);
    let p = formats.params(1 << 20, 1_500_000_000, 44);
    rng.fill(&mut b.a.0[..ROWS * DIM], 3);
    let x = &b.a.0[..ROWS * DIM];
    let (found, expected) = (&mut b.found8[..ROWS * DIM], &mut b.expected8[..ROWS * DIM]);
    bino_mark_layernorm_fast();
    for _ in 0..CALLS {
        layernorm_rows(x, DIM, &p, found);
    }
    bino_mark_layernorm_reference();
    for _ in 0..CALLS {
        layernorm_rows_reference(x, DIM, &p, expected);
    }
    bino_mark_end();
    let same = found == expected && CURRENT.load(Ordering::SeqCst) == 0xFFFF;
    defmt::println!(
        "kernel-bench-rows kernel=layernorm rows={=usize} n={=usize} elements={=usize} same={=bool}",
        CALLS * ROWS,
        DIM,
        CALLS * ROWS * DIM,
        same
    );
}

/// The residual add as the engine calls it (blocks of 8 tokens of 128 channels, 120 blocks),
/// with quantiser-like shifts (36-44) and accumulators: `residual_add` and the reference
/// between markers. Counted per element.
fn bench_residual(rng: &mut Rng, b: &mut Buffers) {
    const DIM: usize = 128;
    const ROWS: usize = 8;
    const CALLS: usize = 120;
    let mut params = ResidualCase::random(rng, 36, false);
    // The quantiser's shifts: 36-44 for a requantised delta, 29-33 for a format change.
    for s in params.shift.iter_mut() {
        *s = (*s).min(44);
    }
    for s in params.cshift.iter_mut() {
        *s = 29 + *s % 5;
    }
    for z in params.czero.iter_mut() {
        *z %= 300;
    }
    let acc = &mut b.acc[..ROWS * DIM];
    for a in acc.iter_mut() {
        *a = rng.range(-(1 << 20), 1 << 20) as i32;
    }
    rng.fill(&mut b.found8[..ROWS * DIM], 3);
    b.expected8[..ROWS * DIM].copy_from_slice(&b.found8[..ROWS * DIM]);
    let (x, want, acc) = (
        &mut b.found8[..ROWS * DIM],
        &mut b.expected8[..ROWS * DIM],
        &b.acc[..ROWS * DIM],
    );
    bino_mark_residual_fast();
    for _ in 0..CALLS {
        params.run(DIM, x, acc, false);
    }
    bino_mark_residual_reference();
    for _ in 0..CALLS {
        params.run(DIM, want, acc, true);
    }
    bino_mark_end();
    let same = x == want && CURRENT.load(Ordering::SeqCst) == 0xFFFF;
    defmt::println!(
        "kernel-bench-rows kernel=residual rows={=usize} n={=usize} elements={=usize} same={=bool}",
        CALLS * ROWS,
        DIM,
        CALLS * ROWS * DIM,
        same
    );
}

/// The sharpness-equalised refinement of a half-defocused pair: the rows it blurs and the
/// CRC of its output equal the host's.
fn equalised_refinement_case(t: &mut Tally) {
    let found = match equalise_case::views().and_then(|(l, r)| equalise_case::blurred_rows(&l, &r)) {
        Ok(rows) => [rows as u32, equalise_case::refined_crc().unwrap_or(0)],
        Err(e) => {
            defmt::println!("kernel-tests error kernel=refine_equalised {}", e);
            [u32::MAX; 2]
        }
    };
    let expected = [host::EQUALISED_BLURRED_ROWS as u32, host::EQUALISED_CRC];
    t.check(
        "refine_equalised (blurred rows, crc)",
        [equalise_case::HEIGHT, equalise_case::WIDTH, 0],
        &found,
        &expected,
    );
}

#[entry]
fn main() -> ! {
    defmt::println!("kernel-tests board={=str}", BOARD);
    let mut t = Tally {
        cases: 0,
        failed: 0,
        asm_cases: 0,
    };
    let mut rng = Rng::new(0x9E37_79B9_7F4A_7C15);
    let Some(buffers) = cortex_m::singleton!(: Buffers = Buffers {
        a: Aligned([0; MAX_M * MAX_K]),
        w: Aligned([0; MAX_N * MAX_K]),
        found: [0; MAX_OUT],
        expected: [0; MAX_OUT],
        found8: [0; MAX_OUT],
        expected8: [0; MAX_OUT],
        acc: [0; MAX_OUT],
        weights: Aligned([0; MAX_OUT]),
        widened: [0; 2 * 960],
    }) else {
        defmt::println!("kernel-tests result=fail buffers taken");
        exit(EXIT_FAILURE);
        #[allow(clippy::empty_loop)]
        loop {}
    };
    random_cases(&mut t, &mut rng, buffers);
    rounding_cases(&mut t);
    unaligned_cases(&mut t, &mut rng);
    attention_cases(&mut t, &mut rng, buffers);
    softmax_cases(&mut t, &mut rng, buffers);
    scatter_cases(&mut t, &mut rng, buffers);
    softmax_block_cases(&mut t, &mut rng, buffers);
    scores_cases(&mut t, &mut rng, buffers);
    layernorm_cases(&mut t, &mut rng, buffers);
    residual_cases(&mut t, &mut rng, buffers);
    rope_cases(&mut t, &mut rng);
    conv_epilogue_cases(&mut t, &mut rng);
    equalised_refinement_case(&mut t);
    bench(&mut rng, buffers);
    bench_softmax(&mut rng, buffers);
    bench_scores(&mut rng, buffers);
    bench_pv(&mut rng, buffers);
    bench_layernorm(&mut rng, buffers);
    bench_residual(&mut rng, buffers);
    let pass = t.failed == 0 && t.asm_cases > 0;
    defmt::println!(
        "kernel-tests result={=str} cases={=usize} assembly_cases={=usize} failed={=usize}",
        if pass { "pass" } else { "fail" },
        t.cases,
        t.asm_cases,
        t.failed
    );
    exit(if pass { EXIT_SUCCESS } else { EXIT_FAILURE });
    #[allow(clippy::empty_loop)]
    loop {}
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    defmt::println!("kernel-tests result=panic {}", defmt::Display2Format(info));
    exit(EXIT_FAILURE);
    #[allow(clippy::empty_loop)]
    loop {}
}
