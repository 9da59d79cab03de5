//! [`HeadStream`]: descriptor rows (or pair token rows) in, the correlation into the first
//! ring, the convolutions pumped deepest first, disparity rows out through a [`HeadSink`].

use super::super::ids::{HeadKind, HEAD_CONVS};
use super::projection::{correlate, project, project_pair, reverse_cells, ProjectBuffers};
use super::sizing::{arena_bytes_with, check_candidates, max, ring_bytes_per_col, ring_slot_mut, CELL_BLOCK, TAPS};
use super::{HeadRow, HeadSink, HeadView, HeadWeights, OUT_FRAC_BITS};
use crate::arena::Carver;
use crate::config::{DIM, HEAD_HIDDEN, HEAD_MAX_DISP};
use crate::fixed::Requant;
use crate::kernels::exp::exp_neg_u8;
use crate::Error;

/// Streaming state of the head over one descriptor map (any number of rows, fixed width).
pub struct HeadStream<'a, 'w> {
    pub(super) w: HeadWeights<'w>,
    pub(super) view: HeadView,
    pub(super) cols: usize,
    pub(super) candidates: usize,
    pub(super) rings: &'a mut [i8],
    pub(super) pushed: [usize; HEAD_CONVS],
    pub(super) produced: [usize; HEAD_CONVS],
    pub(super) input_done: bool,
    pub(super) f_left: &'a mut [i8],
    pub(super) f_right: &'a mut [i8],
    pub(super) normed: &'a mut [i8],
    pub(super) gathered: &'a mut [i8],
    pub(super) acc: &'a mut [i32],
    pub(super) logits: &'a mut [i32],
    pub(super) disparity: &'a mut [u16],
    pub(super) confidence: &'a mut [u16],
    pub(super) arena_used: usize,
}

impl<'a, 'w> HeadStream<'a, 'w> {
    /// A stream over descriptor rows of `cols` patch columns, its buffers cut from `arena`;
    /// it reads out the left view.
    pub fn new(weights: HeadWeights<'w>, cols: usize, arena: &'a mut [u8]) -> Result<Self, Error> {
        Self::for_view(weights, cols, HeadView::Left, arena)
    }

    /// [`HeadStream::new`] reading out `view`; it takes the same (left, right) rows.
    pub fn for_view(weights: HeadWeights<'w>, cols: usize, view: HeadView, arena: &'a mut [u8]) -> Result<Self, Error> {
        Self::with_candidates(weights, cols, HEAD_MAX_DISP, view, arena)
    }

    /// [`HeadStream::for_view`] searching `candidates` disparities (0 .. `candidates` - 1
    /// patch columns; [`check_candidates`]) instead of the trained [`HEAD_MAX_DISP`]: for
    /// views wider than the heads' training crops, whose disparities reach further.
    pub fn with_candidates(
        weights: HeadWeights<'w>,
        cols: usize,
        candidates: usize,
        view: HeadView,
        arena: &'a mut [u8],
    ) -> Result<Self, Error> {
        if cols == 0 {
            return Err(Error::EmptyImage);
        }
        check_candidates(candidates)?;
        let head = weights.kind;
        let d = candidates;
        let mut carver = Carver::new(arena, arena_bytes_with(head, cols, d))?;
        // Carver::new took arena_bytes_with(head, cols, d) <= arena.len(): these products
        // cannot overflow.
        let rings_len = cols * ring_bytes_per_col(d);
        let rings = carver.i8s(rings_len)?;
        let f_left = carver.i8s(cols * head.proj_dim())?;
        let f_right = carver.i8s(cols * head.proj_dim())?;
        let normed = carver.i8s(CELL_BLOCK * head.input_dim())?;
        let gathered = carver.i8s(d * TAPS * HEAD_HIDDEN)?;
        let acc = carver.i32s(max(d * HEAD_HIDDEN, CELL_BLOCK * head.proj_dim()))?;
        let logits = carver.i32s(cols * d)?;
        let disparity = carver.u16s(cols)?;
        let confidence = carver.u16s(cols)?;
        let arena_used = carver.used();
        Ok(Self {
            w: weights,
            view,
            cols,
            candidates,
            rings,
            pushed: [0; HEAD_CONVS],
            produced: [0; HEAD_CONVS],
            input_done: false,
            f_left,
            f_right,
            normed,
            gathered,
            acc,
            logits,
            disparity,
            confidence,
            arena_used,
        })
    }

