//! The encoder's int8 tensors from its float weights and the chosen formats
//! (every formula is in docs/int8-model.md).

use anyhow::{ensure, Context, Result};
use bino_core::config::{BAND_TOKEN_ROWS, DEPTH, DIM, HEADS, HEAD_DIM, MLP_HIDDEN};
use bino_core::config::{HEAD_GROUPS, HEAD_HIDDEN, HEAD_MAX_DISP, HEAD_MIDDLE_LAYERS, HEAD_PROJ_DIM};
use bino_core::fixed::Requant;
use bino_core::kernels::types::layernorm::Z_FRAC_BITS;
use bino_core::kernels::types::rope::{QUARTER, TRIG_FRAC_BITS};
use bino_core::model::encoder::DESC_FRAC_BITS;
use bino_core::model::ids::{self, kind, Linear, CONFIG_LEN};
use bino_core::model::weights::EMBED_INPUTS;

use super::formats::{ChannelFormat, EncoderFormats};
use super::scales::{quantize_rows, requant_of};
use crate::float::weights::{FloatEncoder, FloatLinear};
use crate::int8::blob_writer::BlobWriter;

/// Fraction bits the attention output carries before its output factor.
const AVG_FRAC_BITS: u32 = bino_core::kernels::types::attention::AVG_FRAC_BITS;
/// Q8 of queries and keys before the rotation.
const PRE_ROPE: f64 = (1u32 << bino_core::kernels::types::rope::PRE_ROPE_FRAC_BITS) as f64;
/// Residual `REL` values are at most this (the common unit is the largest scale / 2^15).
const REL_MAX: f64 = 32768.0;

/// Writes every encoder tensor of the blob.
pub fn write_encoder(
    float: &FloatEncoder,
    f: &EncoderFormats,
    max_patch_cols: usize,
    w: &mut BlobWriter,
) -> Result<()> {
    ensure!(
        float.blocks.len() == DEPTH,
        "the ONNX encoder has {} blocks, expected {DEPTH}",
        float.blocks.len()
    );
    ensure!(max_patch_cols > 0 && max_patch_cols < 1 << 16, "max width out of range");
    let mut config = [0u16; CONFIG_LEN];
    let values = [
        DIM,
        DEPTH,
        HEADS,
        MLP_HIDDEN,
        BAND_TOKEN_ROWS,
        max_patch_cols,
        HEAD_PROJ_DIM,
        HEAD_GROUPS,
        HEAD_HIDDEN,
        HEAD_MIDDLE_LAYERS,
        HEAD_MAX_DISP,
    ];
    for (c, v) in config.iter_mut().zip(values) {
        *c = v as u16;
    }
    w.add_u16(ids::id(kind::CONFIG, 0), &config)?;
    if let Some(rows) = float.attention_rows {
        w.add_u16(ids::id(kind::ATTENTION_ROWS, 0), &[rows])?;
    }
    write_embedding(float, f, w)?;
    for (s, format) in f.residual.iter().enumerate() {
        w.add_i32(ids::id(kind::RESIDUAL_ZERO, s), &format.zero)?;
        w.add_i32(ids::id(kind::RESIDUAL_REL, s), &relative_scales(format))?;
        let scales: Vec<f32> = format.scale.iter().map(|&x| x as f32).collect();
        w.add_f32(ids::id(kind::META_RESIDUAL_SCALE, s), &scales)?;
    }
    for b in 0..DEPTH {
        write_block(float, f, b, w).with_context(|| format!("quantising block {b}"))?;
    }
    write_rope(float.rope_base as f64, max_patch_cols, w)?;
    write_descriptor(float, f, w)
}

