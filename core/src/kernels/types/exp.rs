//! Integer exponentials for softmax: `exp(-x)` of a non-negative score gap, as unsigned 8 bits.
//!
//! The gap between a score and its row maximum is mapped to base-2 units in Q8 fixed point by
//! one [`Requant`] (it folds the quantisation scales, `1/sqrt(head_dim)` and `log2(e)`); the
//! integer part becomes a shift, the fraction goes through a cubic for `2^(-f/256)`. The cubic
//! (not a table lookup) keeps the function branch-free, so a softmax over a row of scores
//! vectorises; it is within 0.52 LSB of `255 * 2^(-x/256)` and equals the 256-entry table
//! [`EXP2_NEG_Q15`] rounding everywhere but one input.

use crate::fixed::Requant;

/// `round(2^(-f/256) * 2^15)` for `f` in `0..256`.
pub const EXP2_NEG_Q15: [u16; 256] = [
    32768, 32679, 32591, 32503, 32415, 32327, 32240, 32153, 32066, 31979, 31893, 31806, 31720, 31635, 31549, 31464,
    31379, 31294, 31209, 31125, 31041, 30957, 30873, 30790, 30706, 30623, 30541, 30458, 30376, 30293, 30212, 30130,
    30048, 29967, 29886, 29805, 29725, 29644, 29564, 29484, 29405, 29325, 29246, 29167, 29088, 29009, 28931, 28852,
    28774, 28697, 28619, 28542, 28464, 28388, 28311, 28234, 28158, 28082, 28006, 27930, 27855, 27779, 27704, 27629,
    27554, 27480, 27406, 27332, 27258, 27184, 27110, 27037, 26964, 26891, 26818, 26746, 26674, 26601, 26530, 26458,
    26386, 26315, 26244, 26173, 26102, 26031, 25961, 25891, 25821, 25751, 25681, 25612, 25543, 25474, 25405, 25336,
    25268, 25199, 25131, 25063, 24995, 24928, 24860, 24793, 24726, 24659, 24593, 24526, 24460, 24394, 24328, 24262,
    24196, 24131, 24066, 24001, 23936, 23871, 23806, 23742, 23678, 23614, 23550, 23486, 23423, 23359, 23296, 23233,
    23170, 23108, 23045, 22983, 22921, 22859, 22797, 22735, 22674, 22613, 22552, 22491, 22430, 22369, 22309, 22248,
    22188, 22128, 22068, 22009, 21949, 21890, 21831, 21772, 21713, 21654, 21595, 21537, 21479, 21421, 21363, 21305,
    21247, 21190, 21133, 21076, 21019, 20962, 20905, 20849, 20792, 20736, 20680, 20624, 20568, 20513, 20457, 20402,
    20347, 20292, 20237, 20182, 20127, 20073, 20019, 19965, 19911, 19857, 19803, 19750, 19696, 19643, 19590, 19537,
    19484, 19431, 19379, 19326, 19274, 19222, 19170, 19118, 19066, 19015, 18963, 18912, 18861, 18810, 18759, 18708,
    18658, 18607, 18557, 18507, 18457, 18407, 18357, 18308, 18258, 18209, 18160, 18110, 18061, 18013, 17964, 17915,
    17867, 17819, 17770, 17722, 17674, 17627, 17579, 17531, 17484, 17437, 17390, 17343, 17296, 17249, 17202, 17156,
    17109, 17063, 17017, 16971, 16925, 16879, 16834, 16788, 16743, 16697, 16652, 16607, 16562, 16518, 16473, 16428,
];

/// Gaps at or beyond this many Q8 base-2 units give weight 0.
const EXP2_ZERO_FROM: u32 = 23 * 256;
/// `2^(-f/256) * 2^15 ~ C0 - f(C1 - f(C2 - f C3))` with each product shifted by 8: the
/// minimax cubic, its coefficients tuned in the last digit against the exact function.
pub(crate) const C0: u32 = 32768;
pub(crate) const C1: u32 = 22657;
pub(crate) const C2: u32 = 7566;
pub(crate) const C3: u32 = 1295;

/// `round(255 * 2^(-x/256))` (within 0.52) for `x >= 0` in Q8 base-2 units; 255 for
/// negative `x`, 0 from `x >= 23 * 256`.
#[inline(always)]
pub fn exp2_neg_u8(x: i64) -> u8 {
    exp2_neg_u8_q8(x.clamp(0, EXP2_ZERO_FROM as i64) as u32)
}

/// [`exp2_neg_u8`] for `x` in `0..=23 * 256`, branch-free.
#[inline(always)]
const fn exp2_neg_u8_q8(x: u32) -> u8 {
    let whole = x >> 8;
    let f = x & 255;
    // Every intermediate is positive and below 2^24.
    let t = (C3 * f) >> 8;
    let t = ((C2 - t) * f) >> 8;
    let t = ((C1 - t) * f) >> 8;
    let scaled = (C0 - t) * 255;
    (((scaled >> whole) + (1 << 14)) >> 15) as u8
}

