//! The VNNI matrix multiply with the weights read in place, four bytes at a time as
//! broadcasts, against token rows transposed once per block: each `vpdpbusd` adds four
//! products to eight rows' sums of one channel, so no sum needs a horizontal reduction (the
//! 4 x 4 tiles of [`super::matmul_i32`] spent about a third of their time on those).
//!
//! The activations enter unsigned (`a ^ 0x80 = a + 128`), the weights signed, so channel `c`
//! comes out `128 * sum_k w[c][k]` too high: [`weight_sums`] computes that once for a pass,
//! and the products take it off again, exactly (every sum wraps modulo 2^32, as the portable
//! kernels' wrapping adds do).

use core::arch::x86_64::{
    __m256i, _mm256_castsi256_si128, _mm256_dpbusd_epi32, _mm256_extracti128_si256, _mm256_permute2x128_si256,
    _mm256_set1_epi32, _mm256_set1_epi8, _mm256_setzero_si256, _mm256_sub_epi32, _mm256_unpackhi_epi32,
    _mm256_unpackhi_epi64, _mm256_unpacklo_epi32, _mm256_unpacklo_epi64, _mm256_xor_si256, _mm_add_epi32,
    _mm_cvtsi128_si32, _mm_hadd_epi32,
};

use bytemuck::must_cast;

use super::{available, load, MAX_GEMM_K, STEP};

/// Token rows a block: one 32-bit lane each of a 256-bit vector.
pub const ROWS: usize = 8;
/// Channels a group: sixteen independent sums in flight.
const GROUP: usize = 16;
/// Channels of the last group where `n` is not a multiple of [`GROUP`].
const HALF_GROUP: usize = GROUP / 2;

/// Whether [`matmul_i32_summed`] takes `k` and `n`: the kernels run, `k` is a multiple of
/// [`STEP`] up to [`MAX_GEMM_K`] and `n` a multiple of eight.
pub fn takes(k: usize, n: usize) -> bool {
    k != 0 && k.is_multiple_of(STEP) && k <= MAX_GEMM_K && n != 0 && n.is_multiple_of(HALF_GROUP) && available()
}

/// `sums[c] = 128 * sum_k w[c][k]` (wrapping) for the `n = sums.len()` rows of `w` (`n x k`):
/// the correction [`matmul_i32_summed`] takes. `false` (nothing written) where it does not
/// take the shape.
pub fn weight_sums(w: &[i8], k: usize, sums: &mut [i32]) -> bool {
    let n = sums.len();
    if !takes(k, n) || n.checked_mul(k) != Some(w.len()) {
        return false;
    }
    // SAFETY: `available()` saw AVX-512 F/BW/VL/VNNI on this CPU, enabled by the OS.
    #[allow(unsafe_code)]
    unsafe {
        weight_sums_vnni(w, k, sums)
    };
    true
}

/// `out` (`m x n`) = `a` (`m x k`) times the transpose of `w` (`n x k`), as
/// `matmul::matmul_i8_reference` computes it, given `sums` = [`weight_sums`] of `w`. `false`
/// (nothing written) where it does not take `k` and `n` ([`takes`]) or the lengths differ.
pub fn matmul_i32_summed(a: &[i8], w: &[i8], k: usize, sums: &[i32], out: &mut [i32]) -> bool {
    let n = sums.len();
    if !takes(k, n) || n.checked_mul(k) != Some(w.len()) || !a.len().is_multiple_of(k) {
        return false;
    }
    if (a.len() / k).checked_mul(n) != Some(out.len()) {
        return false;
    }
    // SAFETY: as in `weight_sums`. The transposed block lives on the stack, sized for the
    // model's widths (zeroing a block for the longest `k` was 2 % of a pass).
    #[allow(unsafe_code)]
    unsafe {
        match k / 4 {
            0..=32 => matmul_summed::<32>(a, w, k, sums, out),
            33..=120 => matmul_summed::<120>(a, w, k, sums, out),
            _ => matmul_summed::<{ MAX_GEMM_K / 4 }>(a, w, k, sums, out),
        }
    };
    true
}

#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
fn weight_sums_vnni(w: &[i8], k: usize, sums: &mut [i32]) {
    // `vpdpbusd` of 128 (unsigned) and the weights: four `128 * w` a lane.
    let flip = _mm256_set1_epi8(-128);
    for (row, sum) in w.chunks_exact(k).zip(sums.iter_mut()) {
        let mut acc = _mm256_setzero_si256();
        for chunk in row.chunks_exact(STEP) {
            acc = _mm256_dpbusd_epi32(acc, flip, load(chunk));
        }
        let half = _mm_add_epi32(_mm256_castsi256_si128(acc), _mm256_extracti128_si256::<1>(acc));
        let pairs = _mm_hadd_epi32(half, half);
        *sum = _mm_cvtsi128_si32(_mm_hadd_epi32(pairs, pairs));
    }
}

