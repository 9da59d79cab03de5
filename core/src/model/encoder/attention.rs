//! The attention pass of an encoder block: the band's grid, keys and values of every token
//! stored per head (values transposed), then each token block's queries attending over them:
//! over the whole band, or over their own token row ([`AttentionSpan`]).

use crate::config::{DIM, HEADS, HEAD_DIM};
use crate::kernels::dispatch::ChannelRequant;
use crate::kernels::dispatch::PreparedLayerNorm;
use crate::kernels::dispatch::{attend_block, key_layout, scatter_channels, store_key};
use crate::kernels::dispatch::{matmul_i8_pass, matmul_requant_i8_pass, PassWeights};
use crate::kernels::dispatch::{rope_token, RopeLanes};
use crate::kernels::dispatch::{value_sums, KeyLayout, QUERY_BLOCK};
use crate::kernels::params::Uniform;
use crate::model::weights::{AngleCache, AttentionSpan, BlockWeights, ResidualFormat, RopeTables};
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

/// The keys a query attends to: one run of tokens, `first..first + len`, since tokens are
/// stored row by row.
#[derive(Clone, Copy, PartialEq, Eq)]
struct Window {
    first: usize,
    len: usize,
}

impl Window {
    /// The window of token `t`.
    fn of(span: AttentionSpan, grid: Grid, t: usize) -> Self {
        match span {
            AttentionSpan::Band => Self {
                first: 0,
                len: grid.tokens(),
            },
            AttentionSpan::Row => Self {
                first: t - t % grid.fused_cols.max(1),
                len: grid.fused_cols,
            },
        }
    }

    /// Tokens from `t` on (`t` in the window) that share it.
    fn remaining(&self, t: usize) -> usize {
        (self.first + self.len).saturating_sub(t)
    }

    /// A head's keys in the window (`head_keys`: the head's store, `HEAD_DIM` bytes a token in
    /// every layout; a row starts on a layout block, see [`key_layout_of`]).
    fn keys<'k>(&self, head_keys: &'k [i8]) -> &'k [i8] {
        head_keys
            .get(self.first * HEAD_DIM..(self.first + self.len) * HEAD_DIM)
            .unwrap_or_default()
    }

    /// A head's values in the window, `HEAD_DIM x len` (see [`AttentionPass::keys_values`]).
    fn values<'v>(&self, span: AttentionSpan, values: &'v [i8], tokens: usize, head: usize) -> &'v [i8] {
        let start = match span {
            AttentionSpan::Band => head * tokens * HEAD_DIM,
            AttentionSpan::Row => self.first * DIM + head * self.len * HEAD_DIM,
        };
        values.get(start..start + self.len * HEAD_DIM).unwrap_or_default()
    }
}

/// How the keys of a band are stored: a layout's blocks of tokens must not straddle the
/// windows, so with row attention the row's length decides.
pub(super) fn key_layout_of(span: AttentionSpan, grid: Grid) -> KeyLayout {
    match span {
        AttentionSpan::Band => key_layout(grid.tokens()),
        AttentionSpan::Row => key_layout(grid.fused_cols),
    }
}

/// The attention half of one block.
pub(super) struct AttentionPass<'p, 'w> {
    pub(super) w: &'p BlockWeights<'w>,
    pub(super) rope: &'p RopeTables<'w>,
    pub(super) grid: Grid,
    pub(super) input: &'p ResidualFormat<'w>,
    pub(super) output: &'p ResidualFormat<'w>,
    /// How the keys are stored between the two passes ([`key_layout_of`]).
    pub(super) keys: KeyLayout,
    /// Which keys a query attends to.
    pub(super) span: AttentionSpan,
}