/// From this Q8 base-2 input on, [`exp2_neg_u8`] is 0: `255 * 2^15 >> 9` rounds to 0.
pub const EXP2_TABLE_LAST: u32 = 9 * 256;

/// `exp2_neg_u8(x)` for `x` in `0..=EXP2_TABLE_LAST` (the last entry 0): one byte load in
/// place of the cubic on cores without a vector unit, and the gather table of the Helium
/// softmax (`kernels::arch::mve`). Built from the cubic, so it equals it by construction.
pub static EXP2_NEG_U8_TABLE: [u8; EXP2_TABLE_LAST as usize + 1] = {
    let mut t = [0u8; EXP2_TABLE_LAST as usize + 1];
    let mut x = 0;
    while x < t.len() {
        t[x] = exp2_neg_u8_q8(x as u32);
        x += 1;
    }
    t
};

/// [`EXP2_NEG_U8_TABLE`] minus 128, as int8: the weights as the attention's weighted sums store
/// them (`w ^ 0x80`), so the Helium softmax gathers them sign-extended and stores them as they
/// come (the row's sum is then the lanes' sum plus `128 * n`).
#[cfg_attr(not(any(bino_mve, test)), allow(dead_code))]
pub static EXP2_NEG_I8_TABLE: [i8; EXP2_TABLE_LAST as usize + 1] = {
    let mut t = [0i8; EXP2_TABLE_LAST as usize + 1];
    let mut x = 0;
    while x < t.len() {
        t[x] = (exp2_neg_u8_q8(x as u32) ^ 0x80) as i8;
        x += 1;
    }
    t
};

/// [`EXP2_NEG_U8_TABLE`] continued to 4,096 entries (weight 0 from [`EXP2_TABLE_LAST`] on): the
/// Cortex-M7 softmax clamps its index with one `usat #12` instead of a compare and a
/// conditional move.
#[cfg_attr(not(any(bino_dsp, test)), allow(dead_code))]
pub static EXP2_NEG_U8_TABLE_4K: [u8; 4096] = {
    let mut t = [0u8; 4096];
    let mut x = 0;
    while x < t.len() {
        let q = if x < EXP2_TABLE_LAST as usize {
            x as u32
        } else {
            EXP2_TABLE_LAST
        };
        t[x] = exp2_neg_u8_q8(q);
        x += 1;
    }
    t
};

/// `exp(-gap * scale)` as `0..=255`, where `to_log2_q8` turns a score gap into Q8 base-2 units.
#[inline(always)]
pub fn exp_neg_u8(gap: i64, to_log2_q8: Requant) -> u8 {
    exp2_neg_u8(to_log2_q8.apply_i64(gap))
}

/// [`exp_neg_u8`] for a non-negative 32-bit gap, as plain 64-bit arithmetic without
/// saturation (exact: `gap * mult < 2^63`), so a loop over a row of gaps vectorises.
/// `to_log2_q8.shift` must be in `1..=62`, as every [`Requant`] is.
#[inline(always)]
pub fn exp_neg_u8_u32(gap: u32, to_log2_q8: Requant) -> u8 {
    let mult = to_log2_q8.mult.max(0) as u64;
    let shift = to_log2_q8.shift & 63;
    let half = 1u64 << (shift.wrapping_sub(1) & 63);
    let x = (gap as u64 * mult + half) >> shift;
    exp2_neg_u8_q8(x.min(EXP2_ZERO_FROM as u64) as u32)
}

/// Largest score gap [`ExpQ32`] accepts: twice the largest `|q . k|` of `HEAD_DIM` int8 pairs.
pub const EXP_Q32_MAX_GAP: u32 = 1 << 20;

/// [`exp_neg_u8_u32`] prepared for gaps up to [`EXP_Q32_MAX_GAP`], in 32-bit arithmetic only
/// (one high-half multiply), so a softmax row vectorises on cores without 64-bit lanes (MVE).
///
/// With `P = (gap << pre) * mult` and `s = shift + pre >= 33`, `(gap * mult + 2^(shift-1)) >>
/// shift` equals `(P + 2^(s-1)) >> s` (numerator and denominator scaled by `2^pre`), and that
/// equals `(hi(P) + 2^(s-33)) >> (s-32)` because the low word of `P` only adds a fraction below
/// one to an integer numerator. `gap << pre < 2^32` needs `pre <= 11`: shifts from 22 up.
/// `hi(P)` is assembled from 16-bit halves (no partial sum reaches 2^32), because LLVM's loop
/// vectoriser does not vectorise a 64-bit product (MVE has no 64-bit lanes).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ExpQ32 {
    pre: u32,
    mult_hi: u32,
    mult_lo: u32,
    round: u32,
    post: u32,
}

