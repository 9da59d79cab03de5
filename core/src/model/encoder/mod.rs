//! The int8 encoder: a band of up to 48 rows -> residual stream -> descriptor map.
//!
//! Memory (all from the caller's arena): the residual stream, keys and values of the band
//! (`3 x tokens x DIM` bytes), one score and one softmax weight per token, and scratch for
//! [`TOKEN_BLOCK`] tokens at a time. Attention runs one query at a time over the keys of its
//! window (the band, or its own token row: [`AttentionSpan`](crate::model::weights::AttentionSpan)), the MLP
//! hidden layer exists only for one token block: there is no `N x N` or `N x MLP_HIDDEN` buffer.
//!
//! Each block runs in three passes over token blocks:
//! 1. LayerNorm, keys (RoPE) and values of every token, stored per head (values transposed);
//! 2. LayerNorm, queries (RoPE), attention, output projection, residual add;
//! 3. LayerNorm, fc1, GELU table, fc2, residual add.
//!
//! Pass 2 may overwrite a token's residual because every key and value was made in pass 1.

use super::ids::{residual_after_attention, residual_after_block};
use super::probe::{Probe, Stage};
use super::weights::{EncoderWeights, ResidualFormat, EMBED_INPUTS};
use crate::arena::{Carver, ALIGN_SLACK};
use crate::blob::Blob;
use crate::config::{BAND_ROWS, CELL_W, DEPTH, DIM, MLP_HIDDEN, PATCH_H};
use crate::fixed::{round_shift, sat_i8_i64, Requant};
use crate::kernels::dispatch::matmul_requant_i8_prepared;
use crate::kernels::dispatch::ChannelRequant;
use crate::kernels::dispatch::{out_of_line, PreparedLayerNorm, PreparedResidual, QUERY_BLOCK};
use crate::kernels::params::Offset;
use crate::Error;

mod attention;
mod residual;

use attention::{key_layout_of, AttentionPass, Grid};
use residual::{mlp, prepare_with};

/// Tokens processed together by the matrix multiplies (a multiple of the kernel's 4 rows).
pub const TOKEN_BLOCK: usize = 8;

/// Fraction bits of descriptor values before the row embedding is removed.
pub const DESC_FRAC_BITS: u32 = 8;

const fn max(a: usize, b: usize) -> usize {
    if a > b {
        a
    } else {
        b
    }
}

/// Widest accumulator row: fc1's hidden layer, or keys and values together.
const ACC_WIDTH: usize = max(MLP_HIDDEN, 2 * DIM);

/// Words of the attention scores' room that the passes which score nothing lend to the
/// parameters they prepare once a pass: at most the MLP's (its LayerNorm, fc1's requantisation
/// and the residual add's lanes). A short pass (one token row) keeps this room, so its kernels
/// run on prepared parameters as a whole band's do.
const PREPARED_WORDS: usize =
    PreparedLayerNorm::storage_words(DIM) + 4 * MLP_HIDDEN + PreparedResidual::storage_words(DIM);

/// i32 words of the attention scores' room for `tokens`: one query block's scores against every
/// token, and at least [`PREPARED_WORDS`].
const fn score_words(tokens: usize) -> usize {
    max(tokens.saturating_mul(QUERY_BLOCK), PREPARED_WORDS)
}

/// Arena bytes the encoder needs for a band of `band_rows` image rows and `width` pixels.
/// Firmware sizes its static arena with it: `static ARENA: [u8; arena_bytes(48, 160)]`.
/// Saturates at `usize::MAX` for sizes no memory holds (so such a run is
/// [`Error::ArenaTooSmall`], never a small wrong size).
pub const fn arena_bytes(band_rows: usize, width: usize) -> usize {
    let tokens = (band_rows / PATCH_H).saturating_mul(2 * (width / CELL_W));
    // Bytes per token: residual stream, keys, values; softmax weights of one query block.
    let per_token = 3 * DIM + QUERY_BLOCK;
    let fixed = 2 * ALIGN_SLACK
        + TOKEN_BLOCK * (3 * DIM + MLP_HIDDEN) // normalised, queries, attention output, hidden
        + TOKEN_BLOCK * ACC_WIDTH * 4; // accumulators
    (tokens.saturating_mul(per_token))
        .saturating_add(score_words(tokens).saturating_mul(4))
        .saturating_add(fixed)
}

