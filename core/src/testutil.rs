//! The one test PRNG of the project: deterministic pseudo-random inputs (no dependencies, no
//! allocation, `no_std`), so a failure reproduces from its seed.
//!
//! Used by this crate's unit tests and, through the `testutil` feature (test code only, not an
//! API), by the workspace's integration tests (`tests/`) and the firmware's kernel tests
//! (`firmware-sim/src/bin/kernel-tests.rs`).

/// xorshift64* generator.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// A generator whose stream is fixed by `seed` (any value, 0 included).
    pub fn new(seed: u64) -> Self {
        Self(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1)
    }

    /// The next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    /// Uniform in `lo..=hi` (`lo <= hi`; the whole `i64` range takes the bits as they come).
    pub fn range(&mut self, lo: i64, hi: i64) -> i64 {
        let span = hi.wrapping_sub(lo).wrapping_add(1) as u64;
        let bits = self.next_u64();
        lo.wrapping_add(bits.checked_rem(span).unwrap_or(bits) as i64)
    }

    /// A random code in `-128..=127`.
    pub fn i8(&mut self) -> i8 {
        self.range(-128, 127) as i8
    }

    /// Random codes into every entry of `out`.
    pub fn fill_i8(&mut self, out: &mut [i8]) {
        for x in out {
            *x = self.i8();
        }
    }
}

/// A positive real factor as a [`crate::fixed::Requant`], the way the host quantiser makes it:
/// multiplier in `[2^30, 2^31)`. Unit tests only (floating point).
#[cfg(test)]
pub fn requant_of(real: f64) -> crate::fixed::Requant {
    let mut shift = 31i32;
    let mut m = real;
    while m < 0.5 {
        m *= 2.0;
        shift += 1;
    }
    while m >= 1.0 {
        m /= 2.0;
        shift -= 1;
    }
    let mult = (m * (1u64 << 31) as f64 + 0.5) as i64;
    crate::fixed::Requant {
        mult: mult.min(i32::MAX as i64) as i32,
        shift: shift as u32,
    }
}
