//! The stereo heads in int8, streaming: descriptor rows in, disparity rows out.
//!
//! Two heads share everything after their projections ([`HeadKind`]): the export pathway's
//! shared head reads a descriptor row of each view and projects both with one LayerNorm +
//! projection; the native pathway's head reads one row of the pair's de-positioned fused grid
//! (`Encoder::pair_tokens`: per patch column the pair feature `u = [a, b]`, its two phase
//! tokens), normalises `u` once and projects it twice (`P_L`, `P_R`).
//!
//! Per descriptor row pair: LayerNorm and the shared projection of both views, the groupwise
//! correlation over the stream's disparity candidates (`HEAD_MAX_DISP` unless
//! [`HeadStream::with_candidates`] asks for more; row layout `[column][disparity][channel]`), then
//! six 3x3x3 convolutions over (row, disparity, column): a stem, four residual middle layers
//! (`x + relu(conv(x))`) and the output layer, whose logits go through an integer softmax to a
//! soft-argmin disparity and a confidence. Each convolution keeps a ring of the three input rows
//! its kernel spans, so memory depends on the width only; an output row leaves the head six rows
//! after its descriptors went in (one per convolution) and [`HeadStream::finish`] flushes the rest.

use super::ids::{self, kind, HeadKind, Linear, HEAD_CONVS};
use super::weights::{LayerNormScalars, LinearQ};
use crate::arena::{Carver, ALIGN_SLACK};
use crate::blob::Blob;
use crate::config::{
    DIM, HEAD_CANDIDATES_LIMIT, HEAD_GROUPS, HEAD_HIDDEN, HEAD_MAX_DISP, HEAD_MIDDLE_LAYERS, HEAD_PROJ_DIM,
    NATIVE_HEAD_PROJ_DIM,
};
use crate::fixed::{sat_i8_i64, Requant, MAX_SHIFT};
use crate::kernels::arch::PreparedRequant;
use crate::kernels::epilogue::ChannelRequant;
use crate::kernels::exp::exp_neg_u8;
use crate::kernels::gemm::matmul_requant_i8_prepared;
use crate::kernels::layernorm::{layernorm_rows, LayerNormQ};
use crate::kernels::matmul::{dot, matmul_i8};
use crate::kernels::params::Uniform;
use crate::kernels::I32s;
use crate::Error;

/// Kernel positions of a 3x3x3 convolution.
const TAPS: usize = 27;
/// Descriptor cells projected together.
const CELL_BLOCK: usize = 8;
/// The LayerNorm's input unit: descriptors are per-tensor, so any common scale works.
const DESC_REL: i32 = 256;
/// Fraction bits of the disparity and confidence outputs.
pub const OUT_FRAC_BITS: u32 = 8;

const fn max(a: usize, b: usize) -> usize {
    if a > b {
        a
    } else {
        b
    }
}

/// Input channels of convolution `layer`.
const fn conv_inputs(layer: usize) -> usize {
    if layer == 0 {
        HEAD_GROUPS
    } else {
        HEAD_HIDDEN
    }
}

/// Output channels of convolution `layer`.
const fn conv_outputs(layer: usize) -> usize {
    if layer == HEAD_CONVS - 1 {
        1
    } else {
        HEAD_HIDDEN
    }
}

/// Bytes of one ring row of convolution `layer`'s input, for `cols` patch columns and
/// `candidates` disparities.
const fn ring_row(layer: usize, cols: usize, candidates: usize) -> usize {
    cols.saturating_mul(candidates * conv_inputs(layer))
}

/// Bytes per patch column of every ring (three rows per convolution).
const fn ring_bytes_per_col(candidates: usize) -> usize {
    let mut bytes = 0;
    let mut layer = 0;
    while layer < HEAD_CONVS {
        bytes += 3 * candidates * conv_inputs(layer);
        layer += 1;
    }
    bytes
}

/// Checks a head stream's number of disparity candidates (1 to [`HEAD_CANDIDATES_LIMIT`]).
pub const fn check_candidates(candidates: usize) -> Result<(), Error> {
    if candidates == 0 || candidates > HEAD_CANDIDATES_LIMIT {
        Err(Error::Candidates {
            requested: candidates,
            max: HEAD_CANDIDATES_LIMIT,
        })
    } else {
        Ok(())
    }
}

/// Arena bytes of the export head's stream over `cols` patch columns (descriptor map width):
/// [`arena_bytes_for`] of [`HeadKind::Export`].
pub const fn arena_bytes(cols: usize) -> usize {
    arena_bytes_for(HeadKind::Export, cols)
}

