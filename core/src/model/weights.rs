//! Typed, validated views of the encoder's tensors in a blob (zero-copy: they borrow it).

use super::ids::{self, kind, ConfigField, Linear, CONFIG_LEN, RESIDUAL_FORMATS};
use crate::blob::{Blob, BlobError, Le, TensorId};
use crate::config::{BAND_TOKEN_ROWS, DEPTH, DIM, HEADS, HEAD_GROUPS, HEAD_HIDDEN, HEAD_MAX_DISP};
use crate::config::{HEAD_MIDDLE_LAYERS, HEAD_PROJ_DIM, MLP_HIDDEN, PATCH_H, PATCH_W};
use crate::fixed::{Requant, MAX_SHIFT};
use crate::kernels::dispatch::AttentionQ;
use crate::kernels::dispatch::LayerNormQ;
use crate::kernels::dispatch::{Angles, QUARTER};
use crate::kernels::dispatch::{ChannelRequant, ChannelRescale};
use crate::Error;

/// Inputs of the patch embedding: one 4x4 patch of the fused image, channels folded.
pub const EMBED_INPUTS: usize = PATCH_H * PATCH_W;

/// A linear layer: int8 weights (one output channel per row) and its output requantisation.
#[derive(Clone, Copy)]
pub struct LinearQ<'w> {
    /// `out x in` weights.
    pub weight: &'w [i8],
    /// Bias in accumulator units (`out`, or `rows x out` for the embedding).
    pub bias: Le<'w, i32>,
    /// Output multipliers.
    pub mult: Le<'w, i32>,
    /// Output shifts.
    pub shift: &'w [u8],
}

impl<'w> LinearQ<'w> {
    pub(crate) fn load(
        blob: &Blob<'w>,
        layer: Linear,
        outputs: usize,
        inputs: usize,
        bias_len: usize,
    ) -> Result<Self, Error> {
        Ok(Self {
            weight: blob.i8s(layer.id(kind::LINEAR_WEIGHT), outputs * inputs)?,
            bias: blob.i32s(layer.id(kind::LINEAR_BIAS), bias_len)?,
            mult: blob.i32s(layer.id(kind::LINEAR_MULT), outputs)?,
            shift: checked_shifts(blob, layer.id(kind::LINEAR_SHIFT), outputs)?,
        })
    }

    /// The output requantisation of all channels.
    pub fn requant(&self) -> ChannelRequant<'_, Le<'w, i32>, Le<'w, i32>> {
        ChannelRequant {
            bias: &self.bias,
            mult: &self.mult,
            shift: self.shift,
        }
    }
}

/// One per-channel int8 format of the residual stream.
#[derive(Clone, Copy)]
pub struct ResidualFormat<'w> {
    /// Zero points.
    pub zero: Le<'w, i32>,
    /// Scales in a common unit (LayerNorm input).
    pub rel: Le<'w, i32>,
}

/// Moving the residual stream from one format to the next.
#[derive(Clone, Copy)]
pub struct Carry<'w> {
    /// Multipliers.
    pub mult: Le<'w, i32>,
    /// Shifts.
    pub shift: &'w [u8],
}

/// A LayerNorm's scalars.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LayerNormScalars {
    /// Epsilon in the input unit squared.
    pub eps: i64,
    /// Normalised (Q16) to output codes.
    pub out: Requant,
}

impl LayerNormScalars {
    /// The kernel parameters for an input in `format`.
    pub fn with_input<'p, 'w>(&self, format: &'p ResidualFormat<'w>) -> LayerNormQ<'p, Le<'w, i32>, Le<'w, i32>> {
        LayerNormQ {
            zero: &format.zero,
            rel: &format.rel,
            eps: self.eps,
            out: self.out,
        }
    }
}

/// Everything one transformer block needs.
#[derive(Clone, Copy)]
pub struct BlockWeights<'w> {
    /// LayerNorm before attention.
    pub norm1: LayerNormScalars,
    /// Query, key, value projection (`3 DIM` outputs: q, k, v).
    pub qkv: LinearQ<'w>,
    /// Per-head softmax and output parameters.
    pub attention: [AttentionQ; HEADS],
    /// Attention output projection.
    pub proj: LinearQ<'w>,
    /// Residual format change across the attention half.
    pub carry_attention: Carry<'w>,
    /// LayerNorm before the MLP.
    pub norm2: LayerNormScalars,
    /// First MLP layer (to GELU input codes).
    pub fc1: LinearQ<'w>,
    /// GELU from fc1 codes to fc2 input codes.
    pub gelu: &'w [i8; 256],
    /// Second MLP layer.
    pub fc2: LinearQ<'w>,
    /// Residual format change across the MLP half.
    pub carry_mlp: Carry<'w>,
}