/// One grayscale view of a band: `height x width` pixels, row-major.
#[derive(Debug, Clone, Copy)]
pub struct GrayBand<'a> {
    pixels: &'a [u8],
    width: usize,
    height: usize,
    /// Read right to left (see [`GrayBand::mirrored`]).
    mirrored: bool,
}

impl<'a> GrayBand<'a> {
    /// A band view; `height` at most [`BAND_ROWS`], both sizes multiples of 4.
    pub fn new(pixels: &'a [u8], width: usize, height: usize) -> Result<Self, Error> {
        crate::config::check_view_size(height, width)?;
        if height > BAND_ROWS {
            return Err(Error::BandTooTall {
                rows: height,
                max: BAND_ROWS,
            });
        }
        // height <= BAND_ROWS: only an absurd width can overflow, and no slice is that long.
        let expected = width.saturating_mul(height);
        if pixels.len() != expected {
            return Err(Error::BufferSize {
                what: "band pixels",
                expected,
                found: pixels.len(),
            });
        }
        Ok(Self {
            pixels,
            width,
            height,
            mirrored: false,
        })
    }

    /// The same pixels read with each row reversed: the view of a horizontally mirrored
    /// camera, without a copy; `(right.mirrored(), left.mirrored())` is the mirrored pair,
    /// whose left view is the original right view.
    pub fn mirrored(self) -> Self {
        Self {
            mirrored: !self.mirrored,
            ..self
        }
    }

    /// Pixel rows `first..first + rows` of the band, read as it reads them (mirrored or not).
    pub fn rows(&self, first: usize, rows: usize) -> Result<Self, Error> {
        let at = first.saturating_mul(self.width);
        let len = rows.saturating_mul(self.width);
        let found = self.pixels.len();
        let pixels = self.pixels.get(at..at.saturating_add(len)).ok_or(Error::BufferSize {
            what: "band pixels",
            expected: at.saturating_add(len),
            found,
        })?;
        let band = Self::new(pixels, self.width, rows)?;
        Ok(Self {
            mirrored: self.mirrored,
            ..band
        })
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// The pixels, row-major, as given (unmirrored).
    pub fn pixels(&self) -> &'a [u8] {
        self.pixels
    }

    /// Whether it reads each row right to left ([`GrayBand::mirrored`]).
    pub fn is_mirrored(&self) -> bool {
        self.mirrored
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    #[inline(always)]
    fn code(&self, y: usize, x: usize) -> i8 {
        let x = if self.mirrored {
            // x < width for every patch read; an x outside reads as 0 below.
            self.width.checked_sub(x.saturating_add(1)).unwrap_or(usize::MAX)
        } else {
            x
        };
        // Pixel p in [0, 255] is the real value p / 255; codes are p - 128 (zero point -128).
        let p = self
            .pixels
            .get(y.saturating_mul(self.width).saturating_add(x))
            .copied()
            .unwrap_or(0);
        (p ^ 0x80) as i8
    }
}

/// What the encoder sees: a stereo pair, or one view twice (the descriptor pathway).
#[derive(Clone, Copy)]
enum Fused<'a> {
    Pair(GrayBand<'a>, GrayBand<'a>),
    Same(GrayBand<'a>),
}

impl Fused<'_> {
    /// The 4x4 fused-image patch of token (`row`, fused column `col`): per image row, view
    /// columns 2c and 2c+1 interleaved as L, R, L, R (`X[2u] = L[u]`, `X[2u+1] = R[u]`).
    fn patch(&self, row: usize, col: usize, out: &mut [i8]) {
        let (left, right) = match *self {
            Fused::Pair(l, r) => (l, r),
            Fused::Same(v) => (v, v),
        };
        for (kh, out_row) in out.chunks_exact_mut(4).take(PATCH_H).enumerate() {
            let y = PATCH_H * row + kh;
            let (u0, u1) = (2 * col, 2 * col + 1);
            out_row.copy_from_slice(&[left.code(y, u0), right.code(y, u0), left.code(y, u1), right.code(y, u1)]);
        }
    }
}