/// Arena bytes of a `head` stream over `cols` patch columns with the default
/// [`HEAD_MAX_DISP`] candidates: [`arena_bytes_with`].
pub const fn arena_bytes_for(head: HeadKind, cols: usize) -> usize {
    arena_bytes_with(head, cols, HEAD_MAX_DISP)
}

/// Arena bytes of a `head` stream over `cols` patch columns searching `candidates`
/// disparities. Saturates at `usize::MAX` for widths no memory holds, so such a stream is
/// [`Error::ArenaTooSmall`]; a count [`check_candidates`] refuses is sized as the limit.
pub const fn arena_bytes_with(head: HeadKind, cols: usize, candidates: usize) -> usize {
    let d = if candidates > HEAD_CANDIDATES_LIMIT {
        HEAD_CANDIDATES_LIMIT
    } else {
        candidates
    };
    let proj = head.proj_dim();
    let acc = max(d * HEAD_HIDDEN, CELL_BLOCK * proj);
    let per_col = ring_bytes_per_col(d)
        + 2 * proj // projected left and right rows
        + d * 4 // output logits
        + 2 * 2; // disparity and confidence (u16)
    let fixed = CELL_BLOCK * head.input_dim() // normalised input cells
        + d * TAPS * HEAD_HIDDEN // one column's gathered kernel inputs
        + acc * 4
        + 2 * ALIGN_SLACK // accumulators and logits (i32, aligned)
        + 2; // disparity and confidence (u16, aligned)
    cols.saturating_mul(per_col).saturating_add(fixed)
}

/// One head's weights in a blob, validated once.
#[derive(Clone, Copy)]
pub struct HeadWeights<'w> {
    blob: Blob<'w>,
    kind: HeadKind,
    norm: LayerNormScalars,
    correlation: Requant,
    softmax: Requant,
    zeros: [i32; HEAD_CONVS],
    carries: [Requant; HEAD_MIDDLE_LAYERS],
}

impl<'w> HeadWeights<'w> {
    /// Checks every tensor of the export pathway's shared head in `blob`.
    pub fn new(blob: Blob<'w>) -> Result<Self, Error> {
        Self::for_kind(blob, HeadKind::Export)
    }

    /// Checks every tensor of the `head` in `blob` (a blob without that head is
    /// [`Error::Blob`] naming the first missing tensor).
    pub fn for_kind(blob: Blob<'w>, head: HeadKind) -> Result<Self, Error> {
        let at = head.index();
        let norm_id = ids::id(kind::LAYERNORM, head.layernorm());
        let values = blob.i64s(norm_id, 3)?;
        let norm_out = requant_i64(values.get(1), values.get(2)).ok_or(Error::BadParameter { id: norm_id })?;
        let eps = values.get(0).unwrap_or(-1);
        if eps < 0 {
            return Err(Error::BadParameter { id: norm_id });
        }
        let pair = |k: u16| -> Result<Requant, Error> {
            let id = ids::id(k, at);
            let v = blob.i32s(id, 2)?;
            requant_i64(v.get(0).map(i64::from), v.get(1).map(i64::from)).ok_or(Error::BadParameter { id })
        };
        let zero_list = blob.i32s(ids::id(kind::HEAD_ZERO, at), HEAD_CONVS)?;
        let mut zeros = [0i32; HEAD_CONVS];
        for (i, z) in zeros.iter_mut().enumerate() {
            *z = zero_list.get(i).unwrap_or(0);
        }
        let carry_id = ids::id(kind::HEAD_CARRY, at);
        let carry_list = blob.i32s(carry_id, 2 * HEAD_MIDDLE_LAYERS)?;
        let mut carries = [Requant { mult: 0, shift: 1 }; HEAD_MIDDLE_LAYERS];
        for (i, c) in carries.iter_mut().enumerate() {
            let (m, s) = (
                carry_list.get(2 * i).map(i64::from),
                carry_list.get(2 * i + 1).map(i64::from),
            );
            *c = requant_i64(m, s).ok_or(Error::BadParameter { id: carry_id })?;
        }
        let weights = Self {
            blob,
            kind: head,
            norm: LayerNormScalars { eps, out: norm_out },
            correlation: pair(kind::HEAD_CORRELATION)?,
            softmax: pair(kind::HEAD_SOFTMAX)?,
            zeros,
            carries,
        };
        weights.projections()?;
        for layer in 0..HEAD_CONVS {
            weights.conv(layer)?;
        }
        Ok(weights)
    }

    /// Which head these are.
    pub fn kind(&self) -> HeadKind {
        self.kind
    }

