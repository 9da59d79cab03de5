//! RoPE's shared constants and one position's angles (Q14 cosines and sines).

use crate::config::HEAD_DIM;

/// Frequencies per half of a head: pairs `(i, i + QUARTER)`.
pub const QUARTER: usize = HEAD_DIM / 4;
/// Fraction bits of the cosine / sine tables.
pub const TRIG_FRAC_BITS: u32 = 14;
/// Extra fraction bits the accumulators keep through the rotation.
pub const PRE_ROPE_FRAC_BITS: u32 = 8;
/// Bound on pre-rotation values: keeps products far inside 64 bits whatever the parameters.
pub(crate) const PRE_ROPE_LIMIT: i64 = 1 << 24;

/// Cosines and sines (Q14) of one position's angles, one per frequency.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[repr(C)]
pub struct Angles {
    /// `round(cos(angle_i) * 2^14)`.
    pub cos: [i16; QUARTER],
    /// `round(sin(angle_i) * 2^14)`.
    pub sin: [i16; QUARTER],
}
