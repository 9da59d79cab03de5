//! The int8 engine of `bino-core` on the host: a blob file, descriptor maps of whole views
//! (overlapping bands, like the float reference), and dequantised stage outputs for
//! comparisons.

pub mod blob_writer;
pub mod crop_maps;
mod heads;
pub mod pass_cache;
pub mod pipeline_maps;

use std::path::{Path, PathBuf};

use anyhow::{ensure, Context, Result};
use bino_core::band::BandPlan;
use bino_core::blob::Blob;
use bino_core::config::{check_view_size, CELL_W, DIM, PATCH_H};
use bino_core::model::encoder::{arena_bytes, Encoder, GrayBand};
use bino_core::model::ids::{self, kind};
use bino_core::model::probe::{NoProbe, Probe, Stage};
use bino_core::{matching, sgm};

use crate::band_maps::BandedRows;
use crate::data::profile::View;
use crate::eval::DisparityMap;
use crate::float::reference::FeatureMap;

pub use heads::HeadMaps;

/// A weight blob read from a file, with its encoder validated.
pub struct Int8Model {
    path: PathBuf,
    bytes: Vec<u8>,
}

impl Int8Model {
    /// Reads and validates `path` (made by `bino quantize`).
    pub fn load(path: &Path) -> Result<Self> {
        let bytes = crate::io::files::read(path, "weight blob")?;
        let model = Self {
            path: path.to_path_buf(),
            bytes,
        };
        model
            .encoder()
            .with_context(|| format!("invalid weight blob {}", path.display()))?;
        Ok(model)
    }

    /// Wraps blob bytes already in memory.
    pub fn from_bytes(bytes: Vec<u8>, name: &str) -> Result<Self> {
        let model = Self {
            path: PathBuf::from(name),
            bytes,
        };
        model.encoder().with_context(|| format!("invalid weight blob {name}"))?;
        Ok(model)
    }

