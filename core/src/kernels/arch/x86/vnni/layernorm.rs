//! LayerNorm of up to eight token rows in AVX-512 lanes: `dispatch::layernorm`'s 32-bit lane
//! passes (`NarrowParams::row_in_lanes`, whose identities its tests prove) sixteen channels a
//! vector, and the rows' integer square roots taken together in 64-bit lanes (the scalar
//! digit-by-digit root, thirty dependent steps a row, was a third of a row's time). Bit for bit
//! `row_in_lanes`; a row it declines (an identity needs more bits) is left to the caller.

use core::arch::x86_64::{
    __m512i, _mm512_add_epi32, _mm512_add_epi64, _mm512_castsi512_si256, _mm512_cmpge_epu64_mask,
    _mm512_cvtepi32_epi64, _mm512_cvtepi8_epi32, _mm512_extracti64x4_epi64, _mm512_mask_add_epi64,
    _mm512_mask_blend_epi32, _mm512_mask_sub_epi64, _mm512_max_epi32, _mm512_min_epi32, _mm512_mul_epi32,
    _mm512_mullo_epi32, _mm512_reduce_add_epi64, _mm512_reduce_max_epi32, _mm512_reduce_min_epi32, _mm512_set1_epi32,
    _mm512_set1_epi64, _mm512_setzero_si512, _mm512_sll_epi32, _mm512_sra_epi32, _mm512_srli_epi64, _mm512_sub_epi32,
    _mm_cvtsi32_si128,
};

use bytemuck::must_cast;

use super::available;
use super::gemm::pack4;
use crate::fixed::MAX_SHIFT;
use crate::kernels::reference::layernorm::{narrow_shift, reciprocal_of_root, variance_radicand, NarrowShift};

/// Channels of a row: the encoder's width (`d = 2^7` in the identities).
pub const DIM: usize = 128;
/// Rows a call: a token block.
pub const ROWS: usize = 8;
const LANES: usize = 16;
const STEPS: usize = DIM / LANES;

/// A narrow LayerNorm's parameters (`NarrowParams`): per-channel zero points and relative
/// scales (each within `2^15`), `eps`, and the output's multiplier and shift.
pub struct NormLanes<'a> {
    /// Zero points.
    pub zero: &'a [i32; DIM],
    /// Relative scales.
    pub rel: &'a [i32; DIM],
    /// `eps` in unit^2.
    pub eps: i64,
    /// Output multiplier.
    pub mult: i32,
    /// Output shift, `33..=62` here.
    pub shift: u32,
}

/// The rows of `x` (`DIM` codes each, at most [`ROWS`]) normalised into `out` as
/// `row_in_lanes` does; the mask of the rows it left untouched (bit `r`: row `r`), whose values
/// need the 64-bit path. `None` (nothing written) where the kernels do not run, the output
/// shift is below 33 (or past `MAX_SHIFT`) or the lengths do not fit.
pub fn rows(p: &NormLanes<'_>, x: &[i8], out: &mut [i8]) -> Option<u8> {
    if !available() || x.len() != out.len() || !x.len().is_multiple_of(DIM) || x.len() > ROWS * DIM {
        return None;
    }
    if !(33..=MAX_SHIFT).contains(&p.shift) {
        return None;
    }
    // SAFETY: `available()` saw AVX-512 F/BW/VL/VNNI on this CPU, enabled by the OS.
    #[allow(unsafe_code)]
    Some(unsafe { rows_avx512(p, x, out) })
}

