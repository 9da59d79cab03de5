//! The tensor inventory of a BINO int8 blob: which [`TensorId`]s exist and what they hold.
//! `docs/int8-model.md` documents every entry; `bino quantize` writes them.
//!
//! Residual formats: the residual stream is int8 with a per-channel format
//! `real = scale[c] * (q - zero[c])`. Format `s` is the stream after embedding (`s = 0`), after
//! block `b`'s attention (`s = 2b + 1`) and after its MLP (`s = 2b + 2`).

use crate::blob::TensorId;
use crate::config::DEPTH;

/// Tensor kinds (the high 16 bits of a [`TensorId`]).
pub mod kind {
    /// `u16[CONFIG_LEN]`: the model configuration the blob was made for (see [`super::ConfigField`]).
    pub const CONFIG: u16 = 1;
    /// `i8[out x in]`: a linear layer's weights, one output channel per row.
    pub const LINEAR_WEIGHT: u16 = 10;
    /// `i32[out]` (embedding: `i32[rows x out]`, with the row embedding): bias in accumulator units.
    pub const LINEAR_BIAS: u16 = 11;
    /// `i32[out]`: requantisation multipliers of the layer's output.
    pub const LINEAR_MULT: u16 = 12;
    /// `u8[out]`: requantisation shifts of the layer's output.
    pub const LINEAR_SHIFT: u16 = 13;
    /// `i32[DIM]`: zero points of residual format `index`.
    pub const RESIDUAL_ZERO: u16 = 20;
    /// `i32[DIM]`: scales of residual format `index` in a common unit (for LayerNorm).
    pub const RESIDUAL_REL: u16 = 21;
    /// `i32[DIM]`: multipliers from residual format `index` to `index + 1`.
    pub const CARRY_MULT: u16 = 22;
    /// `u8[DIM]`: shifts from residual format `index` to `index + 1`.
    pub const CARRY_SHIFT: u16 = 23;
    /// `i64[3]`: LayerNorm `index`: epsilon (input unit squared), output multiplier, shift.
    pub const LAYERNORM: u16 = 30;
    /// `i32[HEADS x 4]`: block `index`'s attention per head: score-to-log2 mult, shift,
    /// output mult, shift.
    pub const ATTENTION: u16 = 31;
    /// `i8[256]`: block `index`'s GELU from fc1 output codes to fc2 input codes.
    pub const GELU_TABLE: u16 = 32;
    /// `i16[BAND_TOKEN_ROWS x 2 QUARTER]`: RoPE cosines then sines (Q14) per token row.
    pub const ROPE_ROWS: u16 = 33;
    /// `i16[max patch columns x 2 QUARTER]`: RoPE cosines then sines (Q14) per patch column.
    pub const ROPE_COLS: u16 = 34;
    /// `u16[1]`: token rows either side of its own that a query attends to; absent: every
    /// row of the band. The engine runs 0 (each token row attends within itself).
    pub const ATTENTION_ROWS: u16 = 35;
    /// `i32[DIM]`: descriptor multipliers (final residual format to Q8 descriptor codes).
    pub const DESC_MULT: u16 = 40;
    /// `u8[DIM]`: descriptor shifts.
    pub const DESC_SHIFT: u16 = 41;
    /// `i32[BAND_TOKEN_ROWS x DIM]`: the row embedding in Q8 descriptor codes (de-positioning).
    pub const DESC_ROW_OFFSET: u16 = 42;
    /// `i32[2]`: the head's correlation requantisation (mult, shift).
    pub const HEAD_CORRELATION: u16 = 50;
    /// `i32[2 x HEAD_MIDDLE_LAYERS]`: per middle layer, the residual carry (mult, shift).
    pub const HEAD_CARRY: u16 = 51;
    /// `i32[HEAD_CONVS]`: zero points of the conv layers' inputs (correlation, hidden formats).
    pub const HEAD_ZERO: u16 = 52;
    /// `i32[2]`: logit accumulator gap to Q8 log2 units (mult, shift) for the head's softmax.
    pub const HEAD_SOFTMAX: u16 = 53;
    /// `f32[DIM]`: scales of residual format `index` (host tools only; never read by the engine).
    pub const META_RESIDUAL_SCALE: u16 = 60;
    /// `f32[1]`: the descriptor scale (host tools only).
    pub const META_DESC_SCALE: u16 = 61;
    /// `f32[1]`: real logit per unit of the head's output accumulator (host tools only).
    pub const META_HEAD_LOGIT_SCALE: u16 = 62;
}

