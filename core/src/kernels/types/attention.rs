//! Attention's parameters, block size and key layouts.

use crate::fixed::Requant;

/// Fraction bits of the normalised weighted average before the output factor.
pub const AVG_FRAC_BITS: u32 = 16;

/// Quantisation parameters of one head's attention.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AttentionQ {
    /// Score gap (int32 units of `q . k`) to Q8 base-2 units: folds the q and k scales,
    /// `1/sqrt(head_dim)` and `log2(e)`.
    pub to_log2_q8: Requant,
    /// Q16 weighted average of value codes to output codes (`value scale / output scale / 2^16`).
    pub out: Requant,
}

/// Queries attended together by `dispatch::attend_block`: each key and value is read once per block.
pub const QUERY_BLOCK: usize = 4;

/// How a head's keys are stored: as rows for `dispatch::attend_block` (every core), transposed for the
/// x86 VNNI kernels and in code pairs for the x86 AVX2 ones (`dispatch::attend_block_keys`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KeyLayout {
    /// Token by token, `HEAD_DIM` codes each (every core).
    Rows,
    /// Blocks of eight tokens transposed into groups of four codes, flipped to unsigned
    /// (`dispatch::store_key`; x86 hosts with AVX-512 VNNI, where `dispatch::key_layout` picks it).
    Transposed,
    /// Blocks of sixteen tokens in code pairs: group `p` (32 bytes) holds codes `2p, 2p + 1` of
    /// each token of the block in turn (`dispatch::store_key`; x86 hosts with AVX2 but not
    /// AVX-512 VNNI, where `dispatch::key_layout` picks it).
    Paired,
}

/// Tokens per block of [`KeyLayout::Paired`].
pub const PAIR_BLOCK: usize = 16;

/// Byte of code `d` of token `t` in a head's store of [`KeyLayout::Paired`].
#[inline(always)]
pub const fn paired_offset(t: usize, d: usize) -> usize {
    t / PAIR_BLOCK * PAIR_BLOCK * crate::config::HEAD_DIM + d / 2 * 2 * PAIR_BLOCK + t % PAIR_BLOCK * 2 + d % 2
}
