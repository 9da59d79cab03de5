//! The residual stream's updates of an encoder block: its formats, the projection added to the
//! stream, the MLP, and the requantisations prepared once per pass.

use crate::blob::Le;
use crate::config::{DIM, MLP_HIDDEN};
use crate::kernels::dispatch::apply_lut;
use crate::kernels::dispatch::layernorm_rows;
use crate::kernels::dispatch::{layernorm_rows_prepared, LayerNormQ, PreparedLayerNorm};
use crate::kernels::dispatch::{matmul_i8_pass, matmul_requant_i8_pass, PassWeights};
use crate::kernels::dispatch::{residual_add_prepared, ChannelRequant, ChannelRescale, PreparedResidual};
use crate::kernels::params::Uniform;
use crate::kernels::types::prepared::PreparedRequant;
use crate::model::weights::{BlockWeights, LinearQ, ResidualFormat};

use super::TOKEN_BLOCK;

/// A residual add's carry and its delta over decoded per-channel arrays.
pub(super) type Carried<'p> = ChannelRescale<'p, [i32; DIM], [i32; DIM]>;
pub(super) type Delta<'p> = ChannelRequant<'p, [i32; DIM], [i32; DIM]>;

/// A residual add's per-channel parameters read from the blob once per pass (the adds of each
/// token block then index plain arrays, not little-endian blob bytes).
pub(super) struct ResidualParams<'w> {
    carry_zero: [i32; DIM],
    carry_mult: [i32; DIM],
    carry_shift: &'w [u8],
    bias: [i32; DIM],
    mult: [i32; DIM],
    shift: &'w [u8],
    new_zero: [i32; DIM],
}

impl<'w> ResidualParams<'w> {
    /// The carry and the delta as the residual add takes them.
    pub(super) fn views(&self) -> (Carried<'_>, Delta<'_>) {
        (
            ChannelRescale {
                zero: &self.carry_zero,
                mult: &self.carry_mult,
                shift: self.carry_shift,
            },
            ChannelRequant {
                bias: &self.bias,
                mult: &self.mult,
                shift: self.shift,
            },
        )
    }

    /// The lane parameters prepared once for the pass's full token blocks, in `storage`.
    pub(super) fn prepare<'s>(&self, storage: &'s mut [i32]) -> Option<PreparedResidual<'s>> {
        let (carry, delta) = self.views();
        PreparedResidual::new(&carry, &delta, &self.new_zero, TOKEN_BLOCK, storage)
    }

    pub(super) fn new(
        carry: &crate::kernels::dispatch::ChannelRescale<'w, Le<'w, i32>, Le<'w, i32>>,
        proj: &LinearQ<'w>,
        new_zero: &Le<'w, i32>,
    ) -> Self {
        ResidualParams {
            carry_zero: decode_channels(carry.zero, 0),
            carry_mult: decode_channels(carry.mult, 0),
            carry_shift: carry.shift,
            bias: decode_channels(&proj.bias, 0),
            mult: decode_channels(&proj.mult, 0),
            shift: proj.shift,
            new_zero: decode_channels(new_zero, 0),
        }
    }
}

/// `x += proj(a)` with the residual format change of `p` (`proj`: the projection's weights).
pub(super) fn project_add(
    proj: &PassWeights<'_>,
    a: &[i8],
    acc: &mut [i32],
    x_block: &mut [i8],
    p: &ResidualParams<'_>,
    prepared: Option<&PreparedResidual<'_>>,
) {
    let count = x_block.len() / DIM;
    matmul_i8_pass(a, proj, &mut acc[..count * DIM]);
    let (carry, delta) = p.views();
    residual_add_prepared(x_block, &carry, &acc[..count * DIM], &delta, &p.new_zero, prepared);
}