fn write_embedding(float: &FloatEncoder, f: &EncoderFormats, w: &mut BlobWriter) -> Result<()> {
    // Gray input is replicated to three channels: sum the channels' kernels (exact).
    let channels = float.patch_weight.len() / (DIM * EMBED_INPUTS);
    let mut folded = vec![0f32; DIM * EMBED_INPUTS];
    for n in 0..DIM {
        for ch in 0..channels {
            for k in 0..EMBED_INPUTS {
                folded[n * EMBED_INPUTS + k] += float.patch_weight[(n * channels + ch) * EMBED_INPUTS + k];
            }
        }
    }
    let (codes, scales) = quantize_rows(&folded, EMBED_INPUTS);
    let out = &f.residual[0];
    let mut bias = Vec::with_capacity(BAND_TOKEN_ROWS * DIM);
    for r in 0..BAND_TOKEN_ROWS {
        for (n, &scale) in scales.iter().enumerate() {
            let acc_scale = scale / 255.0;
            // Pixel codes are p - 128: the zero point adds 128 * sum_k w[n, k].
            let zero_point_term = 128.0 * row_sum(&codes, EMBED_INPUTS, n) as f64;
            let real = float.patch_bias[n] as f64 + float.row_embed[r * DIM + n] as f64;
            bias.push(to_i32(zero_point_term + real / acc_scale)?);
        }
    }
    let mults: Result<Vec<Requant>> = (0..DIM).map(|n| requant_of(scales[n] / 255.0 / out.scale[n])).collect();
    write_linear(w, Linear::Embed, &codes, &bias, &mults?)
}

fn write_block(float: &FloatEncoder, f: &EncoderFormats, b: usize, w: &mut BlobWriter) -> Result<()> {
    let block = &float.blocks[b];
    let (input, middle, output) = (&f.residual[2 * b], &f.residual[2 * b + 1], &f.residual[2 * b + 2]);
    write_layernorm(
        w,
        ids::layernorm_index(b, false),
        input,
        f.layernorm[2 * b],
        block.ln_eps as f64,
    )?;
    write_layernorm(
        w,
        ids::layernorm_index(b, true),
        middle,
        f.layernorm[2 * b + 1],
        block.ln_eps as f64,
    )?;

    // Q, K, V: LayerNorm affine folded in; q and k to Q8 of their scale (RoPE follows).
    let qkv = fold_layernorm(&block.qkv, &block.norm1_weight, &block.norm1_bias);
    let (codes, scales) = quantize_rows(&qkv.weight, DIM);
    let ln1 = f.layernorm[2 * b];
    let bias = biases(&qkv.bias, &scales, ln1, &codes, DIM, 0)?;
    let mut mults = Vec::with_capacity(3 * DIM);
    for (n, &s) in scales.iter().enumerate() {
        let acc = ln1 * s;
        mults.push(match n / DIM {
            0 => requant_of(acc * PRE_ROPE / f.queries[b])?,
            1 => requant_of(acc * PRE_ROPE / f.keys[b])?,
            _ => requant_of(acc / f.values[b])?,
        });
    }
    write_linear(w, Linear::Qkv(b), &codes, &bias, &mults)?;

    let score = f.queries[b] * f.keys[b] / (HEAD_DIM as f64).sqrt();
    let to_log2 = requant_of(score * std::f64::consts::LOG2_E * 256.0)?;
    let out = requant_of(f.values[b] / (f.attended[b] * (1u64 << AVG_FRAC_BITS) as f64))?;
    let per_head = [to_log2.mult, to_log2.shift as i32, out.mult, out.shift as i32];
    let attention: Vec<i32> = (0..HEADS).flat_map(|_| per_head).collect();
    w.add_i32(ids::id(kind::ATTENTION, b), &attention)?;

    write_residual_linear(w, Linear::Proj(b), &block.proj, f.attended[b], 0, middle)?;
    write_carry(w, 2 * b, input, middle)?;

    let fc1 = fold_layernorm(&block.fc1, &block.norm2_weight, &block.norm2_bias);
    let (codes, scales) = quantize_rows(&fc1.weight, DIM);
    let ln2 = f.layernorm[2 * b + 1];
    let bias = biases(&fc1.bias, &scales, ln2, &codes, DIM, 0)?;
    let mults: Result<Vec<Requant>> = scales.iter().map(|&s| requant_of(ln2 * s / f.gelu_input[b])).collect();
    write_linear(w, Linear::Fc1(b), &codes, &bias, &mults?)?;

    let g = f.gelu_output[b];
    let table: Vec<i8> = (0..256u32)
        .map(|i| {
            let code = i as u8 as i8;
            let y = gelu(code as f64 * f.gelu_input[b]);
            ((y / g.scale).round() + g.zero as f64).clamp(-128.0, 127.0) as i8
        })
        .collect();
    w.add_i8(ids::id(kind::GELU_TABLE, b), &table)?;
    write_residual_linear(w, Linear::Fc2(b), &block.fc2, g.scale, g.zero, output)?;
    write_carry(w, 2 * b + 1, middle, output)
}

