//! The int8 heads on the host: the shared head over two descriptor maps, the native head over
//! a pair token map (each whole, or band by band as the core's pathways run them), and the
//! shared head's own left-right check, each streamed row by row through `bino_core`'s head.

use anyhow::{ensure, Context, Result};
use bino_core::config::{DIM, HEAD_MAX_DISP};
use bino_core::model::head::{
    arena_bytes_with, right_view_row, HeadRow, HeadSink, HeadStream, HeadView, HeadWeights, OUT_FRAC_BITS,
};
use bino_core::model::ids::{self, kind, HeadKind};

use super::{meta_f32, Int8Model};
use crate::band_maps::{per_band, BandedRows, ROW_REACH};

/// The int8 head's outputs over a whole descriptor map.
#[derive(Debug, Clone, PartialEq)]
pub struct HeadMaps {
    /// Token rows.
    pub rows: usize,
    /// Patch columns.
    pub cols: usize,
    /// Soft-argmin disparity per cell, in patch columns.
    pub disparity: Vec<f32>,
    /// Largest candidate probability per cell.
    pub confidence: Vec<f32>,
    /// Real logits (`rows x cols x candidates`); candidates outside the right view are
    /// `-inf`.
    pub logits: Vec<f32>,
    /// The right view's disparity per cell (patch columns) read from the logits' diagonal
    /// (`bino_core::model::head::right_view_row`): the native pathway's one-pass check.
    pub right_view: Vec<f32>,
}

impl Int8Model {
    /// The head's own left-right check as the core's export pathway runs it, on descriptor
    /// maps as the bands computed them ([`Int8Model::descriptor_bands`]): the head on the
    /// mirrored pair (each row's cells reversed, views swapped), each band on its own
    /// ([`Int8Model::head_banded`]), gives the right view, and `bino_core::lr::consistent_row`
    /// compares it with `left_head` (the head's left-view output), row by row. True = kept.
    pub fn head_check(
        &self,
        left: &BandedRows<i8>,
        right: &BandedRows<i8>,
        left_head: &HeadMaps,
        candidates: usize,
        lr_max_diff_q8: u16,
    ) -> Result<Vec<bool>> {
        let (rows, cols) = (left_head.rows, left_head.cols);
        let mirrored = self.head_banded(&right.mirrored(DIM), &left.mirrored(DIM), cols, candidates)?;
        ensure!(mirrored.rows == rows, "the maps and the left head differ in rows");
        let q8 = |d: f32| (d * (1u32 << bino_core::matching::DISPARITY_FRAC_BITS) as f32).round() as u16;
        let mut kept = Vec::with_capacity(rows * cols);
        let mut mask = vec![0u8; cols];
        for (l, r) in left_head
            .disparity
            .chunks_exact(cols)
            .zip(mirrored.disparity.chunks_exact(cols))
        {
            let l: Vec<u16> = l.iter().map(|&d| q8(d)).collect();
            let r: Vec<u16> = r.iter().rev().map(|&d| q8(d)).collect();
            bino_core::lr::consistent_row(&l, &r, lr_max_diff_q8, &mut mask).map_err(anyhow::Error::msg)?;
            kept.extend(mask.iter().map(|&m| m != 0));
        }
        Ok(kept)
    }

    /// The int8 shared head as the core's export pathway runs it: on each band's own
    /// descriptor rows within [`ROW_REACH`] of those it keeps ([`Int8Model::descriptor_bands`]
    /// of both views), each band's kept rows stitched into one map. One band:
    /// [`Int8Model::head_with_candidates`].
    pub fn head_banded(
        &self,
        left: &BandedRows<i8>,
        right: &BandedRows<i8>,
        cols: usize,
        candidates: usize,
    ) -> Result<HeadMaps> {
        let row_len = cols * DIM;
        let lens = [cols, cols, cols * candidates, cols];
        let planes = per_band(&left.beside(right)?, ROW_REACH, &lens, |values, rows| {
            let (l, r): (Vec<&[i8]>, Vec<&[i8]>) = values
                .chunks_exact(2 * row_len)
                .map(|row| row.split_at(row_len))
                .unzip();
            let maps = self.head_with_candidates(&l.concat(), &r.concat(), (rows, cols), candidates)?;
            Ok(vec![maps.disparity, maps.confidence, maps.logits, maps.right_view])
        })?;
        maps_of_planes(planes, left.rows, cols)
    }
}