    /// The input LayerNorm: input codes share one scale (descriptor codes), so any common
    /// unit serves as their relative scale.
    fn input_norm(&self) -> LayerNormQ<'static, Uniform, Uniform> {
        LayerNormQ {
            zero: &Uniform(0),
            rel: &Uniform(DESC_REL),
            eps: self.norm.eps,
            out: self.norm.out,
        }
    }

    /// The left and right projections (`proj_dim x input_dim` of [`HeadKind`]): the export
    /// head's one shared projection twice, or the native head's `P_L` and `P_R`.
    pub fn projections(&self) -> Result<(LinearQ<'w>, LinearQ<'w>), Error> {
        let (out, inputs) = (self.kind.proj_dim(), self.kind.input_dim());
        let load = |layer| LinearQ::load(&self.blob, layer, out, inputs, out);
        match self.kind {
            HeadKind::Export => {
                let shared = load(Linear::HeadProj)?;
                Ok((shared, shared))
            }
            HeadKind::Native => Ok((load(Linear::NativeProjLeft)?, load(Linear::NativeProjRight)?)),
        }
    }

    /// Convolution `layer` (0 stem, 1..=4 middle, 5 output).
    pub fn conv(&self, layer: usize) -> Result<LinearQ<'w>, Error> {
        let (outputs, inputs) = (conv_outputs(layer), TAPS * conv_inputs(layer));
        LinearQ::load(&self.blob, self.kind.conv(layer), outputs, inputs, outputs)
    }
}

fn requant_i64(mult: Option<i64>, shift: Option<i64>) -> Option<Requant> {
    let mult = i32::try_from(mult?).ok()?;
    let shift = u32::try_from(shift?).ok().filter(|&s| (1..=MAX_SHIFT).contains(&s))?;
    Requant::new(mult, shift)
}

/// One output row of the head.
#[derive(Debug, Clone, Copy)]
pub struct HeadRow<'r> {
    /// Token row.
    pub row: usize,
    /// Soft-argmin disparity per patch column, in patch columns, Q8 (`/ 256`).
    pub disparity_q8: &'r [u16],
    /// Largest candidate probability per patch column, Q8 (`256` = certain).
    pub confidence_q8: &'r [u16],
    /// Output-layer accumulators (`cols x candidates`); `i32::MIN` marks candidates outside
    /// the right view. Real logit = accumulator x the blob's `META_HEAD_LOGIT_SCALE`.
    pub logits: &'r [i32],
    /// Disparity candidates per cell (the stream's count).
    pub candidates: usize,
}

/// Receives the head's rows in order.
pub trait HeadSink {
    /// Called once per token row, top to bottom.
    fn row(&mut self, row: HeadRow<'_>);
}

/// Which view's disparity a head stream reads out.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeadView {
    /// The left view's: the head on (left, right), as trained.
    Left,
    /// The right view's: the head on the mirrored pair (mirror(right), mirror(left)), its
    /// output mirrored back, so cell `q` of an output row is right cell `q`. The left-right
    /// check of the head compares the two. The export head takes the same (left, right)
    /// descriptor rows and mirrors them itself (each row's cells in reverse order); the native
    /// head takes the rows of the encoder's pass on the mirrored pair.
    Right,
}

/// Streaming state of the head over one descriptor map (any number of rows, fixed width).
pub struct HeadStream<'a, 'w> {
    w: HeadWeights<'w>,
    view: HeadView,
    cols: usize,
    candidates: usize,
    rings: &'a mut [i8],
    pushed: [usize; HEAD_CONVS],
    produced: [usize; HEAD_CONVS],
    input_done: bool,
    f_left: &'a mut [i8],
    f_right: &'a mut [i8],
    normed: &'a mut [i8],
    gathered: &'a mut [i8],
    acc: &'a mut [i32],
    logits: &'a mut [i32],
    disparity: &'a mut [u16],
    confidence: &'a mut [u16],
    arena_used: usize,
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