/// What a run used.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RunReport {
    /// Token rows of the band.
    pub rows: usize,
    /// Fused token columns.
    pub fused_cols: usize,
    /// Arena bytes used (the high-water mark).
    pub arena_used: usize,
}

struct Buffers<'a> {
    x: &'a mut [i8],
    keys: &'a mut [i8],
    values: &'a mut [i8],
    scores: &'a mut [i32],
    softmax: &'a mut [u8],
    normed: &'a mut [i8],
    queries: &'a mut [i8],
    attended: &'a mut [i8],
    hidden: &'a mut [i8],
    acc: &'a mut [i32],
}

impl<'a> Buffers<'a> {
    fn carve(carver: &mut Carver<'a>, tokens: usize) -> Result<Self, Error> {
        Ok(Self {
            x: carver.i8s(tokens * DIM)?,
            keys: carver.i8s(tokens * DIM)?,
            values: carver.i8s(tokens * DIM)?,
            scores: carver.i32s(score_words(tokens))?,
            softmax: carver.u8s(QUERY_BLOCK * tokens)?,
            normed: carver.i8s(TOKEN_BLOCK * DIM)?,
            queries: carver.i8s(TOKEN_BLOCK * DIM)?,
            attended: carver.i8s(TOKEN_BLOCK * DIM)?,
            hidden: carver.i8s(TOKEN_BLOCK * MLP_HIDDEN)?,
            acc: carver.i32s(TOKEN_BLOCK * ACC_WIDTH)?,
        })
    }
}

/// The int8 encoder over the weights of a blob.
#[derive(Clone, Copy)]
pub struct Encoder<'w> {
    weights: EncoderWeights<'w>,
}

impl<'w> Encoder<'w> {
    /// Validates the blob's encoder tensors (see [`EncoderWeights::new`]).
    pub fn new(blob: Blob<'w>) -> Result<Self, Error> {
        Ok(Self {
            weights: EncoderWeights::new(blob)?,
        })
    }

