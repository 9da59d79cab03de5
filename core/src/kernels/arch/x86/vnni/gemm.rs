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
    __m256i, __m512i, _mm256_castsi256_si128, _mm256_dpbusd_epi32, _mm256_extracti128_si256, _mm256_permute2x128_si256,
    _mm256_set1_epi32, _mm256_set1_epi8, _mm256_setzero_si256, _mm256_sub_epi32, _mm256_unpackhi_epi32,
    _mm256_unpackhi_epi64, _mm256_unpacklo_epi32, _mm256_unpacklo_epi64, _mm256_xor_si256, _mm512_add_epi32,
    _mm512_and_si512, _mm512_castsi256_si512, _mm512_inserti64x4, _mm512_mask_blend_epi32, _mm512_mul_epi32,
    _mm512_packs_epi16, _mm512_packs_epi32, _mm512_permutexvar_epi32, _mm512_set1_epi32, _mm512_set_epi32,
    _mm512_setzero_si512, _mm512_srav_epi32, _mm512_srli_epi64, _mm512_sub_epi32, _mm512_unpackhi_epi32,
    _mm512_unpackhi_epi64, _mm512_unpacklo_epi32, _mm512_unpacklo_epi64, _mm_add_epi32, _mm_cvtsi128_si32,
    _mm_hadd_epi32,
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