impl ExpQ32 {
    /// The prepared factor, or `None` for shifts below 22 (callers use [`exp_neg_u8_u32`]).
    pub fn new(to_log2_q8: Requant) -> Option<Self> {
        let shift = to_log2_q8.shift;
        if !(22..=crate::fixed::MAX_SHIFT).contains(&shift) {
            return None;
        }
        let pre = 33u32.saturating_sub(shift);
        let s = shift + pre;
        let mult = to_log2_q8.mult.max(0) as u32;
        Some(Self {
            pre,
            mult_hi: mult >> 16,
            mult_lo: mult & 0xFFFF,
            round: 1 << (s - 33),
            post: s - 32,
        })
    }

    /// `exp_neg_u8_u32(gap, to_log2_q8)` for `gap <= EXP_Q32_MAX_GAP` (larger gaps are clamped
    /// there, which only the exact path could tell apart).
    #[inline(always)]
    pub fn weight(&self, gap: u32) -> u8 {
        let g = gap.min(EXP_Q32_MAX_GAP) << (self.pre & 15);
        // g <= 2^31 and mult < 2^31: g_hi <= 2^15, mult_hi < 2^15, so `mid` <= 2^32 - 2^16.
        let (g_hi, g_lo) = (g >> 16, g & 0xFFFF);
        let mid = g_hi * self.mult_lo + g_lo * self.mult_hi + ((g_lo * self.mult_lo) >> 16);
        let hi = g_hi * self.mult_hi + (mid >> 16);
        let x = (hi + self.round) >> (self.post & 31);
        exp2_neg_u8_q8(x.min(EXP2_ZERO_FROM))
    }

    /// [`ExpQ32::weight`] through one 32 x 32 -> 64-bit multiply (`umull`) and
    /// [`EXP2_NEG_U8_TABLE`]: fewer instructions on cores with a 64-bit product but no vector
    /// unit (Cortex-M7), where the cubic's four multiplies run one element at a time.
    #[inline(always)]
    pub fn weight_by_table(&self, gap: u32) -> u8 {
        let g = gap.min(EXP_Q32_MAX_GAP) << (self.pre & 15);
        let hi = ((g as u64 * self.mult() as u64) >> 32) as u32;
        let x = (hi + self.round) >> (self.post & 31);
        EXP2_NEG_U8_TABLE
            .get(x.min(EXP2_TABLE_LAST) as usize)
            .copied()
            .unwrap_or(0)
    }

    /// The multiplier (`< 2^31`), whole.
    #[inline(always)]
    pub fn mult(&self) -> u32 {
        (self.mult_hi << 16) | self.mult_lo
    }