    /// The weights.
    pub fn weights(&self) -> &EncoderWeights<'w> {
        &self.weights
    }

    /// Whether overlapping bands may share their common token rows
    /// ([`EncoderWeights::rows_independent`]): a pass over a band's lower rows alone gives those
    /// rows exactly as a pass over the whole band does.
    pub fn rows_independent(&self) -> bool {
        self.weights.rows_independent()
    }

    /// Widest band the weights support, in pixels.
    pub fn max_width(&self) -> usize {
        self.weights.max_patch_cols() * CELL_W
    }

    /// Descriptor map of one view (the encoder on (I, I), phase tokens averaged): writes
    /// `rows/4 x width/4 x DIM` int8 codes (descriptor scale in the blob's metadata) to `out`.
    pub fn describe(
        &self,
        view: GrayBand<'_>,
        arena: &mut [u8],
        out: &mut [i8],
        probe: &mut impl Probe,
    ) -> Result<RunReport, Error> {
        let expected = (view.height / PATCH_H) * (view.width / CELL_W) * DIM;
        if out.len() != expected {
            return Err(Error::BufferSize {
                what: "descriptor output",
                expected,
                found: out.len(),
            });
        }
        let (report, x) = self.forward(Fused::Same(view), view, arena, probe)?;
        self.write_descriptors(x, report.rows, report.fused_cols, out)?;
        Ok(report)
    }

    /// The encoder on a stereo pair; the fused token stream is observed through `probe`
    /// ([`Stage::Block`] of the last block is the output before de-positioning).
    pub fn encode_pair(
        &self,
        left: GrayBand<'_>,
        right: GrayBand<'_>,
        arena: &mut [u8],
        probe: &mut impl Probe,
    ) -> Result<RunReport, Error> {
        check_pair(&left, &right)?;
        Ok(self.forward(Fused::Pair(left, right), left, arena, probe)?.0)
    }

    /// The native pathway's input (DESIGN.md, Readouts): the encoder on the pair (L, R), every
    /// fused token de-positioned and rescaled to descriptor codes (the unit of [`describe`]'s
    /// descriptors, one phase token instead of the mean of two), in the fused grid's order:
    /// `rows/4 x width/4 x [even, odd] x DIM` codes written to `out`. Patch column `p` of a row
    /// holds its even-phase token (fused column `2p`) then its odd-phase token (`2p + 1`): the
    /// two phase maps interleaved, which is the native head's pair feature `u = [a, b]` per cell.
    ///
    /// [`describe`]: Encoder::describe
    pub fn pair_tokens(
        &self,
        left: GrayBand<'_>,
        right: GrayBand<'_>,
        arena: &mut [u8],
        out: &mut [i8],
        probe: &mut impl Probe,
    ) -> Result<RunReport, Error> {
        let expected = (left.height / PATCH_H) * 2 * (left.width / CELL_W) * DIM;
        if out.len() != expected {
            return Err(Error::BufferSize {
                what: "pair token output",
                expected,
                found: out.len(),
            });
        }
        check_pair(&left, &right)?;
        let (report, x) = self.forward(Fused::Pair(left, right), left, arena, probe)?;
        let params = self.descriptor_params()?;
        let row_len = report.fused_cols * DIM;
        for (row, (x_row, out_row)) in x.chunks_exact(row_len).zip(out.chunks_exact_mut(row_len)).enumerate() {
            for (token, cell) in x_row.chunks_exact(DIM).zip(out_row.chunks_exact_mut(DIM)) {
                params.token(row, token, cell);
            }
        }
        Ok(report)
    }

    /// [`Encoder::pair_tokens`] written over the residual stream at the front of `arena`
    /// itself (each token rescaled where it lies): returns the run report and the map's length
    /// in bytes. A pipeline keeps the map there and uses the rest of the arena for the head.
    pub fn pair_tokens_in_place(
        &self,
        left: GrayBand<'_>,
        right: GrayBand<'_>,
        arena: &mut [u8],
        probe: &mut impl Probe,
    ) -> Result<(RunReport, usize), Error> {
        check_pair(&left, &right)?;
        let (report, _) = self.forward(Fused::Pair(left, right), left, arena, probe)?;
        let len = report.rows * report.fused_cols * DIM;
        let x: &mut [i8] = bytemuck::cast_slice_mut(arena.get_mut(..len).ok_or(Error::ArenaTooSmall {
            needed: len,
            available: 0,
        })?);
        let params = self.descriptor_params()?;
        let mut token = [0i8; DIM];
        for (t, cell) in x.chunks_exact_mut(DIM).enumerate() {
            token.copy_from_slice(cell);
            params.token(t / report.fused_cols.max(1), &token, cell);
        }
        Ok((report, len))
    }

    fn forward<'a>(
        &self,
        fused: Fused<'_>,
        view: GrayBand<'_>,
        arena: &'a mut [u8],
        probe: &mut impl Probe,
    ) -> Result<(RunReport, &'a [i8]), Error> {
        if view.width > self.max_width() {
            return Err(Error::TooWide {
                width: view.width,
                max: self.max_width(),
            });
        }
        let rows = view.height / PATCH_H;
        let fused_cols = 2 * (view.width / CELL_W);
        let tokens = rows * fused_cols;
        let mut carver = Carver::new(arena, arena_bytes(view.height, view.width))?;
        let buf = Buffers::carve(&mut carver, tokens)?;
        let rope = self.weights.rope()?;
        let grid = Grid { rows, fused_cols };
        self.embed(fused, grid, buf.x, buf.normed, buf.acc, buf.scores)?;
        probe.observe(Stage::Embed, rows, fused_cols, buf.x);
        let Buffers {
            x,
            keys,
            values,
            scores,
            softmax,
            normed,
            queries,
            attended,
            hidden,
            acc,
        } = buf;
        for b in 0..DEPTH {
            let w = self.weights.block(b)?;
            let input = self.weights.residual(residual_after_attention(b) - 1)?;
            let middle = self.weights.residual(residual_after_attention(b))?;
            let output = self.weights.residual(residual_after_block(b))?;
            let attention = AttentionPass {
                w: &w,
                rope: &rope,
                grid,
                input: &input,
                output: &middle,
                keys: key_layout_of(self.weights.span(), grid),
                span: self.weights.span(),
            };
            // Passes 1 and 3 in frames of their own where the core's stack budget needs it.
            out_of_line(|| attention.keys_values(x, normed, acc, keys, values, scores));
            attention.queries_attend(x, normed, acc, queries, attended, keys, values, scores, softmax, hidden)?;
            probe.observe(Stage::Attention(b), rows, fused_cols, x);
            out_of_line(|| mlp(&w, &middle, &output, x, normed, hidden, acc, scores));
            probe.observe(Stage::Block(b), rows, fused_cols, x);
        }
        Ok((
            RunReport {
                rows,
                fused_cols,
                arena_used: carver.used(),
            },
            x,
        ))
    }

    /// The patch embedding of every token into `x`; `scratch` (the attention scores' room,
    /// idle in this pass) keeps the requantisation prepared for the current token row.
    fn embed(
        &self,
        fused: Fused<'_>,
        grid: Grid,
        x: &mut [i8],
        patches: &mut [i8],
        acc: &mut [i32],
        scratch: &mut [i32],
    ) -> Result<(), Error> {
        let embed = self.weights.embed()?;
        let format = self.weights.residual(0)?;
        let mut prepared_row = None;
        let mut prepared = None;
        for (block, x_block) in x.chunks_mut(TOKEN_BLOCK * DIM).enumerate() {
            let first = block * TOKEN_BLOCK;
            let count = x_block.len() / DIM;
            for (i, patch) in patches.chunks_exact_mut(EMBED_INPUTS).take(count).enumerate() {
                let (row, col) = grid.position(first + i);
                fused.patch(row, col, patch);
            }
            // Tokens of one token row share their bias: multiplied and requantised together
            // (one parameter decode per token row where they are prepared, per run of the
            // block otherwise).
            let mut i = 0;
            while i < count {
                let (row, _) = grid.position(first + i);
                let run = (i + 1..count)
                    .take_while(|&j| grid.position(first + j).0 == row)
                    .count()
                    + 1;
                // The bias table has one row per token row: the row embedding is folded in.
                let bias = Offset {
                    inner: &embed.bias,
                    start: row * DIM,
                };
                let rq = ChannelRequant {
                    bias: &bias,
                    mult: &embed.mult,
                    shift: embed.shift,
                };
                if prepared_row != Some(row) {
                    prepared = prepare_with(&rq, &format.zero, &mut *scratch);
                    prepared_row = Some(row);
                }
                let span = i * DIM..(i + run) * DIM;
                let inputs = i * EMBED_INPUTS..(i + run) * EMBED_INPUTS;
                if let (Some(patch_rows), Some(x_rows)) = (patches.get(inputs), x_block.get_mut(span)) {
                    matmul_requant_i8_prepared(
                        patch_rows,
                        embed.weight,
                        EMBED_INPUTS,
                        prepared.as_ref(),
                        &rq,
                        &format.zero,
                        acc,
                        x_rows,
                    );
                }
                i += run;
            }
        }
        Ok(())
    }

    /// Descriptor map of one view written to the front of `arena` itself (the residual
    /// stream is carved first, and each descriptor cell only reads tokens at or after its own
    /// position): returns the run report and the map's length in bytes, `rows/4 x width/4 x
    /// DIM`. A pipeline keeps the map there and uses the rest of the arena for what follows,
    /// so no separate output buffer is needed.
    pub fn describe_in_place(
        &self,
        view: GrayBand<'_>,
        arena: &mut [u8],
        probe: &mut impl Probe,
    ) -> Result<(RunReport, usize), Error> {
        let (report, _) = self.forward(Fused::Same(view), view, arena, probe)?;
        let len = report.rows * (report.fused_cols / 2) * DIM;
        let x: &mut [i8] = bytemuck::cast_slice_mut(arena.get_mut(..report.rows * report.fused_cols * DIM).ok_or(
            Error::ArenaTooSmall {
                needed: len,
                available: 0,
            },
        )?);
        let params = self.descriptor_params()?;
        let mut even = [0i8; DIM];
        let mut odd = [0i8; DIM];
        for cell in 0..len / DIM {
            // Cell (row, p) reads fused tokens 2p and 2p + 1 of its row, at index >= 2 * cell.
            let src = 2 * cell * DIM;
            even.copy_from_slice(&x[src..src + DIM]);
            odd.copy_from_slice(&x[src + DIM..src + 2 * DIM]);
            let row = cell / (report.fused_cols / 2).max(1);
            params.cell(row, &even, &odd, &mut x[cell * DIM..(cell + 1) * DIM]);
        }
        Ok((report, len))
    }

    fn write_descriptors(&self, x: &[i8], rows: usize, fused_cols: usize, out: &mut [i8]) -> Result<(), Error> {
        let params = self.descriptor_params()?;
        let mut out_cells = out.chunks_exact_mut(DIM);
        for (row, x_row) in x.chunks_exact(fused_cols * DIM).take(rows).enumerate() {
            for pair in x_row.chunks_exact(2 * DIM) {
                let (even, odd) = pair.split_at(DIM);
                let Some(cell) = out_cells.next() else { return Ok(()) };
                params.cell(row, even, odd, cell);
            }
        }
        Ok(())
    }

    fn descriptor_params(&self) -> Result<DescriptorParams<'w>, Error> {
        let (carry, row_offsets) = self.weights.descriptor()?;
        Ok(DescriptorParams {
            format: self.weights.residual(residual_after_block(DEPTH - 1))?,
            carry,
            row_offsets,
        })
    }
}

