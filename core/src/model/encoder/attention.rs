//! The attention pass of an encoder block: the band's grid, keys and values of every token
//! stored per head (values transposed), then each token block's queries attending over them.

use crate::config::{DIM, HEADS, HEAD_DIM};
use crate::kernels::dispatch::matmul_i8;
use crate::kernels::dispatch::matmul_requant_i8_prepared;
use crate::kernels::dispatch::ChannelRequant;
use crate::kernels::dispatch::PreparedLayerNorm;
use crate::kernels::dispatch::{attend_block, scatter_channels, store_key};
use crate::kernels::dispatch::{rope_token, RopeLanes};
use crate::kernels::dispatch::{value_sums, KeyLayout, QUERY_BLOCK};
use crate::kernels::params::Uniform;
use crate::model::weights::{AngleCache, BlockWeights, ResidualFormat, RopeTables};
use crate::Error;

use super::residual::{decode_channels, normalise_block, prepare, project_add, ResidualParams};
use super::TOKEN_BLOCK;

/// The token grid of a band.
#[derive(Clone, Copy)]
pub(super) struct Grid {
    pub(super) rows: usize,
    pub(super) fused_cols: usize,
}

impl Grid {
    pub(super) fn tokens(&self) -> usize {
        self.rows * self.fused_cols
    }

    /// (token row, fused column) of token `t`.
    pub(super) fn position(&self, t: usize) -> (usize, usize) {
        (t / self.fused_cols.max(1), t % self.fused_cols.max(1))
    }
}

/// The attention half of one block.
pub(super) struct AttentionPass<'p, 'w> {
    pub(super) w: &'p BlockWeights<'w>,
    pub(super) rope: &'p RopeTables<'w>,
    pub(super) grid: Grid,
    pub(super) input: &'p ResidualFormat<'w>,
    pub(super) output: &'p ResidualFormat<'w>,
    /// How the keys are stored between the two passes.
    pub(super) keys: KeyLayout,
}