    /// `(pre, round, post)`: the left shift of the gap (`0..=11`), the rounding term added to
    /// the product's high word and the right shift after it (`1..=30`), for the kernels that
    /// compute [`ExpQ32::weight`] in assembly.
    #[inline(always)]
    pub fn shifts(&self) -> (u32, u32, u32) {
        (self.pre & 15, self.round, self.post & 31)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounding_term_is_half_the_divisor_for_every_shift() {
        // The Helium softmax row relies on it (one `vrshl` for the add and the shift).
        for shift in 22..=crate::fixed::MAX_SHIFT {
            let e = ExpQ32::new(Requant { mult: 1 << 30, shift }).unwrap();
            let (_, round, post) = e.shifts();
            assert!(post >= 1 && round == 1 << (post - 1), "shift {shift}");
        }
    }

    #[test]
    fn cubic_follows_the_table_rounding() {
        let mut differ = 0;
        for x in 0..EXP2_ZERO_FROM {
            let (whole, frac) = (x >> 8, (x & 255) as usize);
            let table = (((EXP2_NEG_Q15[frac] as u32 * 255) >> whole) + (1 << 14)) >> 15;
            let got = exp2_neg_u8(x as i64) as u32;
            assert!(got.abs_diff(table) <= 1, "{x}");
            differ += (got != table) as u32;
        }
        assert!(differ <= 1, "{differ} inputs differ from the table");
    }

    #[test]
    fn u32_gap_path_equals_the_saturating_one() {
        let mut rng = crate::testutil::Rng::new(5);
        for (mult, shift) in [
            (1 << 30, 31),
            (1_500_000_000, 36),
            (1_073_741_824, 20),
            (2_000_000_000, 45),
        ] {
            let r = Requant { mult, shift };
            for _ in 0..2000 {
                let gap = ((rng.next_u64() as u32) >> (rng.next_u64() % 31)) as i64;
                assert_eq!(exp_neg_u8_u32(gap as u32, r), exp_neg_u8(gap, r), "{gap} {r:?}");
            }
            assert_eq!(exp_neg_u8_u32(u32::MAX, r), exp_neg_u8(u32::MAX as i64, r));
        }
    }

    #[test]
    fn q32_path_equals_the_u64_one() {
        let mut rng = crate::testutil::Rng::new(17);
        for shift in 22..=62u32 {
            for mult in [1 << 30, 1_433_499_224, 1_997_098_146, i32::MAX, 1, 0] {
                let r = Requant { mult, shift };
                let Some(e) = ExpQ32::new(r) else {
                    panic!("shift {shift} rejected")
                };
                for i in 0..300u32 {
                    let gap = match i {
                        0 => 0,
                        1 => EXP_Q32_MAX_GAP,
                        2 => EXP_Q32_MAX_GAP - 1,
                        _ => (rng.next_u64() as u32) >> (12 + i % 20),
                    };
                    assert_eq!(e.weight(gap), exp_neg_u8_u32(gap, r), "{gap} {r:?}");
                }
            }
        }
        assert!(ExpQ32::new(Requant {
            mult: 1 << 30,
            shift: 21
        })
        .is_none());
    }

    #[test]
    fn byte_table_equals_the_cubic_everywhere() {
        for x in 0..=EXP2_ZERO_FROM + 300 {
            let want = exp2_neg_u8(x as i64);
            if x >= EXP2_TABLE_LAST {
                assert_eq!(want, 0, "{x}: the table's last entry must stand for every larger input");
            } else {
                assert_eq!(EXP2_NEG_U8_TABLE[x as usize], want, "{x}");
            }
        }
        assert_eq!(EXP2_NEG_U8_TABLE[EXP2_TABLE_LAST as usize], 0);
        for (&w, &o) in EXP2_NEG_U8_TABLE.iter().zip(&EXP2_NEG_I8_TABLE) {
            assert_eq!(o as i32, w as i32 - 128);
        }
        // The bound is tight: the entry before it is not 0.
        assert!(EXP2_NEG_U8_TABLE[..EXP2_TABLE_LAST as usize]
            .iter()
            .rev()
            .take(256)
            .any(|&w| w > 0));
    }

    #[test]
    fn table_path_equals_the_cubic_path() {
        let mut rng = crate::testutil::Rng::new(23);
        for shift in 22..=62u32 {
            for mult in [1 << 30, 1_433_499_224, 1_997_098_146, i32::MAX, 1, 0] {
                let e = ExpQ32::new(Requant { mult, shift }).expect("shift >= 22");
                let (pre, _, post) = e.shifts();
                assert!(pre <= 11 && (1..=30).contains(&post), "{shift}: {pre} {post}");
                for i in 0..400u32 {
                    let gap = match i {
                        0 => 0,
                        1 => EXP_Q32_MAX_GAP,
                        2 => u32::MAX,
                        _ => (rng.next_u64() as u32) >> (i % 32),
                    };
                    assert_eq!(e.weight_by_table(gap), e.weight(gap), "{gap} {mult} {shift}");
                }
            }
        }
    }

    #[test]
    fn table_is_exp2() {
        for (f, &t) in EXP2_NEG_Q15.iter().enumerate() {
            let want = libm_exp2(-(f as f64) / 256.0) * 32768.0;
            assert!((t as f64 - want).abs() <= 0.5, "{f}");
        }
    }

    #[test]
    fn exp2_neg_u8_within_one_lsb() {
        for x in (0..(24 * 256)).step_by(7) {
            let want = 255.0 * libm_exp2(-(x as f64) / 256.0);
            let got = exp2_neg_u8(x) as f64;
            assert!((got - want).abs() <= 1.0, "{x}: {got} vs {want}");
        }
        assert_eq!(exp2_neg_u8(0), 255);
        assert_eq!(exp2_neg_u8(-5), 255);
        assert_eq!(exp2_neg_u8(i64::MAX), 0);
    }

    /// 2^x for tests without std's float functions: a short series is exact enough here.
    fn libm_exp2(x: f64) -> f64 {
        let mut whole = x as i64;
        if whole as f64 > x {
            whole -= 1;
        }
        let frac = x - whole as f64;
        // e^(frac ln 2) by Taylor series (|frac ln2| < 0.7: 20 terms are exact to 1e-16).
        let y = frac * core::f64::consts::LN_2;
        let (mut term, mut sum) = (1.0f64, 1.0f64);
        for i in 1..20 {
            term *= y / i as f64;
            sum += term;
        }
        let mut p = 1.0f64;
        let mut w = whole;
        while w < 0 {
            p /= 2.0;
            w += 1;
        }
        while w > 0 {
            p *= 2.0;
            w -= 1;
        }
        sum * p
    }
}