    /// Where the blob came from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The blob's bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.bytes
    }

    /// The parsed blob.
    pub fn blob(&self) -> Result<Blob<'_>> {
        Blob::parse(&self.bytes).map_err(|e| anyhow::anyhow!("{e}"))
    }

    /// The encoder over the blob.
    pub fn encoder(&self) -> Result<Encoder<'_>> {
        Encoder::new(self.blob()?).map_err(|e| anyhow::anyhow!("{e}"))
    }

    /// Real value of one descriptor code.
    pub fn descriptor_scale(&self) -> Result<f32> {
        meta_f32(&self.blob()?, ids::id(kind::META_DESC_SCALE, 0), 1).map(|v| v[0])
    }

    /// Per-channel (scale, zero point) of residual format `s`, to dequantise stage outputs.
    pub fn residual_format(&self, s: usize) -> Result<(Vec<f32>, Vec<i32>)> {
        let blob = self.blob()?;
        let scale = meta_f32(&blob, ids::id(kind::META_RESIDUAL_SCALE, s), DIM)?;
        let zero = blob
            .i32s(ids::id(kind::RESIDUAL_ZERO, s), DIM)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        Ok((scale, zero.iter().collect()))
    }

    /// Int8 descriptor codes of a whole view (`H/4 x W/4 x DIM`), band by band.
    pub fn descriptor_codes(&self, view: &View) -> Result<(usize, usize, Vec<i8>)> {
        self.descriptor_codes_probed(view, &mut NoProbe)
    }

    /// [`Int8Model::descriptor_codes`], with every band's stages shown to `probe`.
    pub fn descriptor_codes_probed(&self, view: &View, probe: &mut impl Probe) -> Result<(usize, usize, Vec<i8>)> {
        let (cols, bands) = self.descriptor_bands_probed(view, probe)?;
        Ok((bands.rows, cols, bands.assemble()))
    }

    /// [`Int8Model::descriptor_codes`] as the bands computed them, overlaps included: (patch
    /// columns, every band's rows). The export head reads each band on its own
    /// ([`Int8Model::head_banded`]).
    pub fn descriptor_bands(&self, view: &View) -> Result<(usize, BandedRows<i8>)> {
        self.descriptor_bands_probed(view, &mut NoProbe)
    }

    /// [`Int8Model::descriptor_bands`], with every band's stages shown to `probe`.
    pub fn descriptor_bands_probed(&self, view: &View, probe: &mut impl Probe) -> Result<(usize, BandedRows<i8>)> {
        let encoder = self.encoder()?;
        let pixels = to_u8(&view.pixels);
        self.band_outputs(view, 1, |band, arena, band_out| {
            encoder
                .describe(band.gray(&pixels)?, arena, band_out, probe)
                .map_err(anyhow::Error::msg)?;
            Ok(())
        })
    }

    /// The native pathway's input codes of a pair (`H/4 x W/4 x [even, odd] x DIM`: the
    /// de-positioned fused token grid in descriptor codes, `Encoder::pair_tokens`), band by band,
    /// each row from the band that keeps it.
    pub fn pair_token_codes(&self, left: &View, right: &View) -> Result<(usize, usize, Vec<i8>)> {
        let (cols, bands) = self.pair_token_bands(left, right)?;
        Ok((bands.rows, cols, bands.assemble()))
    }

    /// [`Int8Model::pair_token_codes`] as the bands computed them, overlaps included: (patch
    /// columns, every band's rows). The native head reads each band on its own
    /// ([`Int8Model::native_head_banded`]).
    pub fn pair_token_bands(&self, left: &View, right: &View) -> Result<(usize, BandedRows<i8>)> {
        ensure!(
            (left.width, left.height) == (right.width, right.height),
            "views differ in size: {}x{} and {}x{}",
            left.width,
            left.height,
            right.width,
            right.height
        );
        let encoder = self.encoder()?;
        let (left_px, right_px) = (to_u8(&left.pixels), to_u8(&right.pixels));
        self.band_outputs(left, 2, |band, arena, band_out| {
            encoder
                .pair_tokens(
                    band.gray(&left_px)?,
                    band.gray(&right_px)?,
                    arena,
                    band_out,
                    &mut NoProbe,
                )
                .map_err(anyhow::Error::msg)?;
            Ok(())
        })
    }

    /// Dequantised [`Int8Model::pair_token_codes`] (`H/4 x W/2 x DIM`, fused columns), comparable
    /// with the float reference's de-positioned token grid (`ReferenceEncoder::tokens`).
    pub fn pair_tokens(&self, left: &View, right: &View) -> Result<FeatureMap> {
        let (rows, cols, codes) = self.pair_token_codes(left, right)?;
        let scale = self.descriptor_scale()?;
        Ok(FeatureMap {
            rows,
            cols: 2 * cols,
            dim: DIM,
            data: codes.iter().map(|&c| c as f32 * scale).collect(),
        })
    }

    /// Runs `encode` on every band of `view`'s size (it gets the band's rows, the band arena
    /// and the band's output of `per_cell x DIM` codes per patch column): (patch columns, every
    /// band's output rows, each band whole).
    fn band_outputs<F>(&self, view: &View, per_cell: usize, mut encode: F) -> Result<(usize, BandedRows<i8>)>
    where
        F: FnMut(BandRows, &mut [u8], &mut [i8]) -> Result<()>,
    {
        let encoder = self.encoder()?;
        let (rows, cols) = check_view_size(view.height, view.width).map_err(anyhow::Error::msg)?;
        ensure!(
            view.width <= encoder.max_width(),
            "view is {} px wide; the blob supports at most {} (quantise with a larger --max-width)",
            view.width,
            encoder.max_width()
        );
        let plan = BandPlan::new(rows).map_err(anyhow::Error::msg)?;
        let mut arena = vec![0u8; arena_bytes(bino_core::config::BAND_ROWS, view.width)];
        let row_len = cols * per_cell * DIM;
        let width = view.width;
        let mut bands = Vec::with_capacity(plan.len());
        for band in plan.iter() {
            let rows_of_band = BandRows {
                first: band.start * PATCH_H,
                height: band.rows * PATCH_H,
                width,
            };
            let mut band_out = vec![0i8; band.rows * row_len];
            encode(rows_of_band, &mut arena, &mut band_out)?;
            bands.push((band, band_out));
        }
        Ok((cols, BandedRows { rows, row_len, bands }))
    }

    /// Dequantised descriptor map of a view, comparable with the float reference's.
    pub fn descriptors(&self, view: &View) -> Result<FeatureMap> {
        let (rows, cols, codes) = self.descriptor_codes(view)?;
        let scale = self.descriptor_scale()?;
        Ok(FeatureMap {
            rows,
            cols,
            dim: DIM,
            data: codes.iter().map(|&c| c as f32 * scale).collect(),
        })
    }
}

