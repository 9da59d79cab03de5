//! Requantisation to int8 in 32-bit lanes, eight channels per step: the identity of
//! [`NarrowChunk`] and of the prepared columns ([`Col`]): for `|acc| < 2^30` and `|bias| < 2^30`,
//! `sat8(rq(acc) + zero) = sat8((hi32((acc + bias) * mult) + addend) >> s)`.

use bytemuck::must_cast;
use core::arch::x86_64::{
    __m256i, _mm256_add_epi32, _mm256_and_si256, _mm256_blend_epi32, _mm256_max_epi32, _mm256_min_epi32,
    _mm256_mul_epi32, _mm256_or_si256, _mm256_permutevar8x32_epi32, _mm256_set1_epi32, _mm256_setr_epi32,
    _mm256_setr_epi8, _mm256_setzero_si256, _mm256_shuffle_epi8, _mm256_srav_epi32, _mm256_srli_epi64,
    _mm256_unpackhi_epi32, _mm256_unpackhi_epi64, _mm256_unpacklo_epi32, _mm256_unpacklo_epi64,
};

use crate::kernels::types::prepared::Col;
use crate::kernels::types::requant::NarrowChunk;

/// One row of a requantisation chunk in 32-bit lanes ([`NarrowChunk`]'s identity), eight
/// channels per step: `false` where an accumulator lies outside `-2^30..2^30` or the lengths
/// differ (then `out` may be partly written: the caller runs the 64-bit formula on the row).
pub(crate) fn requant_row_narrow(c: &NarrowChunk, acc: &[i32], out: &mut [i8]) -> bool {
    let len = c.len;
    if acc.len() != len || out.len() != len || !crate::kernels::arch::x86::avx2() {
        return false;
    }
    // SAFETY: `avx2()` saw AVX2 on this CPU. The kernel itself only reads and writes through
    // safe slices.
    #[allow(unsafe_code)]
    let in_range = unsafe { requant_narrow_avx2(c, acc, out) };
    let whole = len / 8 * 8;
    let params = c.bias.iter().zip(&c.mult).zip(c.addend.iter().zip(&c.s)).skip(whole);
    let mut tail_in_range = true;
    for ((o, &a), ((&b, &m), (&addend, &s))) in out.iter_mut().zip(acc).skip(whole).zip(params) {
        tail_in_range &= (-(1 << 30)..1 << 30).contains(&a);
        // |a|, |b| < 2^30 where it matters, so neither sum wraps (see `NarrowChunk`).
        let high = ((a.wrapping_add(b) as i64 * m as i64) >> 32) as i32;
        *o = (high.wrapping_add(addend) >> (s & 31)).clamp(-128, 127) as i8;
    }
    in_range && tail_in_range
}

/// Rows of accumulators (`acc`, `m x n` for the `n` prepared columns `words`, bias not yet
/// added) to int8 (`out`, `m x n`), each output [`Col::apply`] of its accumulator plus the bias:
/// `false` where the lengths differ, the CPU lacks AVX2 or an accumulator lies outside
/// `-2^30..2^30` (then `out` may be partly written: the caller recomputes it).
pub(crate) fn requant_prepared(words: &[[i32; 4]], acc: &[i32], out: &mut [i8]) -> bool {
    let n = words.len();
    if n == 0 || acc.len() != out.len() || !acc.len().is_multiple_of(n) || !crate::kernels::arch::x86::avx2() {
        return false;
    }
    // SAFETY: `avx2()` saw AVX2 on this CPU. The kernel only reads and writes through safe
    // slices.
    #[allow(unsafe_code)]
    let in_range = unsafe { requant_prepared_avx2(words, acc, out) };
    let whole = n / 8 * 8;
    let mut tail_in_range = true;
    for (acc_row, out_row) in acc.chunks_exact(n).zip(out.chunks_exact_mut(n)) {
        let tail = acc_row.iter().zip(out_row.iter_mut()).zip(words).skip(whole);
        for ((&a, o), w) in tail {
            tail_in_range &= (-(1 << 30)..1 << 30).contains(&a);
            let col = Col::from_words(w);
            *o = col.apply(a.wrapping_add(col.bias));
        }
    }
    in_range && tail_in_range
}

/// Eight channels' parameters in lanes.
struct Lanes {
    bias: __m256i,
    mult: __m256i,
    addend: __m256i,
    s: __m256i,
}

/// The constants of [`Lanes::apply`].
struct Pack {
    pick: __m256i,
    join: __m256i,
    lo: __m256i,
    hi: __m256i,
    bound: __m256i,
}

impl Pack {
    #[inline]
    #[target_feature(enable = "avx2")]
    fn new() -> Self {
        Self {
            // Byte 0 of each 32-bit lane to the low four bytes of its 128-bit half, then the
            // two halves' low words side by side.
            pick: _mm256_setr_epi8(
                0, 4, 8, 12, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, -1, 0, 4, 8, 12, -1, -1, -1, -1, -1, -1, -1,
                -1, -1, -1, -1, -1,
            ),
            join: _mm256_setr_epi32(0, 4, 0, 0, 0, 0, 0, 0),
            lo: _mm256_set1_epi32(-128),
            hi: _mm256_set1_epi32(127),
            bound: _mm256_set1_epi32(1 << 30),
        }
    }
}