/// Which keys an encoder query attends to (the blob's [`kind::ATTENTION_ROWS`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AttentionSpan {
    /// Every token of the band (blobs without [`kind::ATTENTION_ROWS`]).
    Band,
    /// The tokens of its own token row: a query's keys and values are one row of the band,
    /// so attention costs grow with the band's width only, not with its height.
    Row,
}

impl AttentionSpan {
    /// The span a blob's [`kind::ATTENTION_ROWS`] entry names (`None`: the entry is absent).
    fn of_rows(rows: Option<u16>) -> Result<Self, Error> {
        match rows {
            None => Ok(Self::Band),
            Some(0) => Ok(Self::Row),
            Some(found) => Err(Error::ConfigMismatch {
                field: "attention_rows",
                expected: 0,
                found: found as usize,
            }),
        }
    }

    /// The token row whose RoPE row angles rotate queries and keys of token row `row`. Within
    /// one token row the row rotation of a query and of its keys cancels, so [`AttentionSpan::Row`]
    /// rotates every row by row 0's angles: a token row's result then does not depend on where
    /// its band starts (integer rounding would otherwise differ from row to row).
    pub fn rope_row(self, row: usize) -> usize {
        match self {
            Self::Band => row,
            Self::Row => 0,
        }
    }
}

/// The encoder's weights in a blob, validated once by [`EncoderWeights::new`].
#[derive(Clone, Copy)]
pub struct EncoderWeights<'w> {
    blob: Blob<'w>,
    max_patch_cols: usize,
    span: AttentionSpan,
}

impl<'w> EncoderWeights<'w> {
    /// Checks that `blob` was made for this model configuration and holds every encoder tensor
    /// with the right type and size, and valid shifts.
    pub fn new(blob: Blob<'w>) -> Result<Self, Error> {
        let config = blob.u16s(ids::id(kind::CONFIG, 0), CONFIG_LEN)?;
        let expect = [
            (ConfigField::Dim, "dim", DIM),
            (ConfigField::Depth, "depth", DEPTH),
            (ConfigField::Heads, "heads", HEADS),
            (ConfigField::MlpHidden, "mlp_hidden", MLP_HIDDEN),
            (ConfigField::BandTokenRows, "band_token_rows", BAND_TOKEN_ROWS),
            (ConfigField::HeadProjDim, "head_proj_dim", HEAD_PROJ_DIM),
            (ConfigField::HeadGroups, "head_groups", HEAD_GROUPS),
            (ConfigField::HeadHidden, "head_hidden", HEAD_HIDDEN),
            (ConfigField::HeadMiddleLayers, "head_middle_layers", HEAD_MIDDLE_LAYERS),
            (ConfigField::HeadMaxDisp, "head_max_disp", HEAD_MAX_DISP),
        ];
        for (field, name, expected) in expect {
            let found = config.get(field as usize).unwrap_or(0) as usize;
            if found != expected {
                return Err(Error::ConfigMismatch {
                    field: name,
                    expected,
                    found,
                });
            }
        }
        let max_patch_cols = config.get(ConfigField::MaxPatchCols as usize).unwrap_or(0) as usize;
        if max_patch_cols == 0 {
            return Err(Error::ConfigMismatch {
                field: "max_patch_cols",
                expected: 1,
                found: 0,
            });
        }
        let rows = match blob.u16s(ids::id(kind::ATTENTION_ROWS, 0), 1) {
            Ok(rows) => Some(rows.get(0).unwrap_or(0)),
            Err(BlobError::MissingTensor { .. }) => None,
            Err(e) => return Err(e.into()),
        };
        let span = AttentionSpan::of_rows(rows)?;
        let weights = Self {
            blob,
            max_patch_cols,
            span,
        };
        weights.embed()?;
        for s in 0..RESIDUAL_FORMATS {
            weights.residual(s)?;
        }
        for b in 0..DEPTH {
            weights.block(b)?;
        }
        weights.descriptor()?;
        weights.rope()?;
        Ok(weights)
    }

