//! AVX-512 VNNI kernels of x86-64 host builds, chosen at run time where the CPU has them
//! (`vpdpbusd`: 32 products of an unsigned and a signed byte, summed into 8 int32 lanes, in one
//! instruction, against 16 per `vpmaddwd` + `vpaddd` pair on AVX2). Whatever `-C target-cpu` the build
//! names, these are compiled for the wider features and called only after [`available`] has
//! seen them in `cpuid` and the OS saving their registers (`xgetbv`).
//!
//! `vpdpbusd` multiplies unsigned by signed bytes: the signed codes `x` of one operand enter as
//! `x ^ 0x80 = x + 128`, and `128 * sum(other operand)` comes off again, exactly: every sum is
//! taken modulo 2^32, as the portable kernels' wrapping adds take it, and such sums do not
//! depend on their order. So the results are bit-identical to the portable kernels'.
//! Each entry point returns `false` (computing nothing) where the CPU or the shape does not
//! fit; the caller then runs the AVX2 or portable kernel.

use core::arch::x86_64::{
    __cpuid, __cpuid_count, __m128i, __m256i, __m512i, _mm256_dpbusd_epi32, _mm256_set1_epi8, _mm256_setzero_si256,
    _mm256_xor_si256, _mm512_add_epi16, _mm512_add_epi32, _mm512_add_epi64, _mm512_and_si512, _mm512_cvtepi32_epi8,
    _mm512_mask_blend_epi32, _mm512_min_epu32, _mm512_mul_epu32, _mm512_mulhi_epu16, _mm512_mullo_epi32,
    _mm512_packus_epi16, _mm512_packus_epi32, _mm512_permutexvar_epi32, _mm512_reduce_add_epi32,
    _mm512_reduce_add_epi64, _mm512_sad_epu8, _mm512_set1_epi16, _mm512_set1_epi32, _mm512_set1_epi8, _mm512_set_epi32,
    _mm512_setzero_si512, _mm512_slli_epi16, _mm512_sllv_epi16, _mm512_sllv_epi32, _mm512_srli_epi16,
    _mm512_srli_epi32, _mm512_srli_epi64, _mm512_srlv_epi16, _mm512_srlv_epi32, _mm512_sub_epi16, _mm512_sub_epi32,
    _mm512_xor_si512, _mm_sub_epi32, _xgetbv,
};
use core::sync::atomic::{AtomicU8, Ordering};

use bytemuck::must_cast;

use super::avx2::{sum4, transpose4};
use crate::kernels::types::exp::{ExpQ32, C0, C1, C2, C3, EXP2_TABLE_LAST, EXP_Q32_MAX_GAP};

/// Bytes per step: one 256-bit vector.
pub const STEP: usize = 32;
/// Longest dot product [`matmul_i32`] takes.
pub const MAX_GEMM_K: usize = 1024;
const HEAD: usize = crate::config::HEAD_DIM;

// 0: not yet looked, 1: absent or switched off, 2: in use.
static STATE: AtomicU8 = AtomicU8::new(0);

/// Whether these kernels run: the CPU and OS support AVX-512 F, DQ, BW, VL and VNNI, and
/// [`enable`] has not switched them off.
pub fn available() -> bool {
    match STATE.load(Ordering::Relaxed) {
        1 => false,
        2 => true,
        _ => enable(true),
    }
}

/// Switches the kernels on (only where [`supported`]) or off, for this process; returns
/// whether they now run. Off is how the AVX2 kernels are measured and tested on a CPU with
/// VNNI; the results are the same either way.
pub fn enable(on: bool) -> bool {
    // They use AVX2 helpers too: off wherever the AVX2 kernels are.
    let run = on && super::avx2() && supported();
    STATE.store(if run { 2 } else { 1 }, Ordering::Relaxed);
    run
}

/// Whether the CPU has AVX-512 F, DQ, BW, VL and VNNI and the OS saves their registers.
pub fn supported() -> bool {
    const OSXSAVE: u32 = 1 << 27;
    // xgetbv(0): SSE, AVX, opmask, ZMM_Hi256 and Hi16_ZMM state enabled.
    const AVX512_STATE: u64 = 0b1110_0110;
    if __cpuid(0).eax < 7 || __cpuid(1).ecx & OSXSAVE == 0 {
        return false;
    }
    // SAFETY: OSXSAVE is set, so the CPU has XSAVE (the intrinsic's target feature) and the
    // OS has enabled it: `xgetbv` cannot fault.
    #[allow(unsafe_code)]
    let xcr0 = unsafe { _xgetbv(0) };
    let leaf7 = __cpuid_count(7, 0);
    let (f, dq, bw, vl) = (
        leaf7.ebx >> 16 & 1,
        leaf7.ebx >> 17 & 1,
        leaf7.ebx >> 30 & 1,
        leaf7.ebx >> 31 & 1,
    );
    let vnni = leaf7.ecx >> 11 & 1;
    xcr0 & AVX512_STATE == AVX512_STATE && f & dq & bw & vl & vnni == 1
}