/// The pixel rows of one band of a view.
#[derive(Clone, Copy)]
struct BandRows {
    first: usize,
    height: usize,
    width: usize,
}

impl BandRows {
    /// The band of a whole view's pixels (`width` per row).
    fn gray<'p>(&self, pixels: &'p [u8]) -> Result<GrayBand<'p>> {
        let rows = pixels
            .get(self.first * self.width..(self.first + self.height) * self.width)
            .context("band outside the view")?;
        GrayBand::new(rows, self.width, self.height).map_err(anyhow::Error::msg)
    }
}

/// The pair token layout (`[cell][even, odd][dim]`) from two phase maps of `dim`-value cells.
pub fn interleave_phases<T: Copy>(even: &[T], odd: &[T], dim: usize) -> Vec<T> {
    let mut out = Vec::with_capacity(even.len() + odd.len());
    for (a, b) in even.chunks_exact(dim).zip(odd.chunks_exact(dim)) {
        out.extend_from_slice(a);
        out.extend_from_slice(b);
    }
    out
}

/// Pixels in [0, 1] as the 8-bit codes a camera delivers.
pub fn to_u8(pixels: &[f32]) -> Vec<u8> {
    pixels
        .iter()
        .map(|&v| (v * 255.0).round().clamp(0.0, 255.0) as u8)
        .collect()
}

/// A probe that keeps a dequantised copy of every stage of one band.
#[derive(Default)]
pub struct StageRecorder {
    /// (stage, rows, fused columns, residual codes).
    pub stages: Vec<(Stage, usize, usize, Vec<i8>)>,
}

impl Probe for StageRecorder {
    fn observe(&mut self, stage: Stage, rows: usize, fused_cols: usize, codes: &[i8]) {
        self.stages.push((stage, rows, fused_cols, codes.to_vec()));
    }
}

/// Real values of residual codes in a per-channel format.
pub fn dequantise_residual(codes: &[i8], scale: &[f32], zero: &[i32]) -> Vec<f32> {
    codes
        .chunks_exact(DIM)
        .flat_map(|token| {
            token
                .iter()
                .enumerate()
                .map(|(c, &q)| scale[c] * (q as i32 - zero[c]) as f32)
        })
        .collect()
}

fn meta_f32(blob: &Blob<'_>, id: bino_core::blob::TensorId, len: usize) -> Result<Vec<f32>> {
    let (dtype, bytes) = blob.raw(id).map_err(|e| anyhow::anyhow!("{e}"))?;
    ensure!(
        dtype == bino_core::blob::Dtype::F32 && bytes.len() == 4 * len,
        "blob metadata {id:?} malformed"
    );
    Ok(bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect())
}

/// The integer no-linkage readout of `bino_core::matching`, row by row as a streaming pipeline
/// runs it: descriptor codes (`rows x cols x DIM`, both views) to disparity in patch columns.
pub fn match_rows(left: &[i8], right: &[i8], rows: usize, cols: usize, max_cols: usize) -> Result<DisparityMap> {
    ensure!(
        left.len() == rows * cols * DIM && right.len() == left.len(),
        "descriptor maps differ from {rows}x{cols}x{DIM}"
    );
    let mut norms = vec![0u32; cols];
    let mut row_out = vec![0u16; cols];
    let mut values = Vec::with_capacity(rows * cols);
    for (l, r) in left.chunks_exact(cols * DIM).zip(right.chunks_exact(cols * DIM)) {
        matching::inverse_norms(r, &mut norms).map_err(anyhow::Error::msg)?;
        matching::match_row(l, r, &norms, max_cols, &mut row_out).map_err(anyhow::Error::msg)?;
        let unit = (1u32 << matching::DISPARITY_FRAC_BITS) as f32;
        values.extend(row_out.iter().map(|&d| d as f32 / unit));
    }
    Ok(DisparityMap {
        width: cols,
        height: rows,
        values,
    })
}

