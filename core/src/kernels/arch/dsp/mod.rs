//! Cortex-M7 (Armv7E-M DSP extension) tile: 4 rows x 1 column, two MACs per `smlad`.
//!
//! Each block of 4 activation rows is widened once into a stack scratch of signed 16-bit
//! pairs, interleaved so one `ldrd` brings a row's `(a0, a2)` and `(a1, a3)` of a 4-element
//! group; each weight word is widened in registers (`sxtb16` gives `(w0, w2)`, with `ror #8`
//! `(w1, w3)`) and shared by the 4 rows: per 16 MACs one `ldr`, two `sxtb16`, four `ldrd` and
//! eight `smlad`, the loop unrolled over eight groups where their count allows (two where it is
//! even). The scratch is reused for every output column.
//!
//! One file per concern: `tile` (the widened layout and the tile itself), `gemm` (the drivers
//! and the four-row block kernels), attention's `scores`, `softmax` and `weighted_sums`,
//! `layernorm`, `rope`, `residual`, and `conv` (the head's convolution epilogue). The tile's
//! assembly text (`group!`, `groups8!`) is defined here, before the files that use it.
//! `conv`, `layernorm`, `residual` and `rope` exist on Cortex-M7 only; the others are also
//! compiled for host tests, with portable twins of the assembly.

/// One 4-element group of a tile column as assembly text: a weight word from `{w}` widened by
/// two `sxtb16` into `(w0, w2)` and `(w1, w3)`, then per row one `ldrd` of its widened pair from
/// `{x}` (post-incremented) and two `smlad` into `{a0}`-`{a3}` (temporaries `{t0}`, `{t1}`,
/// `{x0}`, `{x1}`): 15 instructions for 16 MACs.
#[cfg(bino_dsp)]
macro_rules! group {
    () => {
        concat!(
            "ldr {t0}, [{w}], #4\n",
            "ldrd {x0}, {x1}, [{x}], #8\n",
            "sxtb16 {t1}, {t0}\n",
            "sxtb16 {t0}, {t0}, ror #8\n",
            "smlad {a0}, {x0}, {t1}, {a0}\n",
            "smlad {a0}, {x1}, {t0}, {a0}\n",
            "ldrd {x0}, {x1}, [{x}], #8\n",
            "smlad {a1}, {x0}, {t1}, {a1}\n",
            "smlad {a1}, {x1}, {t0}, {a1}\n",
            "ldrd {x0}, {x1}, [{x}], #8\n",
            "smlad {a2}, {x0}, {t1}, {a2}\n",
            "smlad {a2}, {x1}, {t0}, {a2}\n",
            "ldrd {x0}, {x1}, [{x}], #8\n",
            "smlad {a3}, {x0}, {t1}, {a3}\n",
            "smlad {a3}, {x1}, {t0}, {a3}\n",
        )
    };
}

/// Eight `group!`s: the unrolled loop body (122 instructions per 128 MACs with its branch).
#[cfg(bino_dsp)]
macro_rules! groups8 {
    () => {
        concat!(
            group!(),
            group!(),
            group!(),
            group!(),
            group!(),
            group!(),
            group!(),
            group!()
        )
    };
}

/// Activation rows per tile.
pub(super) const ROWS: usize = 4;

#[cfg(bino_dsp)]
mod conv;
mod gemm;
#[cfg(bino_dsp)]
mod layernorm;
#[cfg(bino_dsp)]
mod residual;
#[cfg(bino_dsp)]
mod rope;
mod scores;
mod softmax;
mod tile;
mod weighted_sums;

#[cfg(bino_dsp)]
pub(crate) use conv::conv_epilogue;
pub(crate) use gemm::{gemm, gemm_rows_in};
#[cfg(bino_dsp)]
pub(super) use gemm::{rows_i32, rows_requant};
#[cfg(bino_dsp)]
pub(crate) use layernorm::{layernorm_normalise, layernorm_values, scaled_requant};
#[cfg(bino_dsp)]
pub(crate) use residual::{magnitude_bits, residual_rows8, RESIDUAL_ROWS, RESIDUAL_STRIDE, RESIDUAL_WORDS};
#[cfg(bino_dsp)]
pub(crate) use rope::{rope_requant, rope_rotate_half};
pub(crate) use scores::attention_scores;
#[cfg(bino_dsp)]
pub(crate) use softmax::row_max;
pub(crate) use softmax::softmax_row;
pub(crate) use weighted_sums::{softmax_row_widened, softmax_weighted_sums};