/// Positions in the [`kind::CONFIG`] tensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u16)]
pub enum ConfigField {
    /// Token channels.
    Dim = 0,
    /// Transformer blocks.
    Depth,
    /// Attention heads.
    Heads,
    /// MLP hidden width.
    MlpHidden,
    /// Token rows of a band (row-embedding entries).
    BandTokenRows,
    /// Widest input the RoPE table covers, in patch columns.
    MaxPatchCols,
    /// Head projection channels.
    HeadProjDim,
    /// Head correlation groups.
    HeadGroups,
    /// Head hidden channels.
    HeadHidden,
    /// Head residual middle layers.
    HeadMiddleLayers,
    /// Head disparity candidates.
    HeadMaxDisp,
}

/// Length of the [`kind::CONFIG`] tensor.
pub const CONFIG_LEN: usize = 11;

/// The linear layers of the model (index of the `LINEAR_*` kinds).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Linear {
    /// Patch embedding (4x4 fused patch, channels folded): `DIM x 16`.
    Embed,
    /// Block `b`'s query/key/value projection: `3 DIM x DIM`.
    Qkv(usize),
    /// Block `b`'s attention output projection: `DIM x DIM`.
    Proj(usize),
    /// Block `b`'s first MLP layer: `MLP_HIDDEN x DIM`.
    Fc1(usize),
    /// Block `b`'s second MLP layer: `DIM x MLP_HIDDEN`.
    Fc2(usize),
    /// The head's shared projection: `HEAD_PROJ_DIM x DIM` (its LayerNorm's affine folded in).
    HeadProj,
    /// The head's 3D convolution `i` (0 stem, 1..=4 middle, 5 output): `out x 27 in`,
    /// kernel positions ordered (row, disparity, column), channels innermost.
    HeadConv(usize),
    /// The native head's left projection `P_L`: `NATIVE_HEAD_PROJ_DIM x 2 DIM` (its
    /// LayerNorm's affine folded in).
    NativeProjLeft,
    /// The native head's right projection `P_R`, as [`Linear::NativeProjLeft`].
    NativeProjRight,
    /// The native head's 3D convolution `i`, as [`Linear::HeadConv`].
    NativeConv(usize),
}

impl Linear {
    /// Index of this layer in tensor ids.
    pub const fn index(self) -> u16 {
        let i = match self {
            Linear::Embed => 0,
            Linear::Qkv(b) => 1 + 4 * b,
            Linear::Proj(b) => 2 + 4 * b,
            Linear::Fc1(b) => 3 + 4 * b,
            Linear::Fc2(b) => 4 + 4 * b,
            Linear::HeadProj => HEAD_LINEAR_BASE,
            Linear::HeadConv(i) => HEAD_LINEAR_BASE + 1 + i,
            Linear::NativeProjLeft => NATIVE_LINEAR_BASE,
            Linear::NativeProjRight => NATIVE_LINEAR_BASE + 1,
            Linear::NativeConv(i) => NATIVE_LINEAR_BASE + 2 + i,
        };
        i as u16
    }

    /// The id of this layer's tensor of `kind` (one of the `LINEAR_*` kinds).
    pub const fn id(self, kind: u16) -> TensorId {
        TensorId::new(kind, self.index())
    }
}

/// Linear-layer index of the head's projection; its convolutions follow.
pub const HEAD_LINEAR_BASE: usize = 100;
/// The head's 3D convolutions: stem, middle layers, output.
pub const HEAD_CONVS: usize = crate::config::HEAD_MIDDLE_LAYERS + 2;
/// LayerNorm index of the head's input normalisation.
pub const HEAD_LAYERNORM: usize = 100;
/// Linear-layer index of the native head's left projection; its right projection and its
/// convolutions follow.
pub const NATIVE_LINEAR_BASE: usize = 110;
/// LayerNorm index of the native head's pair-feature normalisation.
pub const NATIVE_LAYERNORM: usize = 101;