    /// Output row `m` of convolution `layer` from its input rows `m - 1 ..= m + 1`.
    fn conv_row(&mut self, layer: usize, m: usize, sink: &mut impl HeadSink) -> Result<(), Error> {
        let conv = self.w.conv(layer)?;
        let (cols, nd) = (self.cols, self.candidates);
        let cin = conv_inputs(layer);
        let cout = conv_outputs(layer);
        let rows_in = self.pushed[layer];
        let base = ring_base(layer, cols, nd);
        let (lower, upper) = self
            .rings
            .split_at_mut(ring_base(layer + 1, cols, nd).min(self.rings.len()));
        let input = lower.get(base..).unwrap_or(&[]);
        let slot_of = |r: isize| -> Option<&[i8]> {
            let r = usize::try_from(r).ok().filter(|&r| r < rows_in)?;
            let len = ring_row(layer, cols, nd);
            input.get((r % 3) * len..(r % 3 + 1) * len)
        };
        let rows = [slot_of(m as isize - 1), slot_of(m as isize), slot_of(m as isize + 1)];
        let zero = self.w.zeros.get(layer).copied().unwrap_or(0);
        let out_len = ring_row(layer + 1, cols, nd);
        let out_slot = if layer + 1 < HEAD_CONVS {
            let next = self.pushed[layer + 1];
            upper.get_mut((next % 3) * out_len..(next % 3 + 1) * out_len)
        } else {
            None
        };
        let k = TAPS * cin;
        let rq = conv.requant();
        // The epilogue in 32-bit lanes where the formats allow (quantiser-made ones do).
        let lanes = if layer + 1 < HEAD_CONVS && cout == HEAD_HIDDEN {
            let carry = layer.checked_sub(1).and_then(|l| self.w.carries.get(l).copied());
            let next_zero = self.w.zeros.get(layer + 1).copied().unwrap_or(0);
            ConvEpilogue::new(&rq, carry, zero, next_zero)
        } else {
            None
        };
        let mut out_slot = out_slot;
        for p in 0..cols {
            let gathered = self.gathered.get_mut(..nd * k).unwrap_or(&mut []);
            gather(&rows, (p, cols, nd), cin, zero as i8, gathered);
            let acc = self.acc.get_mut(..nd * cout).unwrap_or(&mut []);
            matmul_i8(gathered, conv.weight, k, acc);
            if layer + 1 == HEAD_CONVS {
                for (d, &a) in self.acc.iter().take(nd).enumerate() {
                    if let Some(l) = self.logits.get_mut(p * nd + d) {
                        *l = if d <= p {
                            a.saturating_add(conv.bias.at(0))
                        } else {
                            i32::MIN
                        };
                    }
                }
                continue;
            }
            let Some(out) = out_slot.as_deref_mut() else { continue };
            let out_cell = out.get_mut(p * nd * cout..(p + 1) * nd * cout).unwrap_or(&mut []);
            let next_zero = self.w.zeros.get(layer + 1).copied().unwrap_or(0) as i64;
            let center = rows[1].and_then(|r| r.get(p * nd * cin..(p + 1) * nd * cin));
            let acc = self.acc.get(..nd * cout).unwrap_or(&[]);
            if lanes.as_ref().is_some_and(|l| l.apply(acc, center, out_cell)) {
                continue;
            }
            for (i, (o, &a)) in out_cell.iter_mut().zip(self.acc.iter()).enumerate() {
                let relu = rq.apply(i % cout, a).max(0);
                let carried = match (layer, center) {
                    (0, _) => 0,
                    (l, Some(x)) => {
                        let carry = self
                            .w
                            .carries
                            .get(l - 1)
                            .copied()
                            .unwrap_or(Requant { mult: 0, shift: 1 });
                        carry.apply_i64(x.get(i).copied().unwrap_or(0) as i64 - zero as i64)
                    }
                    (_, None) => 0,
                };
                *o = sat_i8_i64(carried + relu + next_zero);
            }
        }
        if layer + 1 == HEAD_CONVS {
            self.emit(m, sink);
        }
        Ok(())
    }