/// Pass 3: the MLP of every token block (hidden layer only for one block at a time); `scratch`
/// (the attention scores' room, idle in this pass) keeps fc1's prepared requantisation.
#[allow(clippy::too_many_arguments)]
pub(super) fn mlp(
    w: &BlockWeights<'_>,
    input: &ResidualFormat<'_>,
    output: &ResidualFormat<'_>,
    x: &mut [i8],
    normed: &mut [i8],
    hidden: &mut [i8],
    acc: &mut [i32],
    scratch: &mut [i32],
) {
    let ln = w.norm2.with_input(input);
    let residual = ResidualParams::new(&w.carry_mlp.from_format(input), &w.fc2, &output.zero);
    let fc1 = w.fc1.requant();
    let (ln_storage, scratch) = scratch.split_at_mut(PreparedLayerNorm::storage_words(DIM).min(scratch.len() / 2));
    let mut ln_prepared = PreparedLayerNorm::new(&ln, DIM, ln_storage);
    let (fc1_storage, residual_storage) = scratch.split_at_mut((4 * MLP_HIDDEN).min(scratch.len()));
    let fc1_prepared = prepare(&fc1, fc1_storage);
    let residual_prepared = residual.prepare(residual_storage);
    let (fc1_weights, fc2_weights) = (
        PassWeights::new(w.fc1.weight, DIM),
        PassWeights::new(w.fc2.weight, MLP_HIDDEN),
    );
    for x_block in x.chunks_mut(TOKEN_BLOCK * DIM) {
        let count = x_block.len() / DIM;
        normalise_block(x_block, &ln, ln_prepared.as_mut(), normed);
        let hidden = &mut hidden[..count * MLP_HIDDEN];
        matmul_requant_i8_pass(
            &normed[..count * DIM],
            &fc1_weights,
            fc1_prepared.as_ref(),
            &fc1,
            &Uniform(0),
            acc,
            hidden,
        );
        apply_lut(hidden, w.gelu);
        project_add(
            &fc2_weights,
            hidden,
            acc,
            x_block,
            &residual,
            residual_prepared.as_ref(),
        );
    }
}

/// `rq`'s columns with output zero point 0 prepared in `scratch` for a pass's fused GEMMs, on
/// cores with an assembly kernel (elsewhere the call-by-call path costs the same); `None` where
/// `scratch` is too small (bands under 480 tokens for fc1) or a channel is out of range.
pub(super) fn prepare<'s, B, M>(rq: &ChannelRequant<'_, B, M>, scratch: &'s mut [i32]) -> Option<PreparedRequant<'s>>
where
    B: crate::kernels::I32s + ?Sized,
    M: crate::kernels::I32s + ?Sized,
{
    prepare_with(rq, &Uniform(0), scratch)
}

/// [`prepare`] with the output zero points `zero`.
pub(super) fn prepare_with<'s, B, M, Z>(
    rq: &ChannelRequant<'_, B, M>,
    zero: &Z,
    scratch: &'s mut [i32],
) -> Option<PreparedRequant<'s>>
where
    B: crate::kernels::I32s + ?Sized,
    M: crate::kernels::I32s + ?Sized,
    Z: crate::kernels::I32s + ?Sized,
{
    if crate::kernels::dispatch::PREPARED_GEMM {
        PreparedRequant::new(rq, zero, scratch)
    } else {
        None
    }
}

/// A token block's LayerNorm into `normed`: on the parameters prepared for the pass where
/// they are, else decoded for this call.
pub(super) fn normalise_block<Z, R>(
    x_block: &[i8],
    ln: &LayerNormQ<'_, Z, R>,
    prepared: Option<&mut PreparedLayerNorm<'_>>,
    normed: &mut [i8],
) where
    Z: crate::kernels::I32s + ?Sized,
    R: crate::kernels::I32s + ?Sized,
{
    match prepared {
        Some(p) => layernorm_rows_prepared(x_block, p, normed),
        None => layernorm_rows(x_block, DIM, ln, normed),
    }
}

/// `DIM` per-channel values of a blob array from `start` on (zeros past its end).
pub(super) fn decode_channels(values: &crate::blob::Le<'_, i32>, start: usize) -> [i32; DIM] {
    core::array::from_fn(|c| values.at(start + c))
}