    /// The blob these views borrow.
    pub fn blob(&self) -> &Blob<'w> {
        &self.blob
    }

    /// Which keys a query attends to.
    pub fn span(&self) -> AttentionSpan {
        self.span
    }

    /// Whether a token row's outputs depend on its own pixel rows only, not on its place in the
    /// band: attention within each token row ([`AttentionSpan::Row`]) and one row embedding for
    /// every token row (the embedding's bias rows and the descriptors' row offsets all equal, as
    /// `bino_train.export --row-embedding` makes them). Overlapping bands then share their
    /// common token rows, each computed once.
    pub fn rows_independent(&self) -> bool {
        let same_rows =
            |table: Le<'_, i32>| (1..BAND_TOKEN_ROWS).all(|r| (0..DIM).all(|c| table.at(r * DIM + c) == table.at(c)));
        self.span == AttentionSpan::Row
            && self.embed().is_ok_and(|e| same_rows(e.bias))
            && self.descriptor().is_ok_and(|(_, offsets)| same_rows(offsets))
    }

    /// Widest input the weights cover (the RoPE column table), in patch columns.
    pub fn max_patch_cols(&self) -> usize {
        self.max_patch_cols
    }

    /// The patch embedding; its bias holds one row of `DIM` per token row (row embedding folded in).
    pub fn embed(&self) -> Result<LinearQ<'w>, Error> {
        LinearQ::load(&self.blob, Linear::Embed, DIM, EMBED_INPUTS, BAND_TOKEN_ROWS * DIM)
    }

    /// Residual format `s`.
    pub fn residual(&self, s: usize) -> Result<ResidualFormat<'w>, Error> {
        Ok(ResidualFormat {
            zero: self.blob.i32s(ids::id(kind::RESIDUAL_ZERO, s), DIM)?,
            rel: self.blob.i32s(ids::id(kind::RESIDUAL_REL, s), DIM)?,
        })
    }

    fn carry(&self, s: usize) -> Result<Carry<'w>, Error> {
        Ok(Carry {
            mult: self.blob.i32s(ids::id(kind::CARRY_MULT, s), DIM)?,
            shift: checked_shifts(&self.blob, ids::id(kind::CARRY_SHIFT, s), DIM)?,
        })
    }

    fn layernorm(&self, index: usize) -> Result<LayerNormScalars, Error> {
        let id = ids::id(kind::LAYERNORM, index);
        let values = self.blob.i64s(id, 3)?;
        let eps = values.get(0).unwrap_or(0);
        let mult = i32::try_from(values.get(1).unwrap_or(-1)).map_err(|_| Error::BadParameter { id })?;
        let shift = u32::try_from(values.get(2).unwrap_or(0)).map_err(|_| Error::BadParameter { id })?;
        if eps < 0 {
            return Err(Error::BadParameter { id });
        }
        let out = Requant::new(mult, shift).ok_or(Error::BadParameter { id })?;
        Ok(LayerNormScalars { eps, out })
    }

    fn attention(&self, b: usize) -> Result<[AttentionQ; HEADS], Error> {
        let id = ids::id(kind::ATTENTION, b);
        let values = self.blob.i32s(id, HEADS * 4)?;
        let requant = |i: usize| {
            let mult = values.get(i).unwrap_or(0);
            let shift = u32::try_from(values.get(i + 1).unwrap_or(0)).unwrap_or(0);
            Requant::new(mult, shift).ok_or(Error::BadParameter { id })
        };
        let mut heads = [AttentionQ {
            to_log2_q8: Requant { mult: 0, shift: 1 },
            out: Requant { mult: 0, shift: 1 },
        }; HEADS];
        for (h, head) in heads.iter_mut().enumerate() {
            *head = AttentionQ {
                to_log2_q8: requant(4 * h)?,
                out: requant(4 * h + 2)?,
            };
        }
        Ok(heads)
    }

    /// Block `b`'s weights.
    pub fn block(&self, b: usize) -> Result<BlockWeights<'w>, Error> {
        let gelu_id = ids::id(kind::GELU_TABLE, b);
        let gelu = self.blob.i8s(gelu_id, 256)?;
        let gelu: &[i8; 256] = gelu.try_into().map_err(|_| Error::BadParameter { id: gelu_id })?;
        Ok(BlockWeights {
            norm1: self.layernorm(ids::layernorm_index(b, false))?,
            qkv: LinearQ::load(&self.blob, Linear::Qkv(b), 3 * DIM, DIM, 3 * DIM)?,
            attention: self.attention(b)?,
            proj: LinearQ::load(&self.blob, Linear::Proj(b), DIM, DIM, DIM)?,
            carry_attention: self.carry(ids::residual_after_attention(b) - 1)?,
            norm2: self.layernorm(ids::layernorm_index(b, true))?,
            fc1: LinearQ::load(&self.blob, Linear::Fc1(b), MLP_HIDDEN, DIM, MLP_HIDDEN)?,
            gelu,
            fc2: LinearQ::load(&self.blob, Linear::Fc2(b), DIM, MLP_HIDDEN, DIM)?,
            carry_mlp: self.carry(ids::residual_after_block(b) - 1)?,
        })
    }

    /// Final residual format to Q8 descriptor codes, and the row embedding in those codes.
    pub fn descriptor(&self) -> Result<(Carry<'w>, Le<'w, i32>), Error> {
        let carry = Carry {
            mult: self.blob.i32s(ids::id(kind::DESC_MULT, 0), DIM)?,
            shift: checked_shifts(&self.blob, ids::id(kind::DESC_SHIFT, 0), DIM)?,
        };
        let offsets = self
            .blob
            .i32s(ids::id(kind::DESC_ROW_OFFSET, 0), BAND_TOKEN_ROWS * DIM)?;
        Ok((carry, offsets))
    }

    /// The RoPE cosine / sine tables.
    pub fn rope(&self) -> Result<RopeTables<'w>, Error> {
        Ok(RopeTables {
            rows: self
                .blob
                .i16s(ids::id(kind::ROPE_ROWS, 0), BAND_TOKEN_ROWS * 2 * QUARTER)?,
            cols: self
                .blob
                .i16s(ids::id(kind::ROPE_COLS, 0), self.max_patch_cols * 2 * QUARTER)?,
        })
    }
}

