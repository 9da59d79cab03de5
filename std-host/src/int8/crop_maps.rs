//! The int8 engine's maps of a stack of small crops: what quantisation-aware head training
//! reads in place of the float encoder's (`python -m bino_train.int8_cache`).

use anyhow::{ensure, Context, Result};
use bino_core::config::DIM;

use super::Int8Model;
use crate::data::profile::View;
use crate::io::npy::Array;
use crate::readout::pathway::Pathway;

/// The maps the head of `pathway` reads, for every crop pair of `crops` (`(N, 2, H, W)`, gray in
/// [0, 1], left then right), dequantised: `(N, 2, H/4, W/4, DIM)`. Export: the descriptor maps
/// D(L), D(R) (one pass each); native: the even and odd phase maps of one pass on (L, R).
/// `threads` workers split the crops; the result does not depend on their number.
pub fn crop_maps(model: &Int8Model, crops: &Array, pathway: Pathway, threads: usize) -> Result<Array> {
    let [n, two, height, width] = crops.shape[..] else {
        anyhow::bail!("crops have shape {:?}; expected (N, 2, H, W)", crops.shape);
    };
    ensure!(two == 2, "crops have {two} views per crop; expected 2 (left, right)");
    let (rows, cols) = bino_core::config::check_view_size(height, width).map_err(anyhow::Error::msg)?;
    let scale = model.descriptor_scale()?;
    let per_crop = 2 * rows * cols * DIM;
    let mut out = vec![0f32; n * per_crop];
    let workers = threads.clamp(1, n.max(1));
    let chunk = n.div_ceil(workers).max(1);
    std::thread::scope(|scope| -> Result<()> {
        let handles: Vec<_> = out
            .chunks_mut(chunk * per_crop)
            .enumerate()
            .map(|(w, slot)| {
                scope.spawn(move || -> Result<()> {
                    for (k, maps) in slot.chunks_mut(per_crop).enumerate() {
                        let i = w * chunk + k;
                        let codes = crop_codes(model, crops, i, pathway)?;
                        for (m, &c) in maps.iter_mut().zip(&codes) {
                            *m = c as f32 * scale;
                        }
                    }
                    Ok(())
                })
            })
            .collect();
        for h in handles {
            h.join().map_err(|_| anyhow::anyhow!("a crop worker panicked"))??;
        }
        Ok(())
    })?;
    Array::new(vec![n, 2, rows, cols, DIM], out)
}

/// Crop `i`'s codes in `(2, rows, cols, DIM)` order.
fn crop_codes(model: &Int8Model, crops: &Array, i: usize, pathway: Pathway) -> Result<Vec<i8>> {
    let (height, width) = (crops.shape[2], crops.shape[3]);
    let view = |v: usize| {
        let at = (2 * i + v) * height * width;
        View {
            width,
            height,
            pixels: crops.data[at..at + height * width].to_vec(),
        }
    };
    let (left, right) = (view(0), view(1));
    let context = || format!("crop {i}");
    match pathway {
        Pathway::Export => {
            let (_, _, mut codes) = model.descriptor_codes(&left).with_context(context)?;
            codes.extend(model.descriptor_codes(&right).with_context(context)?.2);
            Ok(codes)
        }
        Pathway::Native => {
            let (_, _, fused) = model.pair_token_codes(&left, &right).with_context(context)?;
            // fused is (rows, cols, [even, odd], DIM): split into the two phase maps.
            let even = fused.chunks_exact(2 * DIM).flat_map(|c| c[..DIM].iter().copied());
            let odd = fused.chunks_exact(2 * DIM).flat_map(|c| c[DIM..].iter().copied());
            Ok(even.chain(odd).collect())
        }
    }
}