/// A linear layer whose output is added to the residual stream (in `out`'s format).
fn write_residual_linear(
    w: &mut BlobWriter,
    layer: Linear,
    float: &FloatLinear,
    in_scale: f64,
    in_zero: i32,
    out: &ChannelFormat,
) -> Result<()> {
    let (codes, scales) = quantize_rows(&float.weight, float.in_features);
    let bias = biases(&float.bias, &scales, in_scale, &codes, float.in_features, in_zero)?;
    let mults: Result<Vec<Requant>> = (0..float.out_features)
        .map(|n| requant_of(in_scale * scales[n] / out.scale[n]))
        .collect();
    write_linear(w, layer, &codes, &bias, &mults?)
}

/// Bias in accumulator units, with the input zero point folded in: `b / (s_in s_w) - zero sum_k w`.
fn biases(bias: &[f32], scales: &[f64], in_scale: f64, codes: &[i8], inputs: usize, in_zero: i32) -> Result<Vec<i32>> {
    (0..scales.len())
        .map(|n| {
            let zero_term = in_zero as f64 * row_sum(codes, inputs, n) as f64;
            to_i32(bias[n] as f64 / (in_scale * scales[n]) - zero_term)
        })
        .collect()
}

fn write_linear(w: &mut BlobWriter, layer: Linear, codes: &[i8], bias: &[i32], mults: &[Requant]) -> Result<()> {
    let mult: Vec<i32> = mults.iter().map(|r| r.mult).collect();
    let shift: Vec<u8> = mults.iter().map(|r| r.shift as u8).collect();
    w.add_i8(layer.id(kind::LINEAR_WEIGHT), codes)?;
    w.add_i32(layer.id(kind::LINEAR_BIAS), bias)?;
    w.add_i32(layer.id(kind::LINEAR_MULT), &mult)?;
    w.add_u8(layer.id(kind::LINEAR_SHIFT), &shift)?;
    Ok(())
}

fn write_carry(w: &mut BlobWriter, from: usize, input: &ChannelFormat, output: &ChannelFormat) -> Result<()> {
    let mults: Result<Vec<Requant>> = (0..DIM).map(|n| requant_of(input.scale[n] / output.scale[n])).collect();
    let mults = mults?;
    w.add_i32(
        ids::id(kind::CARRY_MULT, from),
        &mults.iter().map(|r| r.mult).collect::<Vec<_>>(),
    )?;
    w.add_u8(
        ids::id(kind::CARRY_SHIFT, from),
        &mults.iter().map(|r| r.shift as u8).collect::<Vec<_>>(),
    )?;
    Ok(())
}

/// The common unit of a format's LayerNorm: the largest channel scale / 2^15.
fn unit(format: &ChannelFormat) -> f64 {
    format.scale.iter().cloned().fold(0.0, f64::max) / REL_MAX
}

fn relative_scales(format: &ChannelFormat) -> Vec<i32> {
    let u = unit(format);
    format.scale.iter().map(|&s| (s / u).round().max(1.0) as i32).collect()
}