impl Lanes {
    /// Eight int8 outputs of eight accumulators; `outside` gets the sign bit of a lane whose
    /// accumulator lies outside `-2^30..2^30` (`acc + 2^30` is negative exactly there).
    #[inline]
    #[target_feature(enable = "avx2")]
    fn apply(&self, a: __m256i, k: &Pack, outside: &mut __m256i) -> [i8; 8] {
        *outside = _mm256_or_si256(*outside, _mm256_add_epi32(a, k.bound));
        let x = _mm256_add_epi32(a, self.bias);
        // High halves of the eight 64-bit products: even lanes, then odd lanes.
        let even = _mm256_mul_epi32(x, self.mult);
        let odd = _mm256_mul_epi32(_mm256_srli_epi64::<32>(x), _mm256_srli_epi64::<32>(self.mult));
        let high = _mm256_blend_epi32::<0b1010_1010>(_mm256_srli_epi64::<32>(even), odd);
        let v = _mm256_srav_epi32(_mm256_add_epi32(high, self.addend), self.s);
        let v = _mm256_min_epi32(_mm256_max_epi32(v, k.lo), k.hi);
        let bytes = _mm256_permutevar8x32_epi32(_mm256_shuffle_epi8(v, k.pick), k.join);
        let words: [u64; 4] = must_cast(bytes);
        words[0].to_le_bytes().map(|b| b as i8)
    }
}

#[inline(always)]
fn lanes(v: &[i32]) -> __m256i {
    must_cast(<[i32; 8]>::try_from(v).unwrap_or([0; 8]))
}

/// The whole steps of eight of [`requant_row_narrow`]; `false` if an accumulator among them
/// lies outside `-2^30..2^30` (their outputs are then wrong: the caller recomputes the row).
#[target_feature(enable = "avx2")]
fn requant_narrow_avx2(c: &NarrowChunk, acc: &[i32], out: &mut [i8]) -> bool {
    let k = Pack::new();
    let mut outside = _mm256_setzero_si256();
    let params = c
        .bias
        .chunks_exact(8)
        .zip(c.mult.chunks_exact(8))
        .zip(c.addend.chunks_exact(8).zip(c.s.chunks_exact(8)));
    for ((o, a), ((b, m), (addend, s))) in out.chunks_exact_mut(8).zip(acc.chunks_exact(8)).zip(params) {
        let p = Lanes {
            bias: lanes(b),
            mult: lanes(m),
            addend: lanes(addend),
            s: lanes(s),
        };
        o.copy_from_slice(&p.apply(lanes(a), &k, &mut outside));
    }
    let outside: [i32; 8] = must_cast(outside);
    outside.iter().all(|&f| f >= 0)
}

/// The whole steps of eight columns of [`requant_prepared`], every row of a step on its
/// columns' parameters (transposed from the records once); `false` if an accumulator among
/// them lies outside `-2^30..2^30`.
#[target_feature(enable = "avx2")]
fn requant_prepared_avx2(words: &[[i32; 4]], acc: &[i32], out: &mut [i8]) -> bool {
    let n = words.len();
    let k = Pack::new();
    // The transpose below leaves channel `i` of eight in lane [0, 2, 4, 6, 1, 3, 5, 7][i].
    let natural = _mm256_setr_epi32(0, 4, 1, 5, 2, 6, 3, 7);
    let low_five = _mm256_set1_epi32(31);
    let mut outside = _mm256_setzero_si256();
    for (step, cols) in words.chunks_exact(8).enumerate() {
        let flat = cols.as_flattened();
        let v: [__m256i; 4] = core::array::from_fn(|i| lanes(flat.get(8 * i..8 * i + 8).unwrap_or(&[])));
        // Records (bias, mult, addend, s) two per vector to one vector per field.
        let (t0, t1) = (_mm256_unpacklo_epi32(v[0], v[1]), _mm256_unpackhi_epi32(v[0], v[1]));
        let (t2, t3) = (_mm256_unpacklo_epi32(v[2], v[3]), _mm256_unpackhi_epi32(v[2], v[3]));
        let field = |x| _mm256_permutevar8x32_epi32(x, natural);
        let p = Lanes {
            bias: field(_mm256_unpacklo_epi64(t0, t2)),
            mult: field(_mm256_unpackhi_epi64(t0, t2)),
            addend: field(_mm256_unpacklo_epi64(t1, t3)),
            // `Col::from_words`' mask.
            s: _mm256_and_si256(field(_mm256_unpackhi_epi64(t1, t3)), low_five),
        };
        let at = 8 * step;
        for (acc_row, out_row) in acc.chunks_exact(n).zip(out.chunks_exact_mut(n)) {
            let (Some(a), Some(o)) = (acc_row.get(at..at + 8), out_row.get_mut(at..at + 8)) else {
                continue;
            };
            o.copy_from_slice(&p.apply(lanes(a), &k, &mut outside));
        }
    }
    let outside: [i32; 8] = must_cast(outside);
    outside.iter().all(|&f| f >= 0)
}
