//! LayerNorm's parameters and the fraction bits its stages share.

use super::params::I32s;
use crate::fixed::Requant;

/// `z` is carried in Q16 between the division and the output factor.
pub const Z_FRAC_BITS: u32 = 16;

/// Parameters of one integer LayerNorm.
#[derive(Clone, Copy)]
pub struct LayerNormQ<'p, Z: I32s + ?Sized, R: I32s + ?Sized> {
    /// Input zero points per channel.
    pub zero: &'p Z,
    /// Input scales per channel in a common unit.
    pub rel: &'p R,
    /// LayerNorm epsilon in the common unit squared.
    pub eps: i64,
    /// `1 / (output scale * 2^16)`: from the Q16 normalised value to int8.
    pub out: Requant,
}