/// `out` (`m x n` int8) = the prepared columns `words` (`Col` records, one per row of `w`)
/// applied to [`matmul_i32_summed`]'s products, requantised in registers sixteen channels at a
/// time (no accumulator buffer). `false` (nothing written) where it does not take the shape
/// (`n` a multiple of sixteen, besides [`takes`]) or the lengths differ. The prepared columns'
/// identity needs accumulators within `2^30`: with `k <= MAX_GEMM_K` they stay within
/// `1024 * 2^14 = 2^24`.
pub fn matmul_requant_summed(a: &[i8], w: &[i8], k: usize, sums: &[i32], words: &[[i32; 4]], out: &mut [i8]) -> bool {
    let n = sums.len();
    if !takes(k, n) || !n.is_multiple_of(GROUP) || words.len() != n || n.checked_mul(k) != Some(w.len()) {
        return false;
    }
    if !a.len().is_multiple_of(k) || (a.len() / k).checked_mul(n) != Some(out.len()) {
        return false;
    }
    // SAFETY: as in `weight_sums`.
    #[allow(unsafe_code)]
    unsafe {
        match k / 4 {
            0..=32 => requant_summed::<32>(a, w, k, sums, words, out),
            33..=120 => requant_summed::<120>(a, w, k, sums, words, out),
            _ => requant_summed::<{ MAX_GEMM_K / 4 }>(a, w, k, sums, words, out),
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

// `matmul_summed` with each group's sums requantised in registers: the rows of sixteen
// channels from two 8 x 8 transposes, less their corrections, through `Requant16`; four rows'
// bytes packed together.
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
fn requant_summed<const G: usize>(a: &[i8], w: &[i8], k: usize, sums: &[i32], words: &[[i32; 4]], out: &mut [i8]) {
    let n = sums.len();
    let mut groups = [_mm256_setzero_si256(); G];
    let Some(groups) = groups.get_mut(..k / 4) else {
        return;
    };
    for (a8, o8) in a.chunks(ROWS * k).zip(out.chunks_mut(ROWS * n)) {
        let rows = a8.len() / k;
        transpose_block(a8, k, groups);
        let params = w
            .chunks_exact(GROUP * k)
            .zip(sums.chunks_exact(GROUP))
            .zip(words.chunks_exact(GROUP));
        for (q, ((w16, s16), cols)) in params.enumerate() {
            let (Ok(s16), Ok(cols)) = (<[i32; GROUP]>::try_from(s16), <&[[i32; 4]; GROUP]>::try_from(cols)) else {
                continue;
            };
            let acc = channels::<GROUP>(groups, w16);
            let (first, second) = acc.split_at(HALF_GROUP);
            let (Ok(first), Ok(second)) = (<[__m256i; ROWS]>::try_from(first), <[__m256i; ROWS]>::try_from(second))
            else {
                continue;
            };
            let (low, high) = (transpose8(first), transpose8(second));
            let corr: __m512i = must_cast(s16);
            let rq = Requant16::new(cols);
            let values: [__m512i; ROWS] = core::array::from_fn(|r| {
                rq.apply(_mm512_sub_epi32(
                    _mm512_inserti64x4::<1>(_mm512_castsi256_si512(low[r]), high[r]),
                    corr,
                ))
            });
            let bytes: [[[i8; GROUP]; 4]; 2] = [pack4(&values[..4]), pack4(&values[4..])];
            for (r, row) in bytes.as_flattened().iter().enumerate().take(rows) {
                if let Some(slot) = o8.get_mut(r * n + q * GROUP..r * n + (q + 1) * GROUP) {
                    slot.copy_from_slice(row);
                }
            }
        }
    }
}

/// Sixteen channels' prepared columns (`Col`'s bias, multiplier, addend and shift) in lanes.
struct Requant16 {
    bias: __m512i,
    mult: __m512i,
    addend: __m512i,
    s: __m512i,
}

impl Requant16 {
    // The records transposed: after the two unpacks, dword `4 L + i` of a field holds channel
    // `4 i + L`; one `vpermd` a field puts channel `c` in dword `c`.
    #[inline]
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
    fn new(cols: &[[i32; 4]; GROUP]) -> Self {
        let flat: &[[i32; GROUP]; 4] = bytemuck::must_cast_ref(cols);
        let v: [__m512i; 4] = flat.map(must_cast);
        let (t0, t1) = (_mm512_unpacklo_epi32(v[0], v[1]), _mm512_unpackhi_epi32(v[0], v[1]));
        let (t2, t3) = (_mm512_unpacklo_epi32(v[2], v[3]), _mm512_unpackhi_epi32(v[2], v[3]));
        let natural = _mm512_set_epi32(15, 11, 7, 3, 14, 10, 6, 2, 13, 9, 5, 1, 12, 8, 4, 0);
        let field = |x| _mm512_permutexvar_epi32(natural, x);
        Requant16 {
            bias: field(_mm512_unpacklo_epi64(t0, t2)),
            mult: field(_mm512_unpackhi_epi64(t0, t2)),
            addend: field(_mm512_unpacklo_epi64(t1, t3)),
            // `Col::from_words`' mask.
            s: _mm512_and_si512(field(_mm512_unpackhi_epi64(t1, t3)), _mm512_set1_epi32(31)),
        }
    }

    // `Col::apply(acc + bias)` before saturation: `(hi32((acc + bias) * mult) + addend) >> s`.
    #[inline]
    #[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
    fn apply(&self, acc: __m512i) -> __m512i {
        let x = _mm512_add_epi32(acc, self.bias);
        let even = _mm512_mul_epi32(x, self.mult);
        let odd = _mm512_mul_epi32(_mm512_srli_epi64::<32>(x), _mm512_srli_epi64::<32>(self.mult));
        let high = _mm512_mask_blend_epi32(0xAAAA, _mm512_srli_epi64::<32>(even), odd);
        _mm512_srav_epi32(_mm512_add_epi32(high, self.addend), self.s)
    }
}

// Four vectors of sixteen 32-bit values to bytes, saturated (the portable clamp to -128..=127):
// the packs interleave their 128-bit lanes, one `vpermd` restores the order.
#[inline]
#[target_feature(enable = "avx2,avx512f,avx512bw,avx512vl,avx512vnni")]
pub(super) fn pack4(v: &[__m512i]) -> [[i8; GROUP]; 4] {
    let zero = _mm512_setzero_si512();
    let at = |i: usize| v.get(i).copied().unwrap_or(zero);
    let unlane = _mm512_set_epi32(15, 11, 7, 3, 14, 10, 6, 2, 13, 9, 5, 1, 12, 8, 4, 0);
    let words = (_mm512_packs_epi32(at(0), at(1)), _mm512_packs_epi32(at(2), at(3)));
    must_cast(_mm512_permutexvar_epi32(unlane, _mm512_packs_epi16(words.0, words.1)))
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

    // The kernels themselves, where the CPU has them: the process-wide switch (`enable`) is
    // turned off for a moment by another test, and the entry points would decline then.
    fn sums_of(w: &[i8], k: usize, sums: &mut [i32]) {
        // SAFETY: the callers checked `supported()`.
        #[allow(unsafe_code)]
        unsafe {
            weight_sums_vnni(w, k, sums)
        }
    }

    fn products(a: &[i8], w: &[i8], k: usize, sums: &[i32], out: &mut [i32]) {
        // SAFETY: as in `sums_of`.
        #[allow(unsafe_code)]
        unsafe {
            matmul_summed::<{ MAX_GEMM_K / 4 }>(a, w, k, sums, out)
        }
    }

    fn requantised(a: &[i8], w: &[i8], k: usize, sums: &[i32], words: &[[i32; 4]], out: &mut [i8]) {
        // SAFETY: as in `sums_of`.
        #[allow(unsafe_code)]
        unsafe {
            requant_summed::<{ MAX_GEMM_K / 4 }>(a, w, k, sums, words, out)
        }
    }

    #[test]
    fn broadcast_products_equal_the_reference() {
        if !crate::kernels::arch::x86::vnni::supported() {
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
            sums_of(w, k, &mut sums[..n]);
            let mut got = [i32::MIN; 19 * 40];
            products(a, w, k, &sums[..n], &mut got[..m * n]);
            let mut want = [0i32; 19 * 40];
            matmul_i8_reference(a, w, k, &mut want[..m * n]);
            assert_eq!(got[..m * n], want[..m * n], "{m}x{n}x{k}");
        }
    }

    #[test]
    fn requantised_in_registers_equals_the_reference() {
        use crate::kernels::dispatch::ChannelRequant;
        use crate::kernels::reference::gemm::matmul_requant_reference;
        use crate::kernels::types::prepared::PreparedRequant;
        if !crate::kernels::arch::x86::vnni::supported() {
            return;
        }
        let mut rng = Rng::new(58);
        let mut a = [0i8; 19 * 480];
        let mut w = [0i8; 480 * 128];
        let shapes = [
            (8, 128, 128),
            (8, 480, 128),
            (19, 16, 480),
            (5, 32, 64),
            (1, 48, 32),
            (8, 128, 480),
        ];
        for (case, (m, n, k)) in shapes.into_iter().enumerate() {
            rng.fill_i8(&mut a[..m * k]);
            rng.fill_i8(&mut w[..n * k]);
            match case % 3 {
                1 => {
                    a[..m * k].fill(-128);
                    w[..n * k].fill(-128);
                }
                2 => a[..m * k].fill(127),
                _ => {}
            }
            let (a, w) = (&a[..m * k], &w[..n * k]);
            // Parameters over the prepared columns' whole range.
            let bias: [i32; 480] = core::array::from_fn(|_| rng.range(-(1 << 30) + 1, (1 << 30) - 1) as i32);
            let mult: [i32; 480] = core::array::from_fn(|_| rng.range(i32::MIN as i64, i32::MAX as i64) as i32);
            // Shifts up to 54: `2^(s-1) + zero * 2^s` (s = shift - 32) stays within 2^30.
            let shift: [u8; 480] = core::array::from_fn(|i| [33, 54, 40, 47][i % 4]);
            let zero: [i32; 480] = core::array::from_fn(|_| rng.range(-128, 127) as i32);
            let rq = ChannelRequant {
                bias: &bias[..n],
                mult: &mult[..n],
                shift: &shift[..n],
            };
            let mut storage = [0i32; 4 * 480];
            let prepared = PreparedRequant::new(&rq, &zero[..n], &mut storage).expect("columns in range");
            let mut sums = [0i32; 480];
            sums_of(w, k, &mut sums[..n]);
            let mut got = [0i8; 19 * 480];
            requantised(a, w, k, &sums[..n], prepared.records(), &mut got[..m * n]);
            let mut want = [0i8; 19 * 480];
            matmul_requant_reference(a, w, k, &rq, &zero[..n], &mut want[..m * n]);
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
        // The requantised products: channels not a multiple of sixteen, a short output.
        let (words, mut bytes) = ([[0, 1, 0, 1]; 24], [5i8; 64]);
        assert!(!matmul_requant_summed(
            &[1; 64],
            &[1; 24 * 32],
            32,
            &[0; 24],
            &words,
            &mut bytes[..48]
        ));
        assert!(!matmul_requant_summed(
            &[1; 64],
            &[1; 16 * 32],
            32,
            &[0; 16],
            &words[..16],
            &mut bytes[..31]
        ));
        assert_eq!(bytes, [5; 64]);
    }
}