/// [`HeadMaps`] from the planes of a banded head (disparity, confidence, logits, right view).
fn maps_of_planes(planes: Vec<Vec<f32>>, rows: usize, cols: usize) -> Result<HeadMaps> {
    let [disparity, confidence, logits, right_view] =
        <[Vec<f32>; 4]>::try_from(planes).map_err(|p| anyhow::anyhow!("the banded head gave {} planes", p.len()))?;
    Ok(HeadMaps {
        rows,
        cols,
        disparity,
        confidence,
        logits,
        right_view,
    })
}

struct CollectRows<'m, 'w> {
    out: &'m mut HeadMaps,
    logit_scale: f32,
    weights: HeadWeights<'w>,
    right: Vec<u16>,
}

impl HeadSink for CollectRows<'_, '_> {
    fn row(&mut self, row: HeadRow<'_>) {
        let q8 = (1u32 << OUT_FRAC_BITS) as f32;
        self.right.resize(row.disparity_q8.len(), 0);
        // The row and the buffer are both `cols` wide: the only error is unreachable; a row
        // that failed would leave `right_view` short, which the whole-map check reports.
        if right_view_row(&self.weights, &row, &mut self.right).is_ok() {
            self.out.right_view.extend(self.right.iter().map(|&d| d as f32 / q8));
        }
        self.out
            .disparity
            .extend(row.disparity_q8.iter().map(|&d| d as f32 / q8));
        self.out
            .confidence
            .extend(row.confidence_q8.iter().map(|&c| c as f32 / q8));
        let scale = self.logit_scale;
        self.out.logits.extend(row.logits.iter().map(|&l| {
            if l == i32::MIN {
                f32::NEG_INFINITY
            } else {
                l as f32 * scale
            }
        }));
    }
}

impl Int8Model {
    /// Whether the blob holds the shared head.
    pub fn has_head(&self) -> bool {
        self.has_head_of(HeadKind::Export)
    }

    /// Whether the blob holds `head` (the native pathway's head: `--native-head` at quantisation).
    pub fn has_head_of(&self, head: HeadKind) -> bool {
        self.blob()
            .ok()
            .and_then(|b| HeadWeights::for_kind(b, head).ok())
            .is_some()
    }

    /// An error naming the blob and how to add `head` when the blob does not carry it (what a
    /// command checks before it runs a head readout).
    pub fn require_head(&self, head: HeadKind) -> Result<()> {
        self.head_weights(head).map(|_| ())
    }

    /// The blob's `head` weights, or an error naming the blob and how to add that head.
    fn head_weights(&self, head: HeadKind) -> Result<(HeadWeights<'_>, f32)> {
        let blob = self.blob()?;
        let flag = match head {
            HeadKind::Export => "--head",
            HeadKind::Native => "--native-head",
        };
        let weights = HeadWeights::for_kind(blob, head)
            .map_err(|e| anyhow::anyhow!("{e}"))
            .with_context(|| {
                format!(
                    "{} holds no usable {} pathway head (quantise with {flag})",
                    self.path.display(),
                    head.pathway()
                )
            })?;
        let logit_scale = meta_f32(&blob, ids::id(kind::META_HEAD_LOGIT_SCALE, head.index()), 1)?[0];
        Ok((weights, logit_scale))
    }

    /// The int8 native head over a pair token code map (`rows x cols x [even, odd] x DIM`,
    /// [`Int8Model::pair_token_codes`]), streamed row by row.
    pub fn native_head(&self, tokens: &[i8], rows: usize, cols: usize) -> Result<HeadMaps> {
        self.native_head_with_candidates(tokens, (rows, cols), HEAD_MAX_DISP)
    }