// Row blocks of eight: the block transposed to `k / 4 <= G` vectors (lane `r`: row `r`'s four
// codes of that group, flipped to unsigned), then the channels sixteen (or eight) at a time.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
fn matmul_summed<const G: usize>(a: &[i8], w: &[i8], k: usize, sums: &[i32], out: &mut [i32]) {
    let n = sums.len();
    let mut groups = [_mm256_setzero_si256(); G];
    let Some(groups) = groups.get_mut(..k / 4) else {
        return;
    };
    for (a8, o8) in a.chunks(ROWS * k).zip(out.chunks_mut(ROWS * n)) {
        let rows = a8.len() / k;
        transpose_block(a8, k, groups);
        let whole = n / GROUP * GROUP;
        for (j, w16) in (0..whole).step_by(GROUP).zip(w.chunks_exact(GROUP * k)) {
            let acc = channels::<GROUP>(groups, w16);
            let (first, second) = acc.split_at(HALF_GROUP);
            store_rows(first, sums, j, o8, rows, n);
            store_rows(second, sums, j + HALF_GROUP, o8, rows, n);
        }
        if let Some(w8) = w.get(whole * k..(whole + HALF_GROUP) * k) {
            let acc = channels::<HALF_GROUP>(groups, w8);
            store_rows(&acc, sums, whole, o8, rows, n);
        }
    }
}

// The block's rows (up to eight, `k` codes each; missing rows read as zeros, their lanes
// unused) as `k / 4` vectors of eight rows' four codes, flipped to unsigned.
#[inline]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
fn transpose_block(a8: &[i8], k: usize, groups: &mut [__m256i]) {
    let flip = _mm256_set1_epi8(-128);
    for (s, out) in groups.chunks_exact_mut(8).enumerate() {
        let at = s * STEP;
        let rows: [__m256i; ROWS] = core::array::from_fn(|r| {
            let chunk = a8.get(r * k + at..r * k + at + STEP).unwrap_or(&[]);
            _mm256_xor_si256(load(chunk), flip)
        });
        out.copy_from_slice(&transpose8(rows));
    }
}

// Eight channels' (or sixteen's) sums over every group: lane `r` of `acc[c]` is row `r` times
// channel `c`, plus the flip's correction. Each channel's four codes of a group are one
// broadcast memory operand of its `vpdpbusd` (raw reads: checked slices cost a compare and a
// scalar load each, and the loop ran at a third of the speed). The model's two widths get
// their own copies, whose constant row offsets need no pointer per channel.
#[inline]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
fn channels<const C: usize>(groups: &[__m256i], wc: &[i8]) -> [__m256i; C] {
    match groups.len() {
        32 => channels_of::<C, 32>(groups, wc),
        120 => channels_of::<C, 120>(groups, wc),
        _ => channels_of::<C, 0>(groups, wc),
    }
}

// `channels` for rows of `G` groups (`0`: any, `groups.len()`).
#[inline]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
fn channels_of<const C: usize, const G: usize>(groups: &[__m256i], wc: &[i8]) -> [__m256i; C] {
    let count = if G == 0 { groups.len() } else { G };
    let mut acc = [_mm256_setzero_si256(); C];
    if groups.len() != count || wc.len() != C * 4 * count {
        return acc;
    }
    let base = wc.as_ptr();
    for (g, &x) in groups.iter().enumerate() {
        for (c, acc_c) in acc.iter_mut().enumerate() {
            // SAFETY: `c < C` and `g < count`, so the four bytes at `(c * count + g) * 4` lie
            // within `wc` (`C * count * 4` bytes, checked above).
            #[allow(unsafe_code)]
            let four = unsafe { base.add((c * count + g) * 4).cast::<i32>().read_unaligned() };
            *acc_c = _mm256_dpbusd_epi32(*acc_c, x, _mm256_set1_epi32(four));
        }
    }
    acc
}

// Eight channels' sums (`acc[c]`, lanes = rows) from channel `j` on, less their corrections,
// written to the block's `rows` output rows.
#[inline]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
fn store_rows(acc: &[__m256i], sums: &[i32], j: usize, o8: &mut [i32], rows: usize, n: usize) {
    let (Ok(acc), Some(corr)) = (
        <[__m256i; ROWS]>::try_from(acc),
        sums.get(j..j + ROWS).and_then(|s| <[i32; ROWS]>::try_from(s).ok()),
    ) else {
        return;
    };
    let corr: __m256i = must_cast(corr);
    for (r, row) in transpose8(acc).into_iter().enumerate().take(rows) {
        let values: [i32; ROWS] = must_cast(_mm256_sub_epi32(row, corr));
        if let Some(slot) = o8.get_mut(r * n + j..r * n + j + ROWS) {
            slot.copy_from_slice(&values);
        }
    }
}