#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
fn rows_avx512(p: &NormLanes<'_>, x: &[i8], out: &mut [i8]) -> u8 {
    let (zero, _) = p.zero.as_chunks::<LANES>();
    let (rel, _) = p.rel.as_chunks::<LANES>();
    let mut normalised = [[_mm512_setzero_si512(); STEPS]; ROWS];
    let mut radicands = [0u64; ROWS];
    let mut left_rows = 0u8;
    let d = DIM as i64;
    for (r, (row, n)) in x.chunks_exact(DIM).zip(normalised.iter_mut()).enumerate() {
        let (codes, _) = row.as_chunks::<LANES>();
        // `v = (q - zero) * rel`, its 64-bit sum, minimum and maximum.
        let mut v = [_mm512_setzero_si512(); STEPS];
        let (mut sum, mut lo, mut hi) = (
            _mm512_setzero_si512(),
            _mm512_set1_epi32(i32::MAX),
            _mm512_set1_epi32(i32::MIN),
        );
        for (((v, q), z), rl) in v.iter_mut().zip(codes).zip(zero).zip(rel) {
            let z: __m512i = must_cast(*z);
            let rl: __m512i = must_cast(*rl);
            *v = _mm512_mullo_epi32(_mm512_sub_epi32(_mm512_cvtepi8_epi32(must_cast(*q)), z), rl);
            let wide = _mm512_add_epi64(
                _mm512_cvtepi32_epi64(_mm512_castsi512_si256(*v)),
                _mm512_cvtepi32_epi64(_mm512_extracti64x4_epi64::<1>(*v)),
            );
            sum = _mm512_add_epi64(sum, wide);
            (lo, hi) = (_mm512_min_epi32(lo, *v), _mm512_max_epi32(hi, *v));
        }
        let (sum, lo, hi) = (
            _mm512_reduce_add_epi64(sum),
            _mm512_reduce_min_epi32(lo),
            _mm512_reduce_max_epi32(hi),
        );
        // `row_in_lanes`' shift cases.
        let Some(NarrowShift {
            shift,
            left,
            add,
            right,
        }) = narrow_shift(sum, lo, hi, d)
        else {
            left_rows |= 1 << r;
            continue;
        };
        // `n = ((v << left) + add) >> right` and the 64-bit sum of its squares (`|n| < 2^25`).
        let (left, right) = (_mm_cvtsi32_si128(left as i32), _mm_cvtsi32_si128(right as i32));
        let add = _mm512_set1_epi32(add);
        let mut squares = _mm512_setzero_si512();
        for (n, &v) in n.iter_mut().zip(&v) {
            *n = _mm512_sra_epi32(_mm512_add_epi32(_mm512_sll_epi32(v, left), add), right);
            let even = _mm512_mul_epi32(*n, *n);
            let odd = _mm512_mul_epi32(_mm512_srli_epi64::<32>(*n), _mm512_srli_epi64::<32>(*n));
            squares = _mm512_add_epi64(squares, _mm512_add_epi64(even, odd));
        }
        let sum_sq = _mm512_reduce_add_epi64(squares);
        radicands[r] = variance_radicand(sum_sq >> 7, p.eps, d, shift);
    }
    let roots = isqrt8(radicands);
    let post = p.shift - 32;
    for (r, ((o, n), root)) in out.chunks_exact_mut(DIM).zip(&normalised).zip(roots).enumerate() {
        let recip = reciprocal_of_root(root).min(i32::MAX as i64);
        if left_rows & (1 << r) != 0 || recip >= 1 << 23 {
            left_rows |= 1 << r;
            continue;
        }
        if let Ok(o) = <&mut [i8; DIM]>::try_from(o) {
            output(n, (recip << 8) as i32, p.mult, 1 << (post - 1), post, o);
        }
    }
    left_rows
}

/// `isqrt_u64` of eight values at once: the same digit-by-digit steps in 64-bit lanes, from
/// the largest power of four below 2^64 (the steps above a value's own first bit leave its root
/// and remainder as they are).
#[inline]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
fn isqrt8(n: [u64; ROWS]) -> [u32; ROWS] {
    let mut rem: __m512i = must_cast(n);
    let mut root = _mm512_setzero_si512();
    let mut bit = _mm512_set1_epi64(1 << 62);
    for _ in 0..32 {
        let trial = _mm512_add_epi64(root, bit);
        let fits = _mm512_cmpge_epu64_mask(rem, trial);
        rem = _mm512_mask_sub_epi64(rem, fits, rem, trial);
        let half = _mm512_srli_epi64::<1>(root);
        root = _mm512_mask_add_epi64(half, fits, half, bit);
        bit = _mm512_srli_epi64::<2>(bit);
    }
    must_cast::<__m512i, [u64; ROWS]>(root).map(|r| r as u32)
}

