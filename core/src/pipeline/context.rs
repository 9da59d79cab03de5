//! What the stages of one run share ([`Context`]): the head's weights, the options and the
//! view's size; its helpers cut the refinement's scratch and run the export pathway's two
//! encoder passes (the encoder is the run's [`BandEncoder`], not part of the context).

use super::api::{BandEncoder, Options, Passes, Refine, Sink, Stage};
#[cfg(doc)]
use super::arena_bytes_for;
use super::feeding::Fresh;
use super::refine_stage::{BandView, RefineIo, Scratch};
use super::sizing::{arena_bytes_with, ReadoutShape};
use crate::arena::split;
use crate::config::{DIM, PATCH_H};
use crate::model::encoder::GrayBand;
use crate::model::head::HeadWeights;
use crate::Error;

/// What the stages of one run share.
pub(super) struct Context<'p, 'w> {
    pub(super) head: Option<HeadWeights<'w>>,
    pub(super) opts: &'p Options,
    pub(super) refine: Option<&'p Refine>,
    pub(super) cols: usize,
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) band_px: usize,
    /// How the encoder covers a band: with [`Passes::TokenRows`] (weights whose token rows are
    /// independent) overlapping bands also share their common token rows.
    pub(super) passes: Passes,
}

impl Context<'_, '_> {
    /// Whether overlapping bands share their common token rows ([`Fresh`]).
    pub(super) fn shared_rows(&self) -> bool {
        self.passes == Passes::TokenRows
    }

    /// The arena bytes of this run ([`arena_bytes_with`]), for the error of an arena that
    /// turns out too small.
    pub(super) fn too_small(&self, available: usize) -> Error {
        Error::ArenaTooSmall {
            needed: arena_bytes_with(self.height, self.width, self.opts, self.refine, self.passes),
            available,
        }
    }

    /// Whether this run checks the head left against right.
    pub(super) fn head_lr(&self) -> bool {
        self.head.is_some() && self.opts.head_lr
    }

    /// The head's shape in the arena (sized even without a head: see [`arena_bytes_for`]).
    pub(super) fn head_shape(&self) -> ReadoutShape {
        ReadoutShape {
            lr: self.head_lr(),
            ..ReadoutShape::of(self.opts, self.refine)
        }
    }

    /// The refinement's view of the band buffer and its row scratch, cut from `arena` (none
    /// without the refinement).
    pub(super) fn refine_io<'b>(&self, view: BandView<'b>, arena: &'b mut [u8]) -> Result<RefineIo<'b>, Error> {
        let scratch = Scratch::of(self.refine, arena, self.width, self.height)?;
        Ok(RefineIo { view, scratch })
    }

    /// Both passes of `encoder` over the band in the pixel buffers: the left descriptors are
    /// copied to `desc_left`, the right ones stay at the front of `scratch`. The band's first
    /// `fresh.kept` token rows are the band before's (in `desc_left` and at the front of
    /// `scratch`): they are moved to the front and only the rest is encoded. Returns the
    /// encoder's high-water, the right descriptors and the rest of `scratch`.
    pub(super) fn encode<'s>(
        &self,
        encoder: &mut impl BandEncoder,
        (left_px, right_px): (&[u8], &[u8]),
        fresh: Fresh,
        desc_left: &mut [i8],
        scratch: &'s mut [u8],
        sink: &mut impl Sink,
    ) -> Result<(usize, &'s [i8], &'s mut [u8]), Error> {
        let row_len = self.cols * DIM;
        fresh.keep(desc_left, row_len, "descriptor band")?;
        fresh.keep(scratch, row_len, "descriptor band")?;
        let kept_len = fresh.kept * row_len;
        let fresh_px = self.band_px - fresh.kept * PATCH_H;
        let fresh_len = desc_left.len().saturating_sub(kept_len);
        let available = scratch.len();
        let (_, work) = split(scratch, kept_len).ok_or(Error::ArenaTooSmall {
            needed: kept_len,
            available,
        })?;
        sink.stage(Stage::EncodeLeft);
        let view = GrayBand::new(fresh.pixels(left_px, self.width), self.width, fresh_px)?;
        let (left_used, len) = encoder.view_pass(view, work)?;
        let codes: &[i8] = bytemuck::cast_slice(work.get(..len).unwrap_or_default());
        Error::check_len("descriptor band", fresh_len, codes.len())?;
        desc_left.get_mut(kept_len..).unwrap_or_default().copy_from_slice(codes);
        sink.stage(Stage::EncodeRight);
        let view = GrayBand::new(fresh.pixels(right_px, self.width), self.width, fresh_px)?;
        let (right_used, len) = encoder.view_pass(view, work)?;
        // A stand-in encoder may answer with any length: the right band must be the left's.
        Error::check_len("descriptor band", fresh_len, len)?;
        let (right, rest) = split(scratch, kept_len + len).ok_or(Error::ArenaTooSmall {
            needed: kept_len + len,
            available,
        })?;
        Ok((kept_len + left_used.max(right_used), bytemuck::cast_slice(right), rest))
    }
}