    /// The int8 native head as the core's native pathway runs it: on each band's own rows
    /// within [`ROW_REACH`] of those it keeps ([`Int8Model::pair_token_bands`]), each band's
    /// kept rows stitched into one map. One band: [`Int8Model::native_head_with_candidates`].
    pub fn native_head_banded(&self, tokens: &BandedRows<i8>, cols: usize, candidates: usize) -> Result<HeadMaps> {
        let lens = [cols, cols, cols * candidates, cols];
        let planes = per_band(tokens, ROW_REACH, &lens, |values, rows| {
            let maps = self.native_head_with_candidates(values, (rows, cols), candidates)?;
            Ok(vec![maps.disparity, maps.confidence, maps.logits, maps.right_view])
        })?;
        maps_of_planes(planes, tokens.rows, cols)
    }

    /// [`Int8Model::native_head`] over `candidates` disparities.
    pub fn native_head_with_candidates(
        &self,
        tokens: &[i8],
        (rows, cols): (usize, usize),
        candidates: usize,
    ) -> Result<HeadMaps> {
        ensure!(
            tokens.len() == rows * cols * 2 * DIM,
            "pair token map holds {} codes, expected {rows} x {cols} x 2 x {DIM}",
            tokens.len()
        );
        let (weights, logit_scale) = self.head_weights(HeadKind::Native)?;
        run_head(weights, logit_scale, (rows, cols, candidates), |stream, sink| {
            for row in tokens.chunks_exact(cols * 2 * DIM) {
                stream.push_pair_row(row, sink)?;
            }
            Ok(())
        })
    }

    /// The int8 head over two descriptor code maps (`rows x cols x DIM` each), streamed row by
    /// row, over the trained [`HEAD_MAX_DISP`] candidates.
    pub fn head(&self, left: &[i8], right: &[i8], rows: usize, cols: usize) -> Result<HeadMaps> {
        self.head_with_candidates(left, right, (rows, cols), HEAD_MAX_DISP)
    }

    /// [`Int8Model::head`] over `candidates` disparities (`HeadStream::with_candidates`).
    pub fn head_with_candidates(
        &self,
        left: &[i8],
        right: &[i8],
        (rows, cols): (usize, usize),
        candidates: usize,
    ) -> Result<HeadMaps> {
        ensure!(
            left.len() == rows * cols * DIM && right.len() == left.len(),
            "descriptor maps differ in size"
        );
        let (weights, logit_scale) = self.head_weights(HeadKind::Export)?;
        run_head(weights, logit_scale, (rows, cols, candidates), |stream, sink| {
            for (l, r) in left.chunks_exact(cols * DIM).zip(right.chunks_exact(cols * DIM)) {
                stream.push_row(l, r, sink)?;
            }
            Ok(())
        })
    }
}

/// A head stream over `cols` patch columns and `candidates` disparities fed by `feed`, then
/// finished: the whole maps.
fn run_head<F>(
    weights: HeadWeights<'_>,
    logit_scale: f32,
    (rows, cols, candidates): (usize, usize, usize),
    feed: F,
) -> Result<HeadMaps>
where
    F: FnOnce(&mut HeadStream<'_, '_>, &mut CollectRows<'_, '_>) -> Result<(), bino_core::Error>,
{
    let mut arena = vec![0u8; arena_bytes_with(weights.kind(), cols, candidates)];
    let mut stream = HeadStream::with_candidates(weights, cols, candidates, HeadView::Left, &mut arena)
        .map_err(anyhow::Error::msg)?;
    let mut maps = HeadMaps {
        rows,
        cols,
        disparity: Vec::new(),
        confidence: Vec::new(),
        logits: Vec::new(),
        right_view: Vec::new(),
    };
    let mut sink = CollectRows {
        out: &mut maps,
        logit_scale,
        weights,
        right: Vec::new(),
    };
    feed(&mut stream, &mut sink).map_err(anyhow::Error::msg)?;
    stream.finish(&mut sink).map_err(anyhow::Error::msg)?;
    ensure!(
        maps.disparity.len() == rows * cols && maps.right_view.len() == rows * cols,
        "head emitted {} cells ({} right-view cells) of {}",
        maps.disparity.len(),
        maps.right_view.len(),
        rows * cols
    );
    Ok(maps)
}
