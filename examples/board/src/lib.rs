//! One band pair through `bino-core` on a board, digested as the QEMU firmware digests it.
//!
//! The program (`main.rs`) owns the memory: the weight blob in flash and a static arena of
//! [`ARENA_BYTES`]. This library does the rest, the same on the board and on the host: parse the
//! blob, pull the band's rows one at a time from a [`RowSource`] (here [`Camera`], standing in for
//! a sensor), and fold every output the pipeline hands its [`Sink`] into the CRC-32 [`Digests`]
//! the firmware computes (`docs/integration.md`, "The output digests": the native pathway's,
//! which the board preset runs). [`EXPECTED`] holds the firmware's digests of the shipped test
//! band.
#![no_std]

use bino_core::band::Band;
use bino_core::blob::Blob;
use bino_core::crc32::Crc32;
use bino_core::depth::{DepthModel, DisparityUnit, SectorSummary};
use bino_core::model::head::HeadRow;
use bino_core::pipeline::{FusedRow, HeadChecked, Pipeline, Report, RowSource, Sink};
use bino_core::preset::{self, CALIBRATION, SECTORS};
use bino_core::Error;

/// Band height in pixels: one band (taller frames stream through the same arena).
pub const HEIGHT: usize = 48;
/// Band width in pixels: the width the preset and the board budget are made for.
pub const WIDTH: usize = 160;
/// Arena bytes the run needs, from the preset's `const fn`.
pub const ARENA_BYTES: usize = preset::arena_bytes(HEIGHT, WIDTH);

/// The outputs digested, in slot order: those of the preset's native pathway (one encoder pass
/// on (L, R): its pair tokens, the native head, its one-pass left-right check, the head fused
/// with the census SGM, the refined pixels and their obstacle summary).
pub const OUTPUTS: [&str; 6] = ["pair_tokens", "head", "head_left_right", "fused", "refined", "sectors"];

/// The firmware's digests of the shipped 48x160 test band (`firmware-sim/assets/`) on both
/// Cortex-M cores and on the host (`firmware-sim/measured/m55.json`, `m7.json`).
pub const EXPECTED: Digests = Digests([
    0x30bb_9bf5, // pair_tokens
    0xf61f_b858, // head
    0x0b64_a21d, // head_left_right
    0x236d_f604, // fused
    0x53cc_34d5, // refined
    0x0763_59eb, // sectors
]);

/// CRC-32 (IEEE) of each of [`OUTPUTS`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Digests(pub [u32; OUTPUTS.len()]);

/// A camera stand-in: hands over a frame already in memory one row at a time, as a DMA line
/// buffer would. A real driver waits in `next_row` for the sensor's next line and copies it.
pub struct Camera<'a> {
    left: &'a [u8],
    right: &'a [u8],
    next: usize,
}

impl<'a> Camera<'a> {
    /// A `WIDTH x HEIGHT` frame per view (8-bit grey, rectified, row-major).
    pub fn new(left: &'a [u8], right: &'a [u8]) -> Self {
        Self { left, right, next: 0 }
    }
}

impl RowSource for Camera<'_> {
    fn width(&self) -> usize {
        WIDTH
    }

    fn height(&self) -> usize {
        HEIGHT
    }

    fn next_row(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), Error> {
        let row = self.next * WIDTH..(self.next + 1) * WIDTH;
        match (self.left.get(row.clone()), self.right.get(row)) {
            (Some(l), Some(r)) if left.len() == WIDTH && right.len() == WIDTH => {
                left.copy_from_slice(l);
                right.copy_from_slice(r);
                self.next += 1;
                Ok(())
            }
            // A frame shorter than HEIGHT rows (the pipeline never asks for more).
            _ => Err(Error::EndOfRows {
                row: self.next,
                height: HEIGHT,
            }),
        }
    }
}

/// Digests every output it is handed, and summarises the refined rows' nearest depth per column
/// sector.
struct Recorder {
    crcs: [Crc32; OUTPUTS.len()],
    sectors: SectorSummary<SECTORS>,
    /// The first error of the sector summary.
    error: Option<Error>,
}

impl Sink for Recorder {
    fn pair_band(&mut self, band: Band, tokens: &[i8]) {
        // The token rows this band keeps (one band: all of them), `cols x 2 x 128` codes each.
        let row_len = tokens.len() / band.rows.max(1);
        let kept = (band.keep_from - band.start) * row_len..(band.keep_to - band.start) * row_len;
        update_i8(&mut self.crcs[0], tokens.get(kept).unwrap_or_default());
    }

    fn head(&mut self, row: HeadRow<'_>) {
        update_u16(&mut self.crcs[1], row.disparity_q8);
        update_u16(&mut self.crcs[1], row.confidence_q8);
        for l in row.logits {
            self.crcs[1].update(&l.to_le_bytes());
        }
    }

    fn head_checked(&mut self, row: &HeadChecked<'_>) {
        update_u16(&mut self.crcs[2], row.right_q8);
        self.crcs[2].update(row.consistent);
    }

    fn fused(&mut self, row: &FusedRow<'_>) {
        update_u16(&mut self.crcs[3], row.disparity_q8);
        self.crcs[3].update(row.consistent);
    }

    fn refined(&mut self, _row: usize, disparity_q8: &[u16]) {
        update_u16(&mut self.crcs[4], disparity_q8);
        if let Err(e) = self.sectors.push_row(disparity_q8, None) {
            self.error.get_or_insert(e);
        }
    }
}

/// Runs the band `camera` delivers through the preset's readouts and refinement in `arena`
/// ([`ARENA_BYTES`] at least) and digests every output.
pub fn run_band(blob: &[u8], camera: &mut impl RowSource, arena: &mut [u8]) -> Result<(Digests, Report), Error> {
    let pipeline = Pipeline::new(Blob::parse(blob)?)?; // header, CRC and tensor table, once
                                                       // Refined rows are Q8 pixels at the band's width.
    let depth = DepthModel::new(&CALIBRATION, camera.width(), DisparityUnit::Pixels)?;
    let mut recorder = Recorder {
        crcs: [Crc32::new(); OUTPUTS.len()],
        sectors: SectorSummary::new(&depth, camera.width())?,
        error: None,
    };
    let report = pipeline.run_refined(camera, &preset::OPTIONS, &preset::REFINE, arena, &mut recorder)?;
    if let Some(e) = recorder.error {
        return Err(e);
    }
    let mut digests = recorder.crcs.map(|c| c.finish());
    digests[5] = sectors_digest(&recorder.sectors);
    Ok((Digests(digests), report))
}

/// Per sector: its columns, the bits of its bearing, the nearest depth (`u32::MAX` for none), its
/// row and cell count.
fn sectors_digest(summary: &SectorSummary<SECTORS>) -> u32 {
    let mut crc = Crc32::new();
    for s in summary.sectors() {
        crc.update(&s.first_col.to_le_bytes())
            .update(&s.end_col.to_le_bytes())
            .update(&s.bearing_rad.to_bits().to_le_bytes())
            .update(&s.nearest_mm.unwrap_or(u32::MAX).to_le_bytes())
            .update(&s.nearest_row.to_le_bytes())
            .update(&s.cells.to_le_bytes());
    }
    crc.finish()
}

/// int8 codes as bytes.
fn update_i8(crc: &mut Crc32, codes: &[i8]) {
    for &c in codes {
        crc.update(&[c as u8]);
    }
}

/// `u16` values, little-endian.
fn update_u16(crc: &mut Crc32, values: &[u16]) {
    for v in values {
        crc.update(&v.to_le_bytes());
    }
}