    /// Arena bytes the stream took.
    pub fn arena_used(&self) -> usize {
        self.arena_used
    }

    /// Disparity candidates per cell.
    pub fn candidates(&self) -> usize {
        self.candidates
    }

    /// Feeds the export head the next descriptor row of both views (`cols x DIM` codes each);
    /// emits every output row that became computable.
    pub fn push_row(&mut self, desc_left: &[i8], desc_right: &[i8], sink: &mut impl HeadSink) -> Result<(), Error> {
        self.check_pathway(HeadKind::Export)?;
        let expected = self.cols * DIM;
        for (what, row) in [("left descriptor row", desc_left), ("right descriptor row", desc_right)] {
            Error::check_len(what, expected, row.len())?;
        }
        if self.input_done {
            return Err(Error::StreamFinished);
        }
        let (proj, _) = self.w.projections()?;
        let norm = self.w.input_norm();
        match self.view {
            HeadView::Left => {
                project(desc_left, &norm, &proj, self.normed, self.acc, self.f_left);
                project(desc_right, &norm, &proj, self.normed, self.acc, self.f_right);
            }
            HeadView::Right => {
                // The mirrored pair: the projections are per cell, so projecting first and
                // reversing the cells after is the same as projecting reversed rows.
                project(desc_right, &norm, &proj, self.normed, self.acc, self.f_left);
                project(desc_left, &norm, &proj, self.normed, self.acc, self.f_right);
                reverse_cells(self.f_left, self.w.kind.proj_dim());
                reverse_cells(self.f_right, self.w.kind.proj_dim());
            }
        }
        self.correlate_and_pump(sink)
    }

    /// Feeds the native head the next row of the pair's de-positioned fused grid
    /// (`Encoder::pair_tokens`: `cols x [even, odd] x DIM` codes, the pair feature `u` of each
    /// patch column; for [`HeadView::Right`], the row of the encoder's pass on the mirrored
    /// pair); emits every output row that became computable.
    pub fn push_pair_row(&mut self, tokens: &[i8], sink: &mut impl HeadSink) -> Result<(), Error> {
        self.check_pathway(HeadKind::Native)?;
        let expected = self.cols * 2 * DIM;
        Error::check_len("pair token row", expected, tokens.len())?;
        if self.input_done {
            return Err(Error::StreamFinished);
        }
        let (left, right) = self.w.projections()?;
        let norm = self.w.input_norm();
        let buffers = ProjectBuffers {
            normed: self.normed,
            acc: self.acc,
        };
        project_pair(tokens, &norm, (&left, &right), buffers, (self.f_left, self.f_right));
        self.correlate_and_pump(sink)
    }

    fn check_pathway(&self, input: HeadKind) -> Result<(), Error> {
        if self.w.kind == input {
            Ok(())
        } else {
            Err(Error::PathwayMismatch {
                head: self.w.kind.pathway(),
                input: input.pathway(),
            })
        }
    }

    /// The projected row pair into the correlation ring, then every computable output.
    fn correlate_and_pump(&mut self, sink: &mut impl HeadSink) -> Result<(), Error> {
        let row = self.pushed[0];
        let slot = ring_slot_mut(self.rings, self.cols, self.candidates, 0, row);
        correlate(
            self.f_left,
            self.f_right,
            self.w.kind.proj_dim(),
            self.w.correlation,
            (self.candidates, slot),
        );
        self.pushed[0] += 1;
        self.pump(sink)
    }

