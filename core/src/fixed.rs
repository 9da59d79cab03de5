//! Fixed-point arithmetic of the int8 path: requantisation, saturation, integer square root.
//!
//! Every real-valued factor of the int8 graph (a ratio of quantisation scales) is stored as
//! a [`Requant`]: an integer multiplier and a right shift, `x * mult / 2^shift`, rounded half
//! up. The quantiser on the host chooses them; here they are only applied, so host and
//! firmware compute bit-identical results without a floating-point unit.

/// The largest right shift a [`Requant`] may use; 62 keeps `1 << (shift - 1)` inside `i64`.
pub const MAX_SHIFT: u32 = 62;

/// A real factor `mult / 2^shift` applied to integers, rounding half up.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Requant {
    /// Integer multiplier (the quantiser keeps it in `[2^30, 2^31)` for full precision).
    pub mult: i32,
    /// Right shift, `1..=MAX_SHIFT`.
    pub shift: u32,
}

impl Requant {
    /// A factor, or `None` when the shift is out of range (a corrupt parameter).
    pub const fn new(mult: i32, shift: u32) -> Option<Self> {
        if shift == 0 || shift > MAX_SHIFT {
            None
        } else {
            Some(Self { mult, shift })
        }
    }

    /// `round(x * mult / 2^shift)` in 64 bits, saturating (never reached for 32-bit `x`).
    #[inline(always)]
    pub fn apply_i64(self, x: i64) -> i64 {
        let product = x.saturating_mul(self.mult as i64);
        let half = 1i64 << (self.shift.wrapping_sub(1) & 63);
        product.saturating_add(half) >> (self.shift & 63)
    }

    /// [`Requant::apply_i64`] of a 32-bit accumulator, saturated to `i32`.
    #[inline(always)]
    pub fn apply(self, x: i32) -> i32 {
        clamp_i32(self.apply_i64(x as i64))
    }
}

/// Saturates to the int8 range.
#[inline(always)]
pub fn sat_i8(x: i32) -> i8 {
    x.clamp(i8::MIN as i32, i8::MAX as i32) as i8
}

/// Saturates to the int8 range, from 64 bits.
#[inline(always)]
pub fn sat_i8_i64(x: i64) -> i8 {
    x.clamp(i8::MIN as i64, i8::MAX as i64) as i8
}

/// Saturates to the `i32` range.
#[inline(always)]
pub fn clamp_i32(x: i64) -> i32 {
    x.clamp(i32::MIN as i64, i32::MAX as i64) as i32
}

/// `round(x / 2^shift)`, rounding half up; `shift` of 0 returns `x`, above 62 returns 0.
#[inline(always)]
pub fn round_shift(x: i64, shift: u32) -> i64 {
    match shift {
        0 => x,
        1..=MAX_SHIFT => x.saturating_add(1i64 << (shift - 1)) >> shift,
        _ => 0,
    }
}

/// Floor of the square root of a 64-bit unsigned integer (digit-by-digit, no division).
pub fn isqrt_u64(n: u64) -> u32 {
    let mut rem = n;
    let mut root: u64 = 0;
    // Highest power of four not above n (0 for n = 0: the loop below is then skipped).
    let mut bit: u64 = if n == 0 {
        0
    } else {
        1 << ((63 - n.leading_zeros()) & !1)
    };
    while bit != 0 {
        if rem >= root + bit {
            rem -= root + bit;
            root = (root >> 1) + bit;
        } else {
            root >>= 1;
        }
        bit >>= 2;
    }
    root as u32
}

/// Number of significant bits of `|x|` (0 for 0).
#[inline(always)]
pub fn bit_length(x: u64) -> u32 {
    64 - x.leading_zeros()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requant_rounds_half_up() {
        let Some(half) = Requant::new(1 << 30, 31) else {
            panic!("valid requant rejected")
        };
        assert_eq!(half.apply(5), 3); // 2.5 -> 3
        assert_eq!(half.apply(-5), -2); // -2.5 -> -2
        assert_eq!(half.apply(4), 2);
        assert_eq!(half.apply(i32::MAX), 1 << 30);
    }

    #[test]
    fn requant_rejects_bad_shifts() {
        assert!(Requant::new(1, 0).is_none());
        assert!(Requant::new(1, 63).is_none());
        assert!(Requant::new(1, 62).is_some());
    }

    #[test]
    fn requant_extremes_do_not_panic() {
        for mult in [i32::MIN, -1, 0, 1, i32::MAX] {
            for shift in [1, 31, 62] {
                let Some(r) = Requant::new(mult, shift) else {
                    panic!("valid requant rejected")
                };
                for x in [i32::MIN, -1, 0, 1, i32::MAX] {
                    let _ = r.apply(x);
                }
            }
        }
    }

    #[test]
    fn isqrt_is_floor_sqrt() {
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        for i in 0..2000u64 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let n = if i < 1000 { i } else { state >> (i % 64) };
            let r = isqrt_u64(n) as u64;
            assert!(r * r <= n, "{n}: {r}");
            assert!((r + 1) * (r + 1) > n, "{n}: {r}");
        }
        assert_eq!(isqrt_u64(u64::MAX), u32::MAX);
    }

    #[test]
    fn round_shift_matches_division() {
        assert_eq!(round_shift(7, 1), 4);
        assert_eq!(round_shift(-7, 1), -3);
        assert_eq!(round_shift(7, 0), 7);
        assert_eq!(round_shift(i64::MAX, 64), 0);
    }
}