    fn emit(&mut self, row: usize, sink: &mut impl HeadSink) {
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
fn soft_argmin(logits: &[i32], to_log2_q8: Requant) -> (u16, u16) {
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

/// LayerNorm + projection of one descriptor row, `CELL_BLOCK` cells at a time.
/// Reverses the order of the `len`-value cells of `row` (a tail shorter than a cell stays).
fn reverse_cells<T>(row: &mut [T], len: usize) {
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

fn project(
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
fn project_pair(
    tokens: &[i8],
    norm: &LayerNormQ<'_, Uniform, Uniform>,
    (left, right): (&LinearQ<'_>, &LinearQ<'_>),
    buffers: ProjectBuffers<'_>,
    (f_left, f_right): (&mut [i8], &mut [i8]),
) {
    project_cells(tokens, 2 * DIM, norm, &[left, right], buffers, [f_left, f_right]);
}

/// Scratch of the projections: normalised cells and accumulators of one cell block.
struct ProjectBuffers<'a> {
    normed: &'a mut [i8],
    acc: &'a mut [i32],
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
        if cfg!(any(bino_dsp, bino_mve)) {
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
fn correlate(f_left: &[i8], f_right: &[i8], proj_dim: usize, rq: Requant, (candidates, out): (usize, &mut [i8])) {
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

/// The 27 kernel inputs of every one of the `nd` disparities of column `p` (positions ordered
/// row, disparity, column; channels innermost); outside the volume they are the input's zero
/// point.
fn gather(rows: &[Option<&[i8]>; 3], at: (usize, usize, usize), cin: usize, zero: i8, out: &mut [i8]) {
    // The model's widths as constants: each tap is then a fixed-size copy (a few loads and
    // stores) instead of a `memcpy` call, which cost as much as the copy itself.
    match cin {
        HEAD_GROUPS => gather_fixed::<HEAD_GROUPS>(rows, at, zero, out),
        HEAD_HIDDEN => gather_fixed::<HEAD_HIDDEN>(rows, at, zero, out),
        _ => gather_any(rows, at, cin, zero, out),
    }
}

/// The epilogue of a hidden 3D convolution (`HEAD_HIDDEN` outputs per candidate) in 32-bit
/// scalar lanes, bit for bit `HeadStream::conv_row`'s 64-bit one:
/// `sat8(carry(x - zero) + max(rq(acc), 0) + next_zero)`.
///
/// As in `epilogue::residual_lanes`: a rounded shift `(P + 2^(s-1)) >> s` of a product is
/// `(hi32(P 2^e) + 2^(s-33+e)) >> (s - 32 + e)` for `s - 32 + e >= 1`. The requantisation takes
/// `e = 0` (shifts from 33, `|acc + bias| < 2^31` for `|acc|, |bias| < 2^30`); the carry's
/// `x - zero`, below `2^16`, takes `e = 15` (shifts 18 to 47) or 0 (48 to 62). Each term is
/// then below `2^29` in magnitude and, with `|next_zero| < 2^29`, so is their sum's reach.
/// On the Cortex-M55 the cells with a carry run as a Helium kernel (`kernels::arch`).
pub struct ConvEpilogue {
    bias: [i32; HEAD_HIDDEN],
    mult: [i32; HEAD_HIDDEN],
    round: [i32; HEAD_HIDDEN],
    post: [u8; HEAD_HIDDEN],
    /// The Helium kernel's parameters: bias, multiplier, rounding term and negated right
    /// shift, each `HEAD_HIDDEN` words.
    #[cfg(bino_mve)]
    lanes: [i32; 4 * HEAD_HIDDEN],
    /// The carry's multiplier, left shift, rounding term and right shift (none at layer 0).
    carry: Option<(i32, u32, i32, u32)>,
    zero: i32,
    next_zero: i32,
    /// The Cortex-M7 kernel's parameters: per channel bias, multiplier, rounding term, right
    /// shift.
    #[cfg(bino_dsp)]
    channel_params: [[i32; 4]; HEAD_HIDDEN],
    /// The carry of each input code `q` plus the next zero point, at `q + 128` (the next zero
    /// point alone without a carry), for the Cortex-M7 kernel.
    #[cfg(bino_dsp)]
    carried: [i32; 256],
}

impl ConvEpilogue {
    /// The epilogue of a convolution with `HEAD_HIDDEN` output channels requantised by `rq`,
    /// adding `carry` of its input (zero point `zero`; none at layer 0) and the next layer's
    /// zero point; `None` for formats outside the 32-bit identities (see the type).
    pub fn new<B: I32s + ?Sized, M: I32s + ?Sized>(
        rq: &ChannelRequant<'_, B, M>,
        carry: Option<Requant>,
        zero: i32,
        next_zero: i32,
    ) -> Option<Self> {
        if rq.channels() != HEAD_HIDDEN || zero.unsigned_abs() >= 1 << 15 || next_zero.unsigned_abs() >= 1 << 29 {
            return None;
        }
        let mut e = ConvEpilogue {
            bias: [0; HEAD_HIDDEN],
            mult: [0; HEAD_HIDDEN],
            round: [0; HEAD_HIDDEN],
            post: [1; HEAD_HIDDEN],
            #[cfg(bino_mve)]
            lanes: [0; 4 * HEAD_HIDDEN],
            carry: None,
            zero,
            next_zero,
            #[cfg(bino_dsp)]
            channel_params: [[0; 4]; HEAD_HIDDEN],
            #[cfg(bino_dsp)]
            carried: [next_zero; 256],
        };
        for c in 0..HEAD_HIDDEN {
            let (bias, shift) = (rq.bias.at(c), rq.shift.get(c).copied().unwrap_or(0) as u32);
            if !(33..=62).contains(&shift) || bias.unsigned_abs() >= 1 << 30 {
                return None;
            }
            (e.bias[c], e.mult[c]) = (bias, rq.mult.at(c));
            e.round[c] = 1 << (shift - 33);
            e.post[c] = (shift - 32) as u8;
        }
        #[cfg(bino_mve)]
        for (c, lane) in e.lanes.iter_mut().enumerate() {
            let (part, i) = (c / HEAD_HIDDEN, c % HEAD_HIDDEN);
            *lane = match part {
                0 => e.bias[i],
                1 => e.mult[i],
                2 => e.round[i],
                _ => -(e.post[i] as i32),
            };
        }
        if let Some(r) = carry {
            if !(18..=62).contains(&r.shift) {
                return None;
            }
            let pre = if r.shift <= 47 { 15 } else { 0 };
            e.carry = Some((r.mult, pre, 1 << (r.shift + pre - 33), r.shift + pre - 32));
        }
        #[cfg(bino_dsp)]
        {
            for (c, p) in e.channel_params.iter_mut().enumerate() {
                *p = [e.bias[c], e.mult[c], e.round[c], e.post[c] as i32];
            }
            if let Some(carry) = e.carry {
                let carried: [i32; 256] =
                    core::array::from_fn(|i| e.carry_of(carry, (i as i32 - 128) as i8) + next_zero);
                e.carried = carried;
            }
        }
        Some(e)
    }

    /// The carry of one input code: `(hi32(((q - zero) << pre) mult) + round) >> post`.
    #[inline(always)]
    fn carry_of(&self, (mult, pre, round, post): (i32, u32, i32, u32), q: i8) -> i32 {
        let high = ((((q as i32 - self.zero) << (pre & 31)) as i64 * mult as i64) >> 32) as i32;
        (high + round) >> (post & 31)
    }

    /// The outputs of one cell (`acc` and `out`: candidates x `HEAD_HIDDEN`; `center`: the
    /// cell's input, whose codes the carry adds); `false` for accumulators from `2^30` in
    /// magnitude or lengths that do not match: nothing written (on Cortex-M7, codes written
    /// beside an accumulator past the bound, which the caller then recomputes, every one).
    pub fn apply(&self, acc: &[i32], center: Option<&[i8]>, out: &mut [i8]) -> bool {
        if out.len() != acc.len() || acc.iter().fold(0u32, |m, &a| m.max(a.unsigned_abs())) >= 1 << 30 {
            return false;
        }
        // Cortex-M7: one assembly loop (which reads the bound's bits as it goes; past it the
        // codes are recomputed by the caller, which writes every one).
        #[cfg(bino_dsp)]
        if self.carry.is_none() || center.is_some() {
            let x = center.filter(|_| self.carry.is_some());
            if let Some(bits) =
                crate::kernels::arch::dsp::conv_epilogue(acc, x, &self.channel_params, &self.carried, out)
            {
                return bits < 1 << 30;
            }
        }
        let high = |a: i32, b: i32| ((a as i64 * b as i64) >> 32) as i32;
        let params = self.bias.iter().zip(&self.mult).zip(self.round.iter().zip(&self.post));
        // `max(rq(acc), 0)` of one channel (`|acc|, |bias| < 2^30`: the sum does not wrap).
        let relu = |a: i32, ((&bias, &mult), (&round, &post)): ((&i32, &i32), (&i32, &u8))| {
            ((high(a.wrapping_add(bias), mult) + round) >> (post & 31)).max(0)
        };
        // Each case its own loop over whole cells, so that the channels' loop has no branch or
        // bounds check left and vectorises (MVE on the Cortex-M55).
        match self.carry.zip(center) {
            None => {
                let cells = out.chunks_exact_mut(HEAD_HIDDEN).zip(acc.chunks_exact(HEAD_HIDDEN));
                for (outs, accs) in cells {
                    for ((o, &a), p) in outs.iter_mut().zip(accs).zip(params.clone()) {
                        *o = (relu(a, p) + self.next_zero).clamp(-128, 127) as i8;
                    }
                }
            }
            Some((carry, x)) => {
                #[cfg(bino_mve)]
                let (mult, pre, round, post) = carry;
                let carried = |q: i8| self.carry_of(carry, q);
                let add = |o: &mut i8, a: i32, p, q: i8| {
                    *o = (carried(q) + relu(a, p) + self.next_zero).clamp(-128, 127) as i8;
                };
                #[cfg(bino_mve)]
                if x.len() >= acc.len()
                    && crate::kernels::arch::mve::conv_epilogue(
                        acc,
                        x,
                        &self.lanes,
                        (mult, pre as i32, round, -(post as i32)),
                        self.zero,
                        self.next_zero,
                        out,
                    )
                {
                    return true;
                }
                let cells = out.chunks_exact_mut(HEAD_HIDDEN).zip(acc.chunks_exact(HEAD_HIDDEN));
                if x.len() >= acc.len() {
                    for ((outs, accs), xs) in cells.zip(x.chunks_exact(HEAD_HIDDEN)) {
                        for (((o, &a), p), &q) in outs.iter_mut().zip(accs).zip(params.clone()).zip(xs) {
                            add(o, a, p, q);
                        }
                    }
                } else {
                    // A short `center` (not reached: the stream passes whole rows): missing
                    // codes count as 0.
                    for (cell, (outs, accs)) in cells.enumerate() {
                        for (c, ((o, &a), p)) in outs.iter_mut().zip(accs).zip(params.clone()).enumerate() {
                            add(o, a, p, x.get(cell * HEAD_HIDDEN + c).copied().unwrap_or(0));
                        }
                    }
                }
            }
        }
        true
    }
}

// The fixed-width gathers copy words.
const _: () = assert!(HEAD_GROUPS.is_multiple_of(4) && HEAD_HIDDEN.is_multiple_of(4));

/// [`gather`] for `CIN` input channels (a multiple of 4): the nine (row, column) blocks of the
/// patch column's neighbourhood (`nd` candidates of `CIN` codes each, or `None` outside the
/// band) looked up once per column, then per candidate and tap a copy word by word (a copy of 4
/// bytes is always inlined: one load, one store; a whole-array copy became a `memcpy` call).
fn gather_fixed<const CIN: usize>(
    rows: &[Option<&[i8]>; 3],
    (p, cols, nd): (usize, usize, usize),
    zero: i8,
    out: &mut [i8],
) {
    let block = nd * CIN;
    let blocks: [[Option<&[i8]>; 3]; 3] = core::array::from_fn(|r| {
        core::array::from_fn(|k| {
            let pp = (p + k).checked_sub(1).filter(|&pp| pp < cols)?;
            rows[r]?.get(pp * block..(pp + 1) * block)
        })
    });
    for (d, taps) in out.chunks_exact_mut(TAPS * CIN).enumerate() {
        let mut chunks = taps.chunks_exact_mut(CIN);
        for row_blocks in &blocks {
            for dd in [d.wrapping_sub(1), d, d + 1] {
                // Candidate `dd` of a block: `None` past its ends (`d - 1` wraps to a huge
                // offset, `d + 1 = nd` starts at the block's end).
                let at = dd.wrapping_mul(CIN);
                for b in row_blocks {
                    let Some(dst) = chunks.next().and_then(|c| c.first_chunk_mut::<CIN>()) else {
                        return;
                    };
                    match b.and_then(|b| b.get(at..)).and_then(|s| s.first_chunk::<CIN>()) {
                        Some(s) => {
                            for (d, s) in dst.chunks_exact_mut(4).zip(s.chunks_exact(4)) {
                                d.copy_from_slice(s);
                            }
                        }
                        None => dst.fill(zero),
                    }
                }
            }
        }
    }
}

/// [`gather`] for any channel count.
fn gather_any(rows: &[Option<&[i8]>; 3], (p, cols, nd): (usize, usize, usize), cin: usize, zero: i8, out: &mut [i8]) {
    for (d, taps) in out.chunks_exact_mut(TAPS * cin).enumerate() {
        let mut chunks = taps.chunks_exact_mut(cin);
        for row in rows {
            for dd in [d.wrapping_sub(1), d, d + 1] {
                for pp in [p.wrapping_sub(1), p, p + 1] {
                    let Some(dst) = chunks.next() else { return };
                    let src = match row {
                        Some(r) if dd < nd && pp < cols => r.get((pp * nd + dd) * cin..(pp * nd + dd + 1) * cin),
                        _ => None,
                    };
                    match src {
                        Some(s) => dst.copy_from_slice(s),
                        None => dst.fill(zero),
                    }
                }
            }
        }
    }
}

fn ring_base(layer: usize, cols: usize, candidates: usize) -> usize {
    (0..layer).map(|l| 3 * ring_row(l, cols, candidates)).sum()
}

fn ring_slot_mut(rings: &mut [i8], cols: usize, candidates: usize, layer: usize, row: usize) -> &mut [i8] {
    let len = ring_row(layer, cols, candidates);
    let start = ring_base(layer, cols, candidates) + (row % 3) * len;
    rings.get_mut(start..start + len).unwrap_or(&mut [])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::Rng;

    #[test]
    fn conv_epilogue_lanes_equal_the_64_bit_formula() {
        let mut rng = Rng::new(17);
        let nd = 12;
        let mut taken = 0;
        for trial in 0..120 {
            let lo = if trial % 10 == 9 { 20 } else { 33 };
            let bias: [i32; HEAD_HIDDEN] = core::array::from_fn(|_| rng.range(-(1 << 30) + 1, (1 << 30) - 1) as i32);
            let mult: [i32; HEAD_HIDDEN] =
                core::array::from_fn(|_| rng.range(-(i32::MAX as i64), i32::MAX as i64) as i32);
            let shift: [u8; HEAD_HIDDEN] = core::array::from_fn(|_| rng.range(lo, 62) as u8);
            let rq = ChannelRequant {
                bias: &bias,
                mult: &mult,
                shift: &shift,
            };
            let carry = (trial % 3 != 0).then(|| Requant {
                mult: rng.range(-(i32::MAX as i64), i32::MAX as i64) as i32,
                shift: rng.range(18, 62) as u32,
            });
            let zero = rng.range(-(1 << 15) + 1, (1 << 15) - 1) as i32;
            let next_zero = rng.range(-(1 << 29) + 1, (1 << 29) - 1) as i32;
            let mut acc = [0i32; 12 * HEAD_HIDDEN];
            for a in acc.iter_mut() {
                *a = match trial % 4 {
                    0 => rng.range(-(1 << 30) + 1, (1 << 30) - 1) as i32,
                    1 => rng.range(i32::MIN as i64, i32::MAX as i64) as i32,
                    _ => rng.range(-(1 << 23), 1 << 23) as i32,
                };
            }
            let mut center = [0i8; 12 * HEAD_HIDDEN];
            rng.fill_i8(&mut center);
            // Every seventh trial a center shorter than the cells (its missing codes count as 0).
            let center_len = if trial % 7 == 6 {
                5 * HEAD_HIDDEN + 7
            } else {
                center.len()
            };
            let center = (trial % 5 != 4).then_some(&center[..center_len]);
            let mut want = [0i8; 12 * HEAD_HIDDEN];
            for (i, (o, &a)) in want.iter_mut().zip(&acc).enumerate().take(nd * HEAD_HIDDEN) {
                let relu = rq.apply(i % HEAD_HIDDEN, a).max(0);
                let carried = match (carry, center) {
                    (Some(r), Some(x)) => r.apply_i64(x.get(i).copied().unwrap_or(0) as i64 - zero as i64),
                    _ => 0,
                };
                *o = sat_i8_i64(carried + relu + next_zero as i64);
            }
            match ConvEpilogue::new(&rq, carry, zero, next_zero) {
                Some(e) => {
                    let mut got = [0i8; 12 * HEAD_HIDDEN];
                    if e.apply(&acc, center, &mut got) {
                        assert_eq!(got, want, "trial {trial}");
                        taken += 1;
                    } else {
                        assert_eq!(trial % 4, 1, "trial {trial}: declined small accumulators");
                    }
                }
                None => assert_eq!(trial % 10, 9, "trial {trial}: declined ordinary formats"),
            }
        }
        assert!(taken >= 60, "{taken}");
    }

    #[test]
    fn fixed_width_gather_equals_the_general_one() {
        let mut rng = Rng::new(3);
        let (cols, nd) = (5, 4);
        for cin in [HEAD_GROUPS, HEAD_HIDDEN] {
            let mut ring = [[0i8; 5 * 4 * HEAD_HIDDEN]; 3];
            for r in ring.iter_mut() {
                rng.fill_i8(r);
            }
            let len = cols * nd * cin;
            for missing in [None, Some(0), Some(2)] {
                let rows: [Option<&[i8]>; 3] = core::array::from_fn(|i| (Some(i) != missing).then(|| &ring[i][..len]));
                for p in 0..cols {
                    let mut fixed = [0i8; 4 * TAPS * HEAD_HIDDEN];
                    let mut any = [1i8; 4 * TAPS * HEAD_HIDDEN];
                    gather(&rows, (p, cols, nd), cin, -7, &mut fixed[..nd * TAPS * cin]);
                    gather_any(&rows, (p, cols, nd), cin, -7, &mut any[..nd * TAPS * cin]);
                    assert_eq!(
                        fixed[..nd * TAPS * cin],
                        any[..nd * TAPS * cin],
                        "cin {cin} p {p} {missing:?}"
                    );
                }
            }
        }
    }
}
