//! Cortex-M55 (Helium, MVE) kernels: the GEMMs, a pair of rows against every column triple in
//! one kernel call (2 x 3 tiles, 16 MACs per `vmladava.s8` into scalar accumulators and an
//! `i32` store; a 2 x 1 or 2 x 2 tile for the last one or two columns), the fused
//! requantisation of two rows of accumulators in vector lanes; attention's scores with the
//! queries held in vector registers; the softmax row; LayerNorm's and the residual add's lanes.
//!
//! Where `k` is a multiple of 32 (the encoder's GEMMs and attention) the first 32 codes start
//! the accumulators and a plain loop runs two 16-code steps per iteration: per 192 MACs ten
//! `vldrb`, twelve `vmladava` and the loop end. Any other `k` runs one tail-predicated loop
//! (`dlstp.8` / `letp`) in steps of 16, whose last step loads and multiplies only the elements
//! left, so nothing is read past a row.
//!
//! One file per concern: `gemm` (the drivers and the 2 x 3 row kernel), `requant` (the fused
//! requantisation of two rows), `tile` (the 2 x 1 and 2 x 2 tiles of the last columns, and
//! the portable twins), attention's `scores` (and the values stored channel-major) and
//! `softmax`, `layernorm`, `rope`, `residual`, and `conv` (the head's convolution epilogue).
//! Only `gemm`, `requant` and `tile` are also compiled for host tests (the drivers, with
//! portable twins of the kernels); the rest exist on Cortex-M55 only.

#[cfg(bino_mve)]
mod conv;
mod gemm;
#[cfg(bino_mve)]
mod layernorm;
mod requant;
#[cfg(bino_mve)]
mod residual;
#[cfg(bino_mve)]
mod rope;
#[cfg(bino_mve)]
mod scores;
#[cfg(bino_mve)]
mod softmax;
mod tile;

#[cfg(bino_mve)]
pub(crate) use conv::conv_epilogue;
pub(crate) use gemm::{gemm_fused, gemm_i32, gemm_prepared};
#[cfg(bino_mve)]
pub(crate) use layernorm::{layernorm_normalise, layernorm_values, scaled_requant_lanes};
#[cfg(bino_mve)]
pub(crate) use residual::residual_add_row;
#[cfg(bino_mve)]
pub(crate) use rope::{rope_requant, rope_rotate_half};
#[cfg(bino_mve)]
pub(crate) use scores::{attention_scores, scatter_channels};
#[cfg(bino_mve)]
pub(crate) use softmax::{row_max, softmax_row};