/// `out` (`m x n`) = `a` (`m x k`) times the transpose of `w` (`n x k`), as
/// `matmul::matmul_i8_reference` computes it, when the kernels run, `k` is a multiple of
/// [`STEP`] up to [`MAX_GEMM_K`] and `out` holds exactly `m * n`.
pub fn matmul_i32(a: &[i8], w: &[i8], k: usize, out: &mut [i32]) -> bool {
    if k == 0 || !k.is_multiple_of(STEP) || k > MAX_GEMM_K || !available() {
        return false;
    }
    let (m, n) = (a.len() / k, w.len() / k);
    // No rows on either side: nothing to compute (and the tiles' chunking needs some).
    if m == 0 || n == 0 || m.checked_mul(n) != Some(out.len()) {
        return false;
    }
    // SAFETY: `available()` saw AVX-512 F/BW/VL/VNNI on this CPU, enabled by the OS.
    #[allow(unsafe_code)]
    unsafe {
        matmul_vnni(&a[..m * k], &w[..n * k], k, out)
    };
    true
}

/// `out[at..at + count] = values[..count]` where it fits: a fixed-size copy for a full `N`
/// (a variable-length one is a `memcpy` call).
#[inline(always)]
fn store<const N: usize>(out: &mut [i32], at: usize, values: &[i32; N], count: usize) {
    if count == N {
        if let Some(slot) = out.get_mut(at..at + N) {
            slot.copy_from_slice(values);
        }
    } else {
        for (o, &v) in out.iter_mut().skip(at).zip(values).take(count) {
            *o = v;
        }
    }
}

/// `f()` compiled for AVX-512 F, BW, VL and DQ where the kernels run (`None`, `f` not called,
/// elsewhere): portable loops inlined here vectorise with 64-bit lane multiplies and
/// arithmetic shifts, which AVX2 lacks. The results are those of `f` compiled for AVX2.
#[inline(always)]
pub fn with_avx512<R>(f: impl FnOnce() -> R) -> Option<R> {
    if !available() {
        return None;
    }
    // SAFETY: `available()` saw AVX-512 F/BW/VL/DQ/VNNI on this CPU, enabled by the OS.
    #[allow(unsafe_code)]
    Some(unsafe { run_avx512(f) })
}

#[target_feature(enable = "avx2,bmi1,bmi2,avx512f,avx512bw,avx512vl,avx512dq")]
pub(super) fn run_avx512<R>(f: impl FnOnce() -> R) -> R {
    f()
}

/// `attention::softmax_row` compiled with AVX-512 (16 lanes a vector) where the kernels run;
/// `None` elsewhere.
pub fn softmax_row(e: &ExpQ32, max: i32, scores: &[i32], weights: &mut [u8]) -> Option<u32> {
    if !available() {
        return None;
    }
    // SAFETY: as in `matmul_i32`.
    #[allow(unsafe_code)]
    Some(unsafe { softmax_row_avx512(e, max, scores, weights) })
}

/// Scores per step of the softmax row's tail loop: one 512-bit vector.
const SOFTMAX_STEP: usize = 16;
/// Scores per step of its main loop: four vectors, packed to bytes together.
const SOFTMAX_WIDE: usize = 4 * SOFTMAX_STEP;

/// `ExpQ32::weight` of sixteen gaps' worth of constants, broadcast once per row.
struct ExpLanes {
    row_max: __m512i,
    cap: __m512i,
    pre: __m512i,
    mult: __m512i,
    round: __m512i,
    post: __m512i,
    last: __m512i,
    low_byte: __m512i,
    half: __m512i,
    c: [__m512i; 4],
    // The cubic in 16-bit lanes ([`ExpLanes::cubic16`]).
    c16: [__m512i; 4],
    scale16: __m512i,
    round16: __m512i,
    shift16: __m512i,
}

