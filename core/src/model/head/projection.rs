//! The heads' front: LayerNorm and projection of each descriptor cell (the export head) or
//! pair feature (the native head), then the groupwise correlation of the projected rows.

use super::super::weights::LinearQ;
use super::sizing::{max, CELL_BLOCK};
use crate::config::{DIM, HEAD_GROUPS, HEAD_PROJ_DIM, NATIVE_HEAD_PROJ_DIM};
use crate::fixed::{sat_i8_i64, Requant};
use crate::kernels::dispatch::dot;
use crate::kernels::dispatch::matmul_requant_i8_prepared;
use crate::kernels::dispatch::{layernorm_rows, LayerNormQ};
use crate::kernels::params::Uniform;
use crate::kernels::types::prepared::PreparedRequant;

/// Reverses the order of the `len`-value cells of `row` (a tail shorter than a cell stays).
pub(super) fn reverse_cells<T>(row: &mut [T], len: usize) {
    if len == 0 {
        return;
    }
    let cells = row.len() / len;
    for i in 0..cells / 2 {
        let (front, back) = row.split_at_mut((cells - 1 - i) * len);
        if let (Some(a), Some(b)) = (front.get_mut(i * len..(i + 1) * len), back.get_mut(..len)) {
            a.swap_with_slice(b);
        }
    }
}

/// LayerNorm + projection of one descriptor row, `CELL_BLOCK` cells at a time.
pub(super) fn project(
    desc: &[i8],
    norm: &LayerNormQ<'_, Uniform, Uniform>,
    proj: &LinearQ<'_>,
    normed: &mut [i8],
    acc: &mut [i32],
    out: &mut [i8],
) {
    let buffers = ProjectBuffers { normed, acc };
    project_cells(desc, DIM, norm, &[proj], buffers, [out]);
}

/// The native head's front: each pair feature `u` normalised once, then projected by `P_L`
/// into `f_left` and by `P_R` into `f_right`.
pub(super) fn project_pair(
    tokens: &[i8],
    norm: &LayerNormQ<'_, Uniform, Uniform>,
    (left, right): (&LinearQ<'_>, &LinearQ<'_>),
    buffers: ProjectBuffers<'_>,
    (f_left, f_right): (&mut [i8], &mut [i8]),
) {
    project_cells(tokens, 2 * DIM, norm, &[left, right], buffers, [f_left, f_right]);
}

/// Scratch of the projections: normalised cells and accumulators of one cell block.
pub(super) struct ProjectBuffers<'a> {
    pub(super) normed: &'a mut [i8],
    pub(super) acc: &'a mut [i32],
}

/// The widest head projection (output channels).
const MAX_PROJ_DIM: usize = max(HEAD_PROJ_DIM, NATIVE_HEAD_PROJ_DIM);

/// LayerNorm of each `dim`-code input cell, then projection `k` of the block into `outs[k]`,
/// [`CELL_BLOCK`] cells at a time (one normalisation serves every projection).
fn project_cells<const N: usize>(
    cells: &[i8],
    dim: usize,
    norm: &LayerNormQ<'_, Uniform, Uniform>,
    projections: &[&LinearQ<'_>; N],
    buffers: ProjectBuffers<'_>,
    mut outs: [&mut [i8]; N],
) {
    let Some(first) = projections.first() else { return };
    if dim == 0 {
        return;
    }
    // Every projection has the same shape: its output channels from its weights' length.
    let proj_dim = first.weight.len() / dim;
    // Each projection's requantisation prepared once per call (a row of cells) for its blocks'
    // fused GEMMs, on cores with an assembly kernel (on the stack: 1.5 KiB a projection).
    let mut storage = [[0i32; 4 * MAX_PROJ_DIM]; N];
    let mut slots = storage.iter_mut();
    let prepared: [Option<PreparedRequant<'_>>; N] = core::array::from_fn(|i| {
        let slot = slots.next()?;
        let proj = projections.get(i)?;
        if crate::kernels::dispatch::PREPARED_GEMM {
            PreparedRequant::new(&proj.requant(), &Uniform(0), slot)
        } else {
            None
        }
    });
    for (block, block_cells) in cells.chunks(CELL_BLOCK * dim).enumerate() {
        let count = block_cells.len() / dim;
        let normed = &mut buffers.normed[..count * dim];
        layernorm_rows(block_cells, dim, norm, normed);
        let acc = &mut buffers.acc[..count * proj_dim];
        for ((proj, out), prepared) in projections.iter().zip(outs.iter_mut()).zip(&prepared) {
            let Some(out_cells) = out.get_mut(block * CELL_BLOCK * proj_dim..(block * CELL_BLOCK + count) * proj_dim)
            else {
                return;
            };
            matmul_requant_i8_prepared(
                normed,
                proj.weight,
                dim,
                prepared.as_ref(),
                &proj.requant(),
                &Uniform(0),
                acc,
                out_cells,
            );
        }
    }
}

/// One correlation row of `candidates` disparities: `[column][disparity][group]`, zero where
/// the candidate is outside; features of `proj_dim` channels, [`HEAD_GROUPS`] groups.
pub(super) fn correlate(
    f_left: &[i8],
    f_right: &[i8],
    proj_dim: usize,
    rq: Requant,
    (candidates, out): (usize, &mut [i8]),
) {
    let per_group = proj_dim / HEAD_GROUPS;
    if per_group == 0 || candidates == 0 {
        return;
    }
    let cells_left = f_left.chunks_exact(proj_dim);
    for (p, (left, out_cell)) in cells_left
        .zip(out.chunks_exact_mut(candidates * HEAD_GROUPS))
        .enumerate()
    {
        for (d, out_groups) in out_cell.chunks_exact_mut(HEAD_GROUPS).enumerate() {
            let right = p
                .checked_sub(d)
                .and_then(|q| f_right.get(q * proj_dim..(q + 1) * proj_dim));
            match right {
                Some(right) => {
                    let groups = left.chunks_exact(per_group).zip(right.chunks_exact(per_group));
                    for (o, (a, b)) in out_groups.iter_mut().zip(groups) {
                        *o = sat_i8_i64(rq.apply_i64(dot(a, b) as i64));
                    }
                }
                None => out_groups.fill(0),
            }
        }
    }
}