/// RoPE tables: per token row and per patch column, `QUARTER` cosines then `QUARTER` sines.
#[derive(Clone, Copy)]
pub struct RopeTables<'w> {
    rows: Le<'w, i16>,
    cols: Le<'w, i16>,
}

impl RopeTables<'_> {
    /// Angles of token row `row` and patch column `col` (zeros past the tables' ends).
    pub fn angles(&self, row: usize, col: usize) -> (Angles, Angles) {
        (self.row_angles(row), self.col_angles(col))
    }

    /// Angles of token row `row` (zeros past the table's end).
    pub fn row_angles(&self, row: usize) -> Angles {
        read_angles(&self.rows, row)
    }

    /// Angles of patch column `col` (zeros past the table's end).
    pub fn col_angles(&self, col: usize) -> Angles {
        read_angles(&self.cols, col)
    }
}

/// [`RopeTables::angles`] for positions visited in order: a token row's angles are read once
/// per row and a patch column's once per run of tokens on it (a pass walks the tokens row by
/// row, two fused columns per patch column), not once per token.
pub struct AngleCache<'t, 'w> {
    tables: &'t RopeTables<'w>,
    row: Option<(usize, Angles)>,
    col: Option<(usize, Angles)>,
}

impl<'t, 'w> AngleCache<'t, 'w> {
    /// An empty cache over `tables`.
    pub fn new(tables: &'t RopeTables<'w>) -> Self {
        AngleCache {
            tables,
            row: None,
            col: None,
        }
    }

    /// [`RopeTables::angles`] of (`row`, `col`), read from the tables only when they change.
    pub fn angles(&mut self, row: usize, col: usize) -> (Angles, Angles) {
        let row_angles = match self.row {
            Some((r, a)) if r == row => a,
            _ => {
                let a = self.tables.row_angles(row);
                self.row = Some((row, a));
                a
            }
        };
        let col_angles = match self.col {
            Some((c, a)) if c == col => a,
            _ => {
                let a = self.tables.col_angles(col);
                self.col = Some((col, a));
                a
            }
        };
        (row_angles, col_angles)
    }
}

fn read_angles(table: &Le<'_, i16>, at: usize) -> Angles {
    let mut a = Angles::default();
    let base = at.saturating_mul(2 * QUARTER);
    for i in 0..QUARTER {
        a.cos[i] = table.get(base.saturating_add(i)).unwrap_or(0);
        a.sin[i] = table.get(base.saturating_add(QUARTER + i)).unwrap_or(0);
    }
    a
}

impl<'w> Carry<'w> {
    /// The rescale from `from` to the next format.
    pub fn from_format<'p>(&'p self, from: &'p ResidualFormat<'w>) -> ChannelRescale<'p, Le<'w, i32>, Le<'w, i32>> {
        ChannelRescale {
            zero: &from.zero,
            mult: &self.mult,
            shift: self.shift,
        }
    }
}

/// A shift array whose every entry is a valid [`Requant`] shift.
fn checked_shifts<'w>(blob: &Blob<'w>, id: TensorId, len: usize) -> Result<&'w [u8], Error> {
    let shifts = blob.u8s(id, len)?;
    if shifts.iter().any(|&s| s == 0 || s as u32 > MAX_SHIFT) {
        return Err(Error::BadParameter { id });
    }
    Ok(shifts)
}