impl ExpLanes {
    #[inline]
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
    fn new(e: &ExpQ32, max: i32) -> Self {
        let (pre, round, post) = e.shifts();
        let v = |x: u32| _mm512_set1_epi32(x as i32);
        Self {
            row_max: _mm512_set1_epi32(max),
            cap: v(EXP_Q32_MAX_GAP),
            pre: v(pre),
            mult: v(e.mult()),
            round: v(round),
            post: v(post),
            last: v(EXP2_TABLE_LAST),
            low_byte: v(255),
            half: v(1 << 14),
            c: [v(C0), v(C1), v(C2), v(C3)],
            c16: [C0, C1, C2, C3].map(|c| _mm512_set1_epi16(c as u16 as i16)),
            scale16: _mm512_set1_epi16(0xFF00u16 as i16),
            round16: _mm512_set1_epi16(1 << 6),
            shift16: _mm512_set1_epi16(7),
        }
    }

    // `ExpQ32::weight` in 16 lanes: the exponents, then the cubic. Weights 0..=255.
    #[inline]
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
    fn weights(&self, scores: &[i32; SOFTMAX_STEP]) -> __m512i {
        self.cubic(self.exponents(scores))
    }

    // The exponent `x` (Q8 base 2, `0..=EXP2_TABLE_LAST`) of sixteen scores: the gap's high
    // product word from two `vpmuludq` (a 64-bit product per even or odd lane; the portable
    // code assembles it from 16-bit halves, which `weight_by_table` and the exp tests show to
    // be the same word), clamped at the table's last entry (where the cubic is already 0).
    #[inline]
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
    fn exponents(&self, scores: &[i32; SOFTMAX_STEP]) -> __m512i {
        let s: __m512i = must_cast(*scores);
        let gap = _mm512_sub_epi32(self.row_max, s);
        let g = _mm512_sllv_epi32(_mm512_min_epu32(gap, self.cap), self.pre);
        let even = _mm512_mul_epu32(g, self.mult);
        let odd = _mm512_mul_epu32(_mm512_srli_epi64::<32>(g), self.mult);
        let high = _mm512_mask_blend_epi32(0xAAAA, _mm512_srli_epi64::<32>(even), odd);
        _mm512_min_epu32(
            _mm512_srlv_epi32(_mm512_add_epi32(high, self.round), self.post),
            self.last,
        )
    }

    // exp2_neg_u8_q8(x) in 32-bit lanes: the cubic of the fraction, shifted by the whole part (a
    // gather from its table measured slower on Zen 4).
    #[inline]
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
    fn cubic(&self, x: __m512i) -> __m512i {
        let [c0, c1, c2, c3] = self.c;
        let f = _mm512_and_si512(x, self.low_byte);
        let t = _mm512_srli_epi32::<8>(_mm512_mullo_epi32(c3, f));
        let t = _mm512_srli_epi32::<8>(_mm512_mullo_epi32(_mm512_sub_epi32(c2, t), f));
        let t = _mm512_srli_epi32::<8>(_mm512_mullo_epi32(_mm512_sub_epi32(c1, t), f));
        let scaled = _mm512_mullo_epi32(_mm512_sub_epi32(c0, t), self.low_byte);
        let shifted = _mm512_srlv_epi32(scaled, _mm512_srli_epi32::<8>(x));
        _mm512_srli_epi32::<15>(_mm512_add_epi32(shifted, self.half))
    }

    // The same cubic in 32 16-bit lanes (`x` as `u16`), exactly: `(C * f) >> 8` is
    // `mulhi(C, f << 8)` (and `x << 8` in 16 bits *is* `f << 8`), every coefficient and
    // `C0 - t <= 2^15` fit a `u16`, and the rounding `((P * 255 >> w) + 2^14) >> 15` equals
    // `(mulhi(P, 255 << 8) + 2^(6 + w)) >> (7 + w)` (nested floors of power-of-two divisions
    // compose; the sum stays below 2^16), the shift reaching 16 only at `w = 9`, where
    // `vpsrlvw` gives the 0 the cubic gives. Checked for every `x` by the tests.
    #[inline]
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
    fn cubic16(&self, x: __m512i) -> __m512i {
        let [c0, c1, c2, c3] = self.c16;
        let f8 = _mm512_slli_epi16::<8>(x);
        let t = _mm512_mulhi_epu16(c3, f8);
        let t = _mm512_mulhi_epu16(_mm512_sub_epi16(c2, t), f8);
        let t = _mm512_mulhi_epu16(_mm512_sub_epi16(c1, t), f8);
        let scaled = _mm512_mulhi_epu16(_mm512_sub_epi16(c0, t), self.scale16);
        let whole = _mm512_srli_epi16::<8>(x);
        let rounded = _mm512_add_epi16(scaled, _mm512_sllv_epi16(self.round16, whole));
        _mm512_srlv_epi16(rounded, _mm512_add_epi16(whole, self.shift16))
    }
}