/// The two stereo heads a blob may hold. The per-head scalar tensors (`HEAD_CORRELATION`,
/// `HEAD_CARRY`, `HEAD_ZERO`, `HEAD_SOFTMAX`, `META_HEAD_LOGIT_SCALE`) take [`HeadKind::index`]
/// as their index.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HeadKind {
    /// The shared head of the export pathway: descriptor maps D(L), D(R) of two encoder
    /// passes on (L, L) and (R, R), one LayerNorm + projection for both.
    Export,
    /// The native pathway's head: the fused grid of one pass on (L, R), pair features
    /// `u = [a, b]` (the two phase tokens of a patch column), one LayerNorm, projections
    /// `P_L`, `P_R`.
    Native,
}

impl HeadKind {
    /// Index of this head's scalar tensors.
    pub const fn index(self) -> usize {
        match self {
            HeadKind::Export => 0,
            HeadKind::Native => 1,
        }
    }

    /// LayerNorm index of the head's input normalisation.
    pub const fn layernorm(self) -> usize {
        match self {
            HeadKind::Export => HEAD_LAYERNORM,
            HeadKind::Native => NATIVE_LAYERNORM,
        }
    }

    /// The head's 3D convolution `i`.
    pub const fn conv(self, i: usize) -> Linear {
        match self {
            HeadKind::Export => Linear::HeadConv(i),
            HeadKind::Native => Linear::NativeConv(i),
        }
    }

    /// Channels of one input cell: a descriptor, or the pair feature `[a, b]`.
    pub const fn input_dim(self) -> usize {
        match self {
            HeadKind::Export => crate::config::DIM,
            HeadKind::Native => 2 * crate::config::DIM,
        }
    }

    /// Channels of each projected feature map.
    pub const fn proj_dim(self) -> usize {
        match self {
            HeadKind::Export => crate::config::HEAD_PROJ_DIM,
            HeadKind::Native => crate::config::NATIVE_HEAD_PROJ_DIM,
        }
    }

    /// The pathway's name, as the CLI spells it.
    pub const fn pathway(self) -> &'static str {
        match self {
            HeadKind::Export => "export",
            HeadKind::Native => "native",
        }
    }
}

/// The head a tensor belongs to, `None` for the encoder's (and the blob's configuration): what
/// a blob for one pathway can leave out of the other's.
pub const fn head_of(id: TensorId) -> Option<HeadKind> {
    let index = id.index() as usize;
    match id.kind() {
        kind::LINEAR_WEIGHT | kind::LINEAR_BIAS | kind::LINEAR_MULT | kind::LINEAR_SHIFT => {
            if index >= HEAD_LINEAR_BASE && index < HEAD_LINEAR_BASE + 1 + HEAD_CONVS {
                Some(HeadKind::Export)
            } else if index >= NATIVE_LINEAR_BASE && index < NATIVE_LINEAR_BASE + 2 + HEAD_CONVS {
                Some(HeadKind::Native)
            } else {
                None
            }
        }
        kind::LAYERNORM if index == HEAD_LAYERNORM => Some(HeadKind::Export),
        kind::LAYERNORM if index == NATIVE_LAYERNORM => Some(HeadKind::Native),
        kind::HEAD_CORRELATION
        | kind::HEAD_CARRY
        | kind::HEAD_ZERO
        | kind::HEAD_SOFTMAX
        | kind::META_HEAD_LOGIT_SCALE => match index {
            0 => Some(HeadKind::Export),
            1 => Some(HeadKind::Native),
            _ => None,
        },
        _ => None,
    }
}

/// Residual format after embedding.
pub const fn residual_after_embed() -> usize {
    0
}

/// Residual format after block `b`'s attention.
pub const fn residual_after_attention(b: usize) -> usize {
    2 * b + 1
}