    /// Ends the input: emits the remaining rows (the bottom edge is zero-padded).
    pub fn finish(&mut self, sink: &mut impl HeadSink) -> Result<(), Error> {
        self.input_done = true;
        self.pump(sink)
    }

    /// Starts the stream over, reading out `view`: every buffer as a new stream's, so the next
    /// rows give what a fresh [`HeadStream::for_view`] on the same arena would. Lets one arena
    /// serve the left head and then the mirrored one when the whole map is at hand.
    pub fn restart(&mut self, view: HeadView) {
        self.view = view;
        self.pushed = [0; HEAD_CONVS];
        self.produced = [0; HEAD_CONVS];
        self.input_done = false;
        for buffer in [
            &mut *self.rings,
            &mut *self.f_left,
            &mut *self.f_right,
            &mut *self.normed,
            &mut *self.gathered,
        ] {
            buffer.fill(0);
        }
        self.acc.fill(0);
        self.logits.fill(0);
        self.disparity.fill(0);
        self.confidence.fill(0);
    }

    /// Rows emitted so far.
    pub fn rows_out(&self) -> usize {
        self.produced[HEAD_CONVS - 1]
    }

    fn input_complete(&self, layer: usize) -> bool {
        match layer {
            0 => self.input_done,
            l => self.input_complete(l - 1) && self.produced[l - 1] == self.pushed[l - 1],
        }
    }

    fn next_output(&self, layer: usize) -> Option<usize> {
        let m = self.produced[layer];
        let available = self.pushed[layer];
        (m < available && (m + 1 < available || self.input_complete(layer))).then_some(m)
    }

    /// Deepest layer first, so a ring's oldest row is consumed before it is overwritten.
    fn pump(&mut self, sink: &mut impl HeadSink) -> Result<(), Error> {
        'work: loop {
            for layer in (0..HEAD_CONVS).rev() {
                if let Some(m) = self.next_output(layer) {
                    self.conv_row(layer, m, sink)?;
                    self.produced[layer] += 1;
                    if layer + 1 < HEAD_CONVS {
                        self.pushed[layer + 1] += 1;
                    }
                    continue 'work;
                }
            }
            return Ok(());
        }
    }

    /// Output row `row` from the output layer's logits, to `sink`.
    pub(super) fn emit(&mut self, row: usize, sink: &mut impl HeadSink) {
        for (p, cell) in self.logits.chunks_exact(self.candidates).enumerate().take(self.cols) {
            let (disparity, confidence) = soft_argmin(cell, self.w.softmax);
            if let (Some(d), Some(c)) = (self.disparity.get_mut(p), self.confidence.get_mut(p)) {
                (*d, *c) = (disparity, confidence);
            }
        }
        if self.view == HeadView::Right {
            // Back from the mirrored pair's cell order to the right view's.
            self.disparity.reverse();
            self.confidence.reverse();
            reverse_cells(self.logits, self.candidates);
        }
        sink.row(HeadRow {
            row,
            disparity_q8: self.disparity,
            confidence_q8: self.confidence,
            logits: self.logits,
            candidates: self.candidates,
        });
    }
}

/// Soft-argmin over the valid candidates of one cell: (disparity, confidence), both Q8.
pub(super) fn soft_argmin(logits: &[i32], to_log2_q8: Requant) -> (u16, u16) {
    let max = logits.iter().copied().max().unwrap_or(i32::MIN);
    if max == i32::MIN {
        return (0, 0);
    }
    let (mut total, mut moment) = (0u32, 0u32);
    for (d, &l) in logits.iter().enumerate() {
        if l != i32::MIN {
            let w = exp_neg_u8(max as i64 - l as i64, to_log2_q8) as u32;
            total += w;
            moment += d as u32 * w;
        }
    }
    let total = total.max(1);
    let q8 = 1u32 << OUT_FRAC_BITS;
    let disparity = (moment * q8 + total / 2) / total;
    let confidence = (255 * q8 + total / 2) / total;
    (
        disparity.min(u16::MAX as u32) as u16,
        confidence.min(u16::MAX as u32) as u16,
    )
}