/// How the last residual stream becomes descriptors (from the blob, looked up once).
struct DescriptorParams<'w> {
    format: ResidualFormat<'w>,
    carry: super::weights::Carry<'w>,
    row_offsets: crate::blob::Le<'w, i32>,
}

impl DescriptorParams<'_> {
    /// One descriptor: the two phase tokens of a cell averaged, rescaled, row embedding removed.
    fn cell(&self, row: usize, even: &[i8], odd: &[i8], out: &mut [i8]) {
        for (c, ((&q0, &q1), o)) in even.iter().zip(odd).zip(out.iter_mut()).enumerate() {
            let zero = self.format.zero.at(c) as i64;
            let sum = q0 as i64 - zero + (q1 as i64 - zero);
            let shift = self.carry.shift.get(c).copied().unwrap_or(1) as u32;
            let scaled = Requant {
                mult: self.carry.mult.at(c),
                shift,
            }
            .apply_i64(sum);
            let offset = self.row_offsets.at(row * DIM + c) as i64;
            *o = sat_i8_i64(round_shift(scaled - offset, DESC_FRAC_BITS));
        }
    }
}

impl DescriptorParams<'_> {
    /// One phase token of a cell, de-positioned, in descriptor codes: a cell whose two phase
    /// tokens are both `token` (their mean is the token itself).
    fn token(&self, row: usize, token: &[i8], out: &mut [i8]) {
        self.cell(row, token, token, out);
    }
}

/// [`Error::PairMismatch`] unless the two views of a pair have the same size.
fn check_pair(left: &GrayBand<'_>, right: &GrayBand<'_>) -> Result<(), Error> {
    if left.width != right.width || left.height != right.height {
        return Err(Error::PairMismatch);
    }
    Ok(())
}