/// Residual format after block `b`'s MLP (the block's output).
pub const fn residual_after_block(b: usize) -> usize {
    2 * b + 2
}

/// Number of residual formats.
pub const RESIDUAL_FORMATS: usize = 2 * DEPTH + 1;

/// LayerNorm ids: block `b`'s first (before attention) and second (before the MLP).
pub const fn layernorm_index(b: usize, second: bool) -> usize {
    2 * b + second as usize
}

/// Tensor id of kind `kind` and a `usize` index (indices here are all far below 2^16).
pub const fn id(kind: u16, index: usize) -> TensorId {
    TensorId::new(kind, index as u16)
}

#[cfg(test)]
mod tests {
    #[test]
    fn every_head_tensor_belongs_to_its_head_and_the_encoders_to_none() {
        use super::*;
        for head in [HeadKind::Export, HeadKind::Native] {
            let convs = (0..HEAD_CONVS).map(|i| head.conv(i));
            let projections = match head {
                HeadKind::Export => [Some(Linear::HeadProj), None],
                HeadKind::Native => [Some(Linear::NativeProjLeft), Some(Linear::NativeProjRight)],
            };
            for layer in convs.chain(projections.into_iter().flatten()) {
                for k in [
                    kind::LINEAR_WEIGHT,
                    kind::LINEAR_BIAS,
                    kind::LINEAR_MULT,
                    kind::LINEAR_SHIFT,
                ] {
                    assert_eq!(head_of(layer.id(k)), Some(head), "{layer:?}");
                }
            }
            assert_eq!(head_of(id(kind::LAYERNORM, head.layernorm())), Some(head));
            for k in [
                kind::HEAD_CORRELATION,
                kind::HEAD_CARRY,
                kind::HEAD_ZERO,
                kind::HEAD_SOFTMAX,
            ] {
                assert_eq!(head_of(id(k, head.index())), Some(head));
            }
            assert_eq!(head_of(id(kind::META_HEAD_LOGIT_SCALE, head.index())), Some(head));
        }
        for b in 0..DEPTH {
            for layer in [Linear::Qkv(b), Linear::Proj(b), Linear::Fc1(b), Linear::Fc2(b)] {
                assert_eq!(head_of(layer.id(kind::LINEAR_WEIGHT)), None);
            }
            assert_eq!(head_of(id(kind::LAYERNORM, layernorm_index(b, true))), None);
        }
        assert_eq!(head_of(Linear::Embed.id(kind::LINEAR_BIAS)), None);
        assert_eq!(head_of(id(kind::CONFIG, 0)), None);
        assert_eq!(head_of(id(kind::HEAD_ZERO, 2)), None);
    }

    use super::*;
    use crate::config::HEAD_MIDDLE_LAYERS;

    /// Every linear layer of the encoder and both heads has its own index, so a blob can hold
    /// both heads beside the encoder without one tensor standing for two.
    #[test]
    fn linear_indices_are_unique_across_the_encoder_and_both_heads() {
        let mut indices = [0u16; 64];
        let mut count = 0;
        let mut add = |layer: Linear| {
            indices[count] = layer.index();
            count += 1;
        };
        for layer in [
            Linear::Embed,
            Linear::HeadProj,
            Linear::NativeProjLeft,
            Linear::NativeProjRight,
        ] {
            add(layer);
        }
        for b in 0..DEPTH {
            for layer in [Linear::Qkv(b), Linear::Proj(b), Linear::Fc1(b), Linear::Fc2(b)] {
                add(layer);
            }
        }
        for i in 0..HEAD_MIDDLE_LAYERS + 2 {
            add(HeadKind::Export.conv(i));
            add(HeadKind::Native.conv(i));
        }
        let used = &mut indices[..count];
        used.sort_unstable();
        assert!(used.windows(2).all(|w| w[0] < w[1]), "{used:?}");
        assert_ne!(HeadKind::Export.layernorm(), HeadKind::Native.layernorm());
        assert!(HeadKind::Export.layernorm() > layernorm_index(DEPTH - 1, true));
        assert_ne!(HeadKind::Export.index(), HeadKind::Native.index());
    }
}