// Sixty-four scores a step: four vectors of exponents packed to words (two `vpackusdw`), the
// cubic on those 32 lanes a vector, the weights packed to bytes (one `vpackuswb`, one `vpermd`
// to undo the packs' 128-bit lanes; one `vpmovdb` per vector was the loop's bottleneck) and
// summed with one `vpsadbw`; sixteen a step for the rest.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
fn softmax_row_avx512(e: &ExpQ32, max: i32, scores: &[i32], weights: &mut [u8]) -> u32 {
    let n = scores.len().min(weights.len());
    let lanes = ExpLanes::new(e, max);
    let flip = _mm512_set1_epi8(-128);
    let zero = _mm512_setzero_si512();
    // After the packs, 128-bit lane `l` holds elements 4l..4l+3 of each of the four vectors in
    // turn: dword `4l + i`. Dword `4i + l` of the output takes it.
    let unlane = _mm512_set_epi32(15, 11, 7, 3, 14, 10, 6, 2, 13, 9, 5, 1, 12, 8, 4, 0);
    let mut byte_sums = zero;
    let wide = n / SOFTMAX_WIDE * SOFTMAX_WIDE;
    let (scores_wide, scores_rest) = scores.split_at(wide);
    let (weights_wide, weights_rest) = weights.split_at_mut(wide);
    for (w, s) in weights_wide
        .chunks_exact_mut(SOFTMAX_WIDE)
        .zip(scores_wide.chunks_exact(SOFTMAX_WIDE))
    {
        // Four plain calls: a closure (`array::from_fn`) would not inherit the target features
        // and stays an out-of-line call through the stack.
        let (s0, s123) = s.split_at(SOFTMAX_STEP);
        let (s1, s23) = s123.split_at(SOFTMAX_STEP);
        let (s2, s3) = s23.split_at(SOFTMAX_STEP);
        let sixteen = |x: &[i32]| -> [i32; SOFTMAX_STEP] { x.try_into().unwrap_or([0; SOFTMAX_STEP]) };
        let x = [
            lanes.exponents(&sixteen(s0)),
            lanes.exponents(&sixteen(s1)),
            lanes.exponents(&sixteen(s2)),
            lanes.exponents(&sixteen(s3)),
        ];
        // The exponents (<= EXP2_TABLE_LAST) pack to words losslessly; the cubic then runs on
        // 32 lanes a vector, and its words (<= 255) pack to bytes.
        let w01 = lanes.cubic16(_mm512_packus_epi32(x[0], x[1]));
        let w23 = lanes.cubic16(_mm512_packus_epi32(x[2], x[3]));
        let bytes = _mm512_permutexvar_epi32(unlane, _mm512_packus_epi16(w01, w23));
        byte_sums = _mm512_add_epi64(byte_sums, _mm512_sad_epu8(bytes, zero));
        let out: [u8; SOFTMAX_WIDE] = must_cast(_mm512_xor_si512(bytes, flip));
        w.copy_from_slice(&out);
    }
    let mut sums = zero;
    let step = (n - wide) / SOFTMAX_STEP * SOFTMAX_STEP;
    let (scores_step, scores_tail) = scores_rest.split_at(step.min(scores_rest.len()));
    let (weights_step, weights_tail) = weights_rest.split_at_mut(step.min(weights_rest.len()));
    for (w, s) in weights_step
        .chunks_exact_mut(SOFTMAX_STEP)
        .zip(scores_step.chunks_exact(SOFTMAX_STEP))
    {
        let weight = lanes.weights(s.try_into().unwrap_or(&[0; SOFTMAX_STEP]));
        sums = _mm512_add_epi32(sums, weight);
        let bytes: [u8; SOFTMAX_STEP] = must_cast(_mm512_cvtepi32_epi8(_mm512_xor_si512(weight, flip)));
        w.copy_from_slice(&bytes);
    }
    let tail = crate::kernels::reference::softmax::softmax_row(e, max, scores_tail, weights_tail);
    let wide_sum = _mm512_reduce_add_epi64(byte_sums) as u32;
    wide_sum
        .wrapping_add(_mm512_reduce_add_epi32(sums) as u32)
        .wrapping_add(tail)
}

#[inline(always)]
fn load(chunk: &[i8]) -> __m256i {
    must_cast::<[i8; STEP], __m256i>(chunk.try_into().unwrap_or([0; STEP]))
}