fn write_layernorm(w: &mut BlobWriter, index: usize, input: &ChannelFormat, out_scale: f64, eps: f64) -> Result<()> {
    let u = unit(input);
    let eps_units = (eps / (u * u)).round() as i64;
    let out = requant_of(1.0 / (out_scale * (1u64 << Z_FRAC_BITS) as f64))?;
    w.add_i64(
        ids::id(kind::LAYERNORM, index),
        &[eps_units, out.mult as i64, out.shift as i64],
    )?;
    Ok(())
}

fn write_rope(base: f64, max_patch_cols: usize, w: &mut BlobWriter) -> Result<()> {
    let one = (1u32 << TRIG_FRAC_BITS) as f64;
    let table = |positions: usize| -> Vec<i16> {
        let mut t = Vec::with_capacity(positions * 2 * QUARTER);
        for pos in 0..positions {
            let angles: Vec<f64> = (0..QUARTER)
                .map(|i| pos as f64 / base.powf(i as f64 / QUARTER as f64))
                .collect();
            t.extend(angles.iter().map(|a| (a.cos() * one).round() as i16));
            t.extend(angles.iter().map(|a| (a.sin() * one).round() as i16));
        }
        t
    };
    w.add_i16(ids::id(kind::ROPE_ROWS, 0), &table(BAND_TOKEN_ROWS))?;
    w.add_i16(ids::id(kind::ROPE_COLS, 0), &table(max_patch_cols))?;
    Ok(())
}

fn write_descriptor(float: &FloatEncoder, f: &EncoderFormats, w: &mut BlobWriter) -> Result<()> {
    let last = &f.residual[2 * DEPTH];
    let q8 = (1u32 << DESC_FRAC_BITS) as f64;
    // Phase average (the 1/2) and Q8 in one factor.
    let mults: Result<Vec<Requant>> = last
        .scale
        .iter()
        .map(|&s| requant_of(s * 0.5 * q8 / f.descriptor))
        .collect();
    let mults = mults?;
    w.add_i32(
        ids::id(kind::DESC_MULT, 0),
        &mults.iter().map(|r| r.mult).collect::<Vec<_>>(),
    )?;
    w.add_u8(
        ids::id(kind::DESC_SHIFT, 0),
        &mults.iter().map(|r| r.shift as u8).collect::<Vec<_>>(),
    )?;
    let offsets: Result<Vec<i32>> = float
        .row_embed
        .iter()
        .map(|&a| to_i32(a as f64 / f.descriptor * q8))
        .collect();
    w.add_i32(ids::id(kind::DESC_ROW_OFFSET, 0), &offsets?)?;
    w.add_f32(ids::id(kind::META_DESC_SCALE, 0), &[f.descriptor as f32])?;
    Ok(())
}

/// `W diag(gamma)` and `b + W beta`: LayerNorm's affine part moved into the next layer.
fn fold_layernorm(linear: &FloatLinear, gamma: &[f32], beta: &[f32]) -> FloatLinear {
    let k = linear.in_features;
    let mut weight = linear.weight.clone();
    let mut bias = linear.bias.clone();
    for (n, row) in weight.chunks_exact_mut(k).enumerate() {
        let mut shift = 0f64;
        for (i, wv) in row.iter_mut().enumerate() {
            shift += *wv as f64 * beta[i] as f64;
            *wv *= gamma[i];
        }
        bias[n] += shift as f32;
    }
    FloatLinear {
        out_features: linear.out_features,
        in_features: k,
        weight,
        bias,
    }
}

fn row_sum(codes: &[i8], inputs: usize, n: usize) -> i64 {
    codes[n * inputs..(n + 1) * inputs].iter().map(|&c| c as i64).sum()
}

fn to_i32(x: f64) -> Result<i32> {
    let r = x.round();
    ensure!(
        r.is_finite() && r.abs() < 2f64.powi(31),
        "a bias does not fit in 32 bits ({x:e})"
    );
    Ok(r as i32)
}

/// The erf GELU of the float model (`F.gelu`).
pub fn gelu(x: f64) -> f64 {
    0.5 * x * (1.0 + libm::erf(x / std::f64::consts::SQRT_2))
}