impl AttentionPass<'_, '_> {
    /// Pass 1: keys (rotated) of every token stored `[head][token][HEAD_DIM]`, values
    /// channel-major `[head][HEAD_DIM][token]`.
    /// `scratch` (the attention scores' room, idle in this pass) keeps the values' prepared
    /// requantisation.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn keys_values(
        &self,
        x: &[i8],
        normed: &mut [i8],
        acc: &mut [i32],
        keys: &mut [i8],
        values: &mut [i8],
        scratch: &mut [i32],
    ) {
        let ln = self.w.norm1.with_input(self.input);
        let qkv = &self.w.qkv;
        let k_weights = qkv.weight.get(DIM * DIM..2 * DIM * DIM).unwrap_or(&[]);
        let v_weights = qkv.weight.get(2 * DIM * DIM..3 * DIM * DIM).unwrap_or(&[]);
        // Per-channel parameters decoded from the blob once per pass, not once per token.
        let key_bias = decode_channels(&qkv.bias, DIM);
        let key_mult = decode_channels(&qkv.mult, DIM);
        let key_rq = ChannelRequant {
            bias: &key_bias,
            mult: &key_mult,
            shift: qkv.shift.get(DIM..2 * DIM).unwrap_or(&[]),
        };
        let value_bias = decode_channels(&qkv.bias, 2 * DIM);
        let value_mult = decode_channels(&qkv.mult, 2 * DIM);
        let value_rq = ChannelRequant {
            bias: &value_bias,
            mult: &value_mult,
            shift: qkv.shift.get(2 * DIM..).unwrap_or(&[]),
        };
        let (ln_storage, scratch) = scratch.split_at_mut(PreparedLayerNorm::storage_words(DIM).min(scratch.len() / 2));
        let mut ln_prepared = PreparedLayerNorm::new(&ln, DIM, ln_storage);
        let value_prepared = prepare(&value_rq, scratch);
        // The keys' rotation in 32-bit lanes where the blob's formats allow (quantiser-made ones do).
        let mut key_lanes = RopeLanes::new(&key_rq);
        let tokens = self.grid.tokens();
        let mut angles = AngleCache::new(self.rope);
        let mut rotated = [0i8; DIM];
        let mut block_values = [0i8; TOKEN_BLOCK * DIM];
        for (block, x_block) in x.chunks(TOKEN_BLOCK * DIM).enumerate() {
            let count = x_block.len() / DIM;
            normalise_block(x_block, &ln, ln_prepared.as_mut(), normed);
            let (k_acc, v_acc) = acc.split_at_mut(count * DIM);
            matmul_i8(&normed[..count * DIM], k_weights, DIM, k_acc);
            // Values need no rotation: requantised in the matrix multiply itself.
            let v_out = &mut block_values[..count * DIM];
            matmul_requant_i8_prepared(
                &normed[..count * DIM],
                v_weights,
                DIM,
                value_prepared.as_ref(),
                &value_rq,
                &Uniform(0),
                v_acc,
                v_out,
            );
            for (i, (k_acc, value)) in k_acc.chunks_exact(DIM).zip(v_out.chunks_exact(DIM)).enumerate() {
                let t = block * TOKEN_BLOCK + i;
                let (row, col) = self.grid.position(t);
                let (row_angles, col_angles) = angles.angles(row, col / 2);
                if !key_lanes
                    .as_mut()
                    .is_some_and(|l| l.token(k_acc, &row_angles, &col_angles, &mut rotated))
                {
                    rope_token(k_acc, &key_rq, &row_angles, &col_angles, &mut rotated);
                }
                scatter_heads(self.keys, &rotated, keys, tokens, t);
                scatter_channels(value, values, tokens, t);
            }
        }
    }

    /// Pass 2: queries, attention over all keys, output projection, residual add.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn queries_attend(
        &self,
        x: &mut [i8],
        normed: &mut [i8],
        acc: &mut [i32],
        queries: &mut [i8],
        attended: &mut [i8],
        keys: &[i8],
        values: &[i8],
        scores: &mut [i32],
        softmax: &mut [u8],
        hidden: &mut [i8],
    ) -> Result<(), Error> {
        let ln = self.w.norm1.with_input(self.input);
        let qkv = &self.w.qkv;
        let q_weights = qkv.weight.get(..DIM * DIM).unwrap_or(&[]);
        let (query_bias, query_mult) = (decode_channels(&qkv.bias, 0), decode_channels(&qkv.mult, 0));
        let query_rq = ChannelRequant {
            bias: &query_bias,
            mult: &query_mult,
            shift: qkv.shift.get(..DIM).unwrap_or(&[]),
        };
        let mut query_lanes = RopeLanes::new(&query_rq);
        let proj = &self.w.proj;
        let residual = ResidualParams::new(&self.w.carry_attention.from_format(self.input), proj, &self.output.zero);
        let head_len = self.grid.tokens() * HEAD_DIM;
        let mut angles = AngleCache::new(self.rope);
        let mut sums = [[0i32; HEAD_DIM]; HEADS];
        for (s, v_head) in sums.iter_mut().zip(values.chunks_exact(head_len)) {
            *s = value_sums(v_head, self.grid.tokens());
        }
        // The MLP's hidden buffer is idle in this pass: it keeps the LayerNorm's parameters;
        // the accumulators past a token block's (the keys and values' room) the residual add's.
        let ln_bytes = 4 * PreparedLayerNorm::storage_words(DIM);
        let ln_storage = bytemuck::try_cast_slice_mut::<i8, i32>(hidden.get_mut(..ln_bytes).unwrap_or_default());
        let mut ln_prepared = ln_storage.ok().and_then(|st| PreparedLayerNorm::new(&ln, DIM, st));
        let (acc, acc_spare) = acc.split_at_mut((TOKEN_BLOCK * DIM).min(acc.len()));
        let residual_prepared = residual.prepare(acc_spare);
        let (mut q_block, mut out_block) = ([[0i8; HEAD_DIM]; QUERY_BLOCK], [[0i8; HEAD_DIM]; QUERY_BLOCK]);
        for (block, x_block) in x.chunks_mut(TOKEN_BLOCK * DIM).enumerate() {
            let count = x_block.len() / DIM;
            normalise_block(x_block, &ln, ln_prepared.as_mut(), normed);
            matmul_i8(&normed[..count * DIM], q_weights, DIM, &mut acc[..count * DIM]);
            for (i, (q_acc, query)) in acc
                .chunks_exact(DIM)
                .zip(queries.chunks_exact_mut(DIM))
                .take(count)
                .enumerate()
            {
                let (row, col) = self.grid.position(block * TOKEN_BLOCK + i);
                let (row_angles, col_angles) = angles.angles(row, col / 2);
                if !query_lanes
                    .as_mut()
                    .is_some_and(|l| l.token(q_acc, &row_angles, &col_angles, query))
                {
                    rope_token(q_acc, &query_rq, &row_angles, &col_angles, query);
                }
            }
            let kv = keys.chunks_exact(head_len).zip(values.chunks_exact(head_len));
            for (head, (((k_head, v_head), p), sums)) in kv.zip(self.w.attention.iter()).zip(&sums).enumerate() {
                let part = head * HEAD_DIM..(head + 1) * HEAD_DIM;
                let query_tokens = queries.get(..count * DIM).unwrap_or_default().chunks(QUERY_BLOCK * DIM);
                let out_tokens = attended
                    .get_mut(..count * DIM)
                    .unwrap_or_default()
                    .chunks_mut(QUERY_BLOCK * DIM);
                for (q_tokens, o_tokens) in query_tokens.zip(out_tokens) {
                    // Every query slot rewritten (past the block's last token: zeros), and the
                    // outputs all written by `attend_block`: no arrays zeroed per block.
                    for (i, q) in q_block.iter_mut().enumerate() {
                        match q_tokens.get(i * DIM..).and_then(|t| t.get(part.clone())) {
                            Some(src) => q.copy_from_slice(src),
                            None => *q = [0; HEAD_DIM],
                        }
                    }
                    attend_block(
                        self.keys,
                        &q_block,
                        k_head,
                        v_head,
                        sums,
                        p,
                        scores,
                        softmax,
                        &mut out_block,
                    );
                    for (o, token) in out_block.iter().zip(o_tokens.chunks_exact_mut(DIM)) {
                        token[part.clone()].copy_from_slice(o);
                    }
                }
            }
            project_add(
                proj,
                &attended[..count * DIM],
                acc,
                x_block,
                &residual,
                residual_prepared.as_ref(),
            );
        }
        Ok(())
    }
}

/// Writes one token's `DIM` codes into a `[head][token][HEAD_DIM]` store.
pub(super) fn scatter_heads(layout: KeyLayout, token: &[i8], store: &mut [i8], tokens: usize, t: usize) {
    for (head, part) in store
        .chunks_exact_mut(tokens * HEAD_DIM)
        .zip(token.chunks_exact(HEAD_DIM))
        .take(HEADS)
    {
        store_key(layout, part, head, t);
    }
}