impl AttentionPass<'_, '_> {
    /// Pass 1: keys (rotated) of every token stored `[head][token][HEAD_DIM]`, values
    /// channel-major `[head][HEAD_DIM][token]`, or with row attention per token row
    /// `[row][head][HEAD_DIM][column]` (each row's values a head's whole window).
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
        let (k_weights, v_weights) = (PassWeights::new(k_weights, DIM), PassWeights::new(v_weights, DIM));
        for (block, x_block) in x.chunks(TOKEN_BLOCK * DIM).enumerate() {
            let count = x_block.len() / DIM;
            normalise_block(x_block, &ln, ln_prepared.as_mut(), normed);
            let (k_acc, v_acc) = acc.split_at_mut(count * DIM);
            matmul_i8_pass(&normed[..count * DIM], &k_weights, k_acc);
            // Values need no rotation: requantised in the matrix multiply itself.
            let v_out = &mut block_values[..count * DIM];
            matmul_requant_i8_pass(
                &normed[..count * DIM],
                &v_weights,
                value_prepared.as_ref(),
                &value_rq,
                &Uniform(0),
                v_acc,
                v_out,
            );
            for (i, (k_acc, value)) in k_acc.chunks_exact(DIM).zip(v_out.chunks_exact(DIM)).enumerate() {
                let t = block * TOKEN_BLOCK + i;
                let (row, col) = self.grid.position(t);
                let (row_angles, col_angles) = angles.angles(self.span.rope_row(row), col / 2);
                if !key_lanes
                    .as_mut()
                    .is_some_and(|l| l.token(k_acc, &row_angles, &col_angles, &mut rotated))
                {
                    rope_token(k_acc, &key_rq, &row_angles, &col_angles, &mut rotated);
                }
                scatter_heads(self.keys, &rotated, keys, tokens, t);
                match self.span {
                    AttentionSpan::Band => scatter_channels(value, values, tokens, t),
                    AttentionSpan::Row => {
                        let cols = self.grid.fused_cols;
                        if let Some(row_values) = values.get_mut(row * cols * DIM..(row + 1) * cols * DIM) {
                            scatter_channels(value, row_values, cols, col);
                        }
                    }
                }
            }
        }
    }

    /// Pass 2: queries, attention over the keys of each query's window, output projection,
    /// residual add.
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
        let q_weights = PassWeights::new(qkv.weight.get(..DIM * DIM).unwrap_or(&[]), DIM);
        let (query_bias, query_mult) = (decode_channels(&qkv.bias, 0), decode_channels(&qkv.mult, 0));
        let query_rq = ChannelRequant {
            bias: &query_bias,
            mult: &query_mult,
            shift: qkv.shift.get(..DIM).unwrap_or(&[]),
        };
        let mut query_lanes = RopeLanes::new(&query_rq);
        let proj = &self.w.proj;
        let proj_weights = PassWeights::new(proj.weight, DIM);
        let residual = ResidualParams::new(&self.w.carry_attention.from_format(self.input), proj, &self.output.zero);
        let tokens = self.grid.tokens();
        let head_len = tokens * HEAD_DIM;
        let mut angles = AngleCache::new(self.rope);
        // Each head's value sums over the current window, made when the window changes.
        let mut sums = [[0i32; HEAD_DIM]; HEADS];
        let mut sums_of: Option<Window> = None;
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
            matmul_i8_pass(&normed[..count * DIM], &q_weights, &mut acc[..count * DIM]);
            for (i, (q_acc, query)) in acc
                .chunks_exact(DIM)
                .zip(queries.chunks_exact_mut(DIM))
                .take(count)
                .enumerate()
            {
                let (row, col) = self.grid.position(block * TOKEN_BLOCK + i);
                let (row_angles, col_angles) = angles.angles(self.span.rope_row(row), col / 2);
                if !query_lanes
                    .as_mut()
                    .is_some_and(|l| l.token(q_acc, &row_angles, &col_angles, query))
                {
                    rope_token(q_acc, &query_rq, &row_angles, &col_angles, query);
                }
            }
            // The block's queries in runs that share a window (the whole block with band
            // attention; the block's part of each token row with row attention).
            let first = block * TOKEN_BLOCK;
            let mut i = 0;
            while i < count {
                let window = Window::of(self.span, self.grid, first + i);
                let run = window.remaining(first + i).clamp(1, count - i);
                if sums_of != Some(window) {
                    for (head, s) in sums.iter_mut().enumerate() {
                        *s = value_sums(window.values(self.span, values, tokens, head), window.len);
                    }
                    sums_of = Some(window);
                }
                let run_tokens = i * DIM..(i + run) * DIM;
                let kv = keys.chunks_exact(head_len).zip(self.w.attention.iter()).zip(&sums);
                for (head, ((k_head, p), sums)) in kv.enumerate() {
                    let part = head * HEAD_DIM..(head + 1) * HEAD_DIM;
                    let (k_window, v_window) = (window.keys(k_head), window.values(self.span, values, tokens, head));
                    let query_tokens = queries
                        .get(run_tokens.clone())
                        .unwrap_or_default()
                        .chunks(QUERY_BLOCK * DIM);
                    let out_tokens = attended
                        .get_mut(run_tokens.clone())
                        .unwrap_or_default()
                        .chunks_mut(QUERY_BLOCK * DIM);
                    for (q_tokens, o_tokens) in query_tokens.zip(out_tokens) {
                        // Every query slot rewritten (past the run's last token: zeros), and
                        // the outputs all written by `attend_block`: no arrays zeroed per block.
                        for (i, q) in q_block.iter_mut().enumerate() {
                            match q_tokens.get(i * DIM..).and_then(|t| t.get(part.clone())) {
                                Some(src) => q.copy_from_slice(src),
                                None => *q = [0; HEAD_DIM],
                            }
                        }
                        attend_block(
                            self.keys,
                            &q_block,
                            k_window,
                            v_window,
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
                i += run;
            }
            project_add(
                &proj_weights,
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