/// `out = sat8((hi32(rnd_hi32(n * recip_q) * mult) + round) >> post)` (`scaled_requant_lanes`)
/// sixteen lanes a vector.
#[inline]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
fn output(n: &[__m512i; STEPS], recip_q: i32, mult: i32, round: i32, post: u32, out: &mut [i8; DIM]) {
    let (recip_q, mult, round) = (
        _mm512_set1_epi32(recip_q),
        _mm512_set1_epi32(mult),
        _mm512_set1_epi32(round),
    );
    let (half, post) = (_mm512_set1_epi64(1 << 31), _mm_cvtsi32_si128(post as i32));
    let mut v = [_mm512_setzero_si512(); STEPS];
    for (v, &y) in v.iter_mut().zip(n) {
        let even = _mm512_add_epi64(_mm512_mul_epi32(y, recip_q), half);
        let odd = _mm512_add_epi64(_mm512_mul_epi32(_mm512_srli_epi64::<32>(y), recip_q), half);
        let z = _mm512_mask_blend_epi32(0xAAAA, _mm512_srli_epi64::<32>(even), odd);
        let even = _mm512_mul_epi32(z, mult);
        let odd = _mm512_mul_epi32(_mm512_srli_epi64::<32>(z), mult);
        let high = _mm512_mask_blend_epi32(0xAAAA, _mm512_srli_epi64::<32>(even), odd);
        *v = _mm512_sra_epi32(_mm512_add_epi32(high, round), post);
    }
    let (first, second) = v.split_at(4);
    let bytes: [[[i8; LANES]; 4]; 2] = [pack4(first), pack4(second)];
    *out = must_cast(bytes);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fixed::isqrt_u64;
    use crate::testutil::Rng;

    #[test]
    fn eight_roots_at_once_equal_the_scalar_root() {
        if !crate::kernels::arch::x86::vnni::supported() {
            return;
        }
        let mut rng = Rng::new(61);
        let edges = [
            0,
            1,
            2,
            3,
            4,
            u64::MAX,
            i64::MAX as u64,
            (1 << 58) - 1,
            1 << 58,
            99_999_999_999,
        ];
        for trial in 0..2000 {
            let n: [u64; ROWS] = core::array::from_fn(|i| match (trial + i) % 4 {
                0 => edges[(trial + 3 * i) % edges.len()],
                1 => {
                    let r = rng.range(0, u32::MAX as i64) as u64;
                    (r * r).wrapping_add(rng.range(-1, 1) as u64)
                }
                _ => rng.range(0, i64::MAX) as u64 >> rng.range(0, 62),
            });
            // SAFETY: `supported()` saw the features `isqrt8` is compiled for.
            #[allow(unsafe_code)]
            let roots = unsafe { isqrt8(n) };
            assert_eq!(roots, n.map(isqrt_u64), "{n:?}");
        }
    }

    #[test]
    fn rows_equal_the_reference_and_declined_rows_are_left_alone() {
        if crate::kernels::arch::x86::vnni::supported() {
            crate::kernels::arch::x86::tests::check_layernorm_rows(on_this_cpu);
        }
    }

    // `rows` whatever the process-wide switch says (another test turns it off for a moment).
    fn on_this_cpu(p: &NormLanes<'_>, x: &[i8], out: &mut [i8]) -> Option<u8> {
        let fits = x.len() == out.len() && x.len().is_multiple_of(DIM) && x.len() <= ROWS * DIM;
        if !fits || !(33..=MAX_SHIFT).contains(&p.shift) {
            return None;
        }
        // SAFETY: the caller checked `supported()`.
        #[allow(unsafe_code)]
        Some(unsafe { rows_avx512(p, x, out) })
    }

    #[test]
    fn shapes_and_shifts_it_does_not_take_are_declined() {
        let zero = [0i32; DIM];
        let mut p = NormLanes {
            zero: &zero,
            rel: &zero,
            eps: 0,
            mult: 1 << 30,
            shift: 32,
        };
        let mut out = [1i8; 9 * DIM];
        assert_eq!(rows(&p, &[0; DIM], &mut out[..DIM]), None);
        p.shift = 40;
        assert_eq!(rows(&p, &[0; 9 * DIM], &mut out), None);
        assert_eq!(rows(&p, &[0; DIM + 1], &mut out[..DIM + 1]), None);
        assert_eq!(rows(&p, &[0; DIM], &mut out[..2 * DIM]), None);
        assert!(out.iter().all(|&b| b == 1));
    }
}