/// Each token cell's mean grey level over a view (`rows x cols`, row by row), as the core's
/// pipeline computes the SGM guide from its band buffer: the view's 8-bit pixels
/// ([`to_u8`]), averaged by [`bino_core::sgm::cell_guide`].
pub fn guide_map(view: &View) -> Result<Vec<u8>> {
    let (rows, cols) = (view.height / PATCH_H, view.width / CELL_W);
    let pixels = to_u8(&view.pixels);
    let mut out = vec![0u8; rows * cols];
    for (r, cells) in out.chunks_exact_mut(cols.max(1)).enumerate() {
        let rows: Vec<&[u8]> = (0..PATCH_H)
            .map(|i| &pixels[(r * PATCH_H + i) * view.width..(r * PATCH_H + i + 1) * view.width])
            .collect();
        sgm::cell_guide(&rows, CELL_W, cells).map_err(anyhow::Error::msg)?;
    }
    Ok(out)
}

/// The no-linkage costs through `bino_core::sgm` (4 streaming paths, then the same parabola
/// refinement): descriptor codes (`rows x cols x DIM`, both views) to disparity in patch columns.
pub fn sgm_rows(
    left: &[i8],
    right: &[i8],
    rows: usize,
    cols: usize,
    max_cols: usize,
    penalties: sgm::Penalties,
    guide: Option<&[u8]>,
) -> Result<DisparityMap> {
    ensure!(
        left.len() == rows * cols * DIM && right.len() == left.len(),
        "descriptor maps differ from {rows}x{cols}x{DIM}"
    );
    let len = sgm::state_len(cols, max_cols);
    let (mut vertical, mut diagonal, mut sum) = (vec![0u16; len], vec![0u16; len], vec![0u32; len]);
    let mut stream = sgm::SgmStream::new(cols, max_cols, penalties, &mut vertical, &mut diagonal, &mut sum)
        .map_err(anyhow::Error::msg)?;
    let mut prev_guide = vec![0u8; cols];
    if guide.is_some() {
        ensure!(
            guide.is_some_and(|g| g.len() == rows * cols),
            "the SGM guide is not {rows}x{cols}"
        );
        stream = stream.with_guide(&mut prev_guide).map_err(anyhow::Error::msg)?;
    }
    let (mut norms_l, mut norms_r) = (vec![0u32; cols], vec![0u32; cols]);
    let mut cost = vec![0u16; len];
    let mut row_out = vec![0u16; cols];
    let mut values = Vec::with_capacity(rows * cols);
    let unit = (1u32 << matching::DISPARITY_FRAC_BITS) as f32;
    for (l, r) in left.chunks_exact(cols * DIM).zip(right.chunks_exact(cols * DIM)) {
        matching::inverse_norms(l, &mut norms_l).map_err(anyhow::Error::msg)?;
        matching::inverse_norms(r, &mut norms_r).map_err(anyhow::Error::msg)?;
        matching::cost_row(l, r, &norms_l, &norms_r, max_cols, &mut cost).map_err(anyhow::Error::msg)?;
        match guide {
            Some(g) => {
                let row = values.len() / cols.max(1);
                stream.push_row_guided(&cost, &g[row * cols..(row + 1) * cols], &mut row_out)
            }
            None => stream.push_row(&cost, &mut row_out),
        }
        .map_err(anyhow::Error::msg)?;
        values.extend(row_out.iter().map(|&d| d as f32 / unit));
    }
    Ok(DisparityMap {
        width: cols,
        height: rows,
        values,
    })
}
