//! A head's weights in the blob, every tensor checked once: the input LayerNorm, the
//! projections, the correlation and softmax scales, the convolutions with their zero points and
//! carries.

use super::super::ids::{self, kind, HeadKind, Linear, HEAD_CONVS};
use super::super::weights::{LayerNormScalars, LinearQ};
use super::sizing::{conv_inputs, conv_outputs, TAPS};
use crate::blob::Blob;
use crate::config::HEAD_MIDDLE_LAYERS;
use crate::fixed::{Requant, MAX_SHIFT};
use crate::kernels::dispatch::LayerNormQ;
use crate::kernels::params::Uniform;
use crate::Error;

/// The LayerNorm's input unit: descriptors are per-tensor, so any common scale works.
const DESC_REL: i32 = 256;

/// One head's weights in a blob, validated once.
#[derive(Clone, Copy)]
pub struct HeadWeights<'w> {
    blob: Blob<'w>,
    pub(super) kind: HeadKind,
    norm: LayerNormScalars,
    /// The correlation's requantisation.
    pub(super) correlation: Requant,
    /// Logits to the softmax's log2 Q8 unit.
    pub(super) softmax: Requant,
    /// Each convolution's input zero point.
    pub(super) zeros: [i32; HEAD_CONVS],
    /// Each middle layer's carry of its input.
    pub(super) carries: [Requant; HEAD_MIDDLE_LAYERS],
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
    pub(super) fn input_norm(&self) -> LayerNormQ<'static, Uniform, Uniform> {
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