// Tiles of 4 rows of `a` (signed, memory operands) x 4 rows of `w` (unsigned: `w ^ 0x80`, in
// registers): 16 accumulators, 16 `vpdpbusd` per 32 elements. Row `r` then loses
// `128 * sum(a_r)`, computed once per four rows (the engine multiplies a few token rows at a
// time, so a per-column correction would cost as much as the tiles).
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
fn matmul_vnni(a: &[i8], w: &[i8], k: usize, out: &mut [i32]) {
    let n = w.len() / k;
    let flip = _mm256_set1_epi8(-128);
    for (a4, o4) in a.chunks(4 * k).zip(out.chunks_mut(4 * n)) {
        let rows = a4.len() / k;
        let row_sums: [__m256i; 4] = core::array::from_fn(|r| {
            let mut acc = _mm256_setzero_si256();
            for chunk in a4.get(r * k..(r + 1) * k).unwrap_or(&[]).chunks_exact(STEP) {
                acc = _mm256_dpbusd_epi32(acc, flip, load(chunk));
            }
            acc
        });
        let corrections = sum4(row_sums);
        for (q, w4) in w.chunks(4 * k).enumerate() {
            let j = 4 * q;
            let cols = w4.len() / k;
            let sums = if rows == 4 && cols == 4 {
                full_tile(a4, w4, k)
            } else {
                tile(a4, w4, k, rows, cols)
            };
            let per_col: [__m128i; 4] = core::array::from_fn(|c| _mm_sub_epi32(sum4(sums[c]), corrections));
            for (r, row) in transpose4(per_col).into_iter().enumerate().take(rows) {
                store(o4, r * n + j, &row, cols);
            }
        }
    }
}

// A full 4 x 4 tile: every slice walked by exact chunks, so the loop carries no bounds checks.
#[inline]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
fn full_tile(a4: &[i8], w4: &[i8], k: usize) -> [[__m256i; 4]; 4] {
    let flip = _mm256_set1_epi8(-128);
    let mut acc = [[_mm256_setzero_si256(); 4]; 4];
    let mut rows = a4.chunks_exact(k).map(|r| r.chunks_exact(STEP));
    let mut cols = w4.chunks_exact(k).map(|c| c.chunks_exact(STEP));
    let (Some(a0), Some(a1), Some(a2), Some(a3)) = (rows.next(), rows.next(), rows.next(), rows.next()) else {
        return acc;
    };
    let (Some(w0), Some(w1), Some(w2), Some(w3)) = (cols.next(), cols.next(), cols.next(), cols.next()) else {
        return acc;
    };
    for (((((((x0, x1), x2), x3), v0), v1), v2), v3) in a0.zip(a1).zip(a2).zip(a3).zip(w0).zip(w1).zip(w2).zip(w3) {
        let x = [x0, x1, x2, x3].map(load);
        for (acc_c, v) in acc.iter_mut().zip([v0, v1, v2, v3]) {
            let v = _mm256_xor_si256(load(v), flip);
            for (acc_rc, xr) in acc_c.iter_mut().zip(x) {
                *acc_rc = _mm256_dpbusd_epi32(*acc_rc, v, xr);
            }
        }
    }
    acc
}

// A tile of `rows` x `cols` (each at most 4); missing rows and columns count as zeros.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
fn tile(a4: &[i8], w4: &[i8], k: usize, rows: usize, cols: usize) -> [[__m256i; 4]; 4] {
    let flip = _mm256_set1_epi8(-128);
    let mut acc = [[_mm256_setzero_si256(); 4]; 4];
    for s in 0..k / STEP {
        let at = s * STEP;
        let x: [__m256i; 4] = core::array::from_fn(|r| {
            let row = if r < rows {
                a4.get(r * k + at..r * k + at + STEP)
            } else {
                None
            };
            load(row.unwrap_or(&[]))
        });
        for (c, acc_c) in acc.iter_mut().enumerate().take(cols) {
            let wv = _mm256_xor_si256(load(w4.get(c * k + at..c * k + at + STEP).unwrap_or(&[])), flip);
            for (r, acc_rc) in acc_c.iter_mut().enumerate() {
                *acc_rc = _mm256_dpbusd_epi32(*acc_rc, wv, x[r]);
            }
        }
    }
    acc
}

mod attention;
pub mod gemm;
pub mod layernorm;
pub mod rope;

pub use attention::{keys_transposed, scores4, scores4_transposed, weighted_sums4};

#[cfg(test)]
mod tests;