/// The transpose of an 8 x 8 matrix of 32-bit lanes (vector `i`, lane `j` -> vector `j`,
/// lane `i`).
#[inline]
#[target_feature(enable = "avx2")]
fn transpose8(v: [__m256i; 8]) -> [__m256i; 8] {
    let t = [
        _mm256_unpacklo_epi32(v[0], v[1]),
        _mm256_unpackhi_epi32(v[0], v[1]),
        _mm256_unpacklo_epi32(v[2], v[3]),
        _mm256_unpackhi_epi32(v[2], v[3]),
        _mm256_unpacklo_epi32(v[4], v[5]),
        _mm256_unpackhi_epi32(v[4], v[5]),
        _mm256_unpacklo_epi32(v[6], v[7]),
        _mm256_unpackhi_epi32(v[6], v[7]),
    ];
    // Each 128-bit half holds lanes 0-3 (low) or 4-7 (high) of four source vectors.
    let s = [
        _mm256_unpacklo_epi64(t[0], t[2]),
        _mm256_unpackhi_epi64(t[0], t[2]),
        _mm256_unpacklo_epi64(t[1], t[3]),
        _mm256_unpackhi_epi64(t[1], t[3]),
        _mm256_unpacklo_epi64(t[4], t[6]),
        _mm256_unpackhi_epi64(t[4], t[6]),
        _mm256_unpacklo_epi64(t[5], t[7]),
        _mm256_unpackhi_epi64(t[5], t[7]),
    ];
    [
        _mm256_permute2x128_si256::<0x20>(s[0], s[4]),
        _mm256_permute2x128_si256::<0x20>(s[1], s[5]),
        _mm256_permute2x128_si256::<0x20>(s[2], s[6]),
        _mm256_permute2x128_si256::<0x20>(s[3], s[7]),
        _mm256_permute2x128_si256::<0x31>(s[0], s[4]),
        _mm256_permute2x128_si256::<0x31>(s[1], s[5]),
        _mm256_permute2x128_si256::<0x31>(s[2], s[6]),
        _mm256_permute2x128_si256::<0x31>(s[3], s[7]),
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::reference::matmul::matmul_i8_reference;
    use crate::testutil::Rng;

    #[test]
    fn broadcast_products_equal_the_reference() {
        if !available() {
            return; // `takes` is false: the callers run the other kernels (tested there)
        }
        let mut rng = Rng::new(57);
        let mut a = [0i8; 19 * 480];
        let mut w = [0i8; 40 * 480];
        let shapes = [
            (8, 8, 32),
            (8, 16, 128),
            (8, 24, 128),
            (1, 8, 32),
            (3, 40, 96),
            (19, 24, 480),
            (8, 32, 480),
            (13, 8, 64),
        ];
        for (case, (m, n, k)) in shapes.into_iter().enumerate() {
            rng.fill_i8(&mut a[..m * k]);
            rng.fill_i8(&mut w[..n * k]);
            // Edge codes: every extreme pairing, and a zero matrix.
            match case % 4 {
                1 => a[..m * k].fill(-128),
                2 => w[..n * k].fill(-128),
                3 => {
                    a[..m * k].fill(127);
                    w[..n * k].fill(-128);
                }
                _ => {}
            }
            let (a, w) = (&a[..m * k], &w[..n * k]);
            let mut sums = [0i32; 40];
            assert!(weight_sums(w, k, &mut sums[..n]));
            let mut got = [i32::MIN; 19 * 40];
            assert!(matmul_i32_summed(a, w, k, &sums[..n], &mut got[..m * n]), "{m}x{n}x{k}");
            let mut want = [0i32; 19 * 40];
            matmul_i8_reference(a, w, k, &mut want[..m * n]);
            assert_eq!(got[..m * n], want[..m * n], "{m}x{n}x{k}");
        }
    }

    #[test]
    fn shapes_it_does_not_take_are_declined_untouched() {
        let mut out = [7i32; 64];
        let mut sums = [3i32; 12];
        // n not a multiple of 8, k not a multiple of 32, lengths that differ.
        assert!(!weight_sums(&[1; 12 * 32], 32, &mut sums));
        assert!(!weight_sums(&[1; 8 * 16], 16, &mut sums[..8]));
        assert!(!matmul_i32_summed(&[1; 64], &[1; 12 * 32], 32, &sums, &mut out[..24]));
        assert!(!matmul_i32_summed(
            &[1; 64],
            &[1; 8 * 32],
            32,
            &sums[..8],
            &mut out[..24]
        ));
        assert!(!matmul_i32_summed(
            &[1; 65],
            &[1; 8 * 32],
            32,
            &sums[..8],
            &mut out[..16]
        ));
        assert!(!matmul_i32_summed(
            &[1; 64],
            &[1; 8 * 32],
            0,
            &sums[..8],
            &mut out[..16]
        ));
        assert_eq!(out, [7; 64]);
        assert_eq!(sums, [3; 12]);
    }
}
