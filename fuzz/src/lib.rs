//! What the fuzz targets share: the shipped blob, resealing a mutated blob, and a small
//! pipeline run whose every input the fuzzer chooses. Each target only asserts that
//! `bino-core` returns (`Ok` or `Err`) instead of panicking or hanging; libFuzzer reports a
//! panic, an overflow (the targets build with overflow checks) or a timeout as a crash.

use arbitrary::Arbitrary;
use bino_core::blob::{Blob, CRC_BYTES};
use bino_core::crc32::crc32;
use bino_core::pipeline::{self, MatchedRow, Options, Pipeline, RowSource, Sink};
use bino_core::sgm::Penalties;
use bino_core::Error;

/// The int8 blob the product ships.
pub const SHIPPED_BLOB: &[u8] = include_bytes!("../../weights/bino_int8.bin");

/// Rewrites the trailing CRC-32 so a mutated blob gets past the checksum to the table and
/// parameter checks.
pub fn reseal(bytes: &mut [u8]) {
    let Some(body) = bytes.len().checked_sub(CRC_BYTES) else {
        return;
    };
    let crc = crc32(&bytes[..body]);
    bytes[body..].copy_from_slice(&crc.to_le_bytes());
}

/// Largest pair a fuzzed run may use: heights above 48 still make two bands, and the largest
/// run (two bands of 32 px, both encoder passes and the mirrored head) stays a few seconds under
/// the sanitizer on a loaded 2-core machine, well inside libFuzzer's 10 s timeout (48 px wide
/// with lies up to 112 rows took 11.8 s there: a CI timeout, not a hang).
pub const MAX_WIDTH: usize = 32;
/// See [`MAX_WIDTH`].
pub const MAX_HEIGHT: usize = 56;

/// A pipeline run: sizes, options, arena and the pixels, all chosen by the fuzzer.
#[derive(Debug, Arbitrary)]
pub struct Run {
    /// Width in pixels (taken modulo `MAX_WIDTH + 1`; not necessarily a multiple of 4).
    pub width: u8,
    /// Height in pixels (modulo `MAX_HEIGHT + 1`).
    pub height: u8,
    /// The height the source reports, when it lies about it (`None`: the true one).
    pub reported_height: Option<usize>,
    /// The width the source reports, when it lies about it.
    pub reported_width: Option<usize>,
    /// Source error at this row (`None`: never).
    pub fail_at: Option<u8>,
    /// Disparity candidates (valid: 1 to 64).
    pub max_cols: u8,
    /// SGM penalties.
    pub p1: u16,
    /// SGM penalties.
    pub p2: u16,
    /// SGM penalties: the guide's edge scale (0: none).
    pub edge: u8,
    /// Left-right tolerance, Q8.
    pub lr_max_diff_q8: u16,
    /// The native pathway (one pass on (L, R), the native head) instead of the export one.
    pub native: bool,
    /// Run the head (implied on the native pathway).
    pub head: bool,
    /// With the head: its left-right check (the head rerun on the mirrored pair).
    pub head_lr: bool,
    /// The head's disparity candidates (valid: 1 to 64).
    pub head_candidates: u8,
    /// The refinement's input, an index into [`REFINE_INPUTS`] (`None`: no refinement; a
    /// readout the run does not make must be refused).
    pub refine: Option<u8>,
    /// Arena bytes relative to what `Pipeline::arena_bytes` asks for.
    pub arena_delta: i16,
    /// Pixel values, cycled over both views.
    pub pixels: Vec<u8>,
}

/// A [`RowSource`] that may lie about its size and fail at a chosen row.
struct FuzzSource<'a> {
    width: usize,
    height: usize,
    pixels: &'a [u8],
    fail_at: Option<usize>,
    row: usize,
}

impl RowSource for FuzzSource<'_> {
    fn width(&self) -> usize {
        self.width
    }
    fn height(&self) -> usize {
        self.height
    }
    fn next_row(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), Error> {
        if self.fail_at == Some(self.row) {
            return Err(Error::StreamFinished);
        }
        // Bound the work of a lying source: the pipeline must stop asking on its own first.
        assert!(self.row < 2 * MAX_HEIGHT, "the pipeline read {} rows", self.row);
        for (i, p) in left.iter_mut().chain(right.iter_mut()).enumerate() {
            *p = self
                .pixels
                .get((self.row * 31 + i) % self.pixels.len().max(1))
                .copied()
                .unwrap_or(128);
        }
        self.row += 1;
        Ok(())
    }
}

/// Counts what the pipeline emits (and touches every value, so nothing is optimised out).
#[derive(Default)]
struct CountSink {
    rows: usize,
    head_rows: usize,
    census_rows: usize,
    refined_rows: usize,
    checksum: u64,
}

impl Sink for CountSink {
    fn matched(&mut self, row: &MatchedRow<'_>) {
        self.rows += 1;
        for &v in row.wta_q8.iter().chain(row.sgm_q8) {
            self.checksum = self.checksum.wrapping_mul(31).wrapping_add(v as u64);
        }
    }
    fn head(&mut self, row: bino_core::model::head::HeadRow<'_>) {
        self.head_rows += 1;
        for &v in row.disparity_q8 {
            self.checksum = self.checksum.wrapping_mul(31).wrapping_add(v as u64);
        }
    }
    fn census(&mut self, row: &pipeline::CensusRow<'_>) {
        self.census_rows += 1;
        for &v in row.disparity_q8 {
            self.checksum = self.checksum.wrapping_mul(31).wrapping_add(v as u64);
        }
    }
    fn refined(&mut self, _row: usize, disparity_q8: &[u16]) {
        self.refined_rows += 1;
        for &v in disparity_q8 {
            self.checksum = self.checksum.wrapping_mul(31).wrapping_add(v as u64);
        }
    }
}

/// Every readout the pipeline's refinement can read (the census ones by the encoder-free run).
pub const REFINE_INPUTS: [pipeline::RefineInput; 11] = [
    pipeline::RefineInput::Nolink,
    pipeline::RefineInput::NolinkLr,
    pipeline::RefineInput::Sgm,
    pipeline::RefineInput::SgmLr,
    pipeline::RefineInput::Head,
    pipeline::RefineInput::HeadLr,
    pipeline::RefineInput::FusedLr,
    pipeline::RefineInput::FusedCensusLr,
    pipeline::RefineInput::FusedAllLr,
    pipeline::RefineInput::Census,
    pipeline::RefineInput::CensusLr,
];

/// Runs `run` through the pipeline of `blob`; returns the pipeline's result.
pub fn run_pipeline(blob: Blob<'_>, run: &Run) -> Result<pipeline::Report, Error> {
    let pipeline = Pipeline::new(blob)?;
    let width = usize::from(run.width) % (MAX_WIDTH + 1);
    let height = usize::from(run.height) % (MAX_HEIGHT + 1);
    let opts = Options {
        pathway: if run.native {
            pipeline::Pathway::Native
        } else {
            pipeline::Pathway::Export
        },
        max_cols: usize::from(run.max_cols),
        penalties: Penalties {
            p1: run.p1,
            p2: run.p2,
            edge: run.edge,
        },
        lr_max_diff_q8: run.lr_max_diff_q8,
        head: run.head,
        head_lr: run.head_lr,
        head_candidates: usize::from(run.head_candidates),
    };
    // A lying source reports a size of its own: small ones are run (the pipeline then asks
    // for rows the source may not have), absurd ones must be refused before any row is read.
    // Lies stay within the sizes a fuzzed run may take, so an execution stays short (a 48x192
    // band pair six times over under the sanitizer takes seconds).
    let reported_width = match run.reported_width {
        Some(w) if w < 1 << 20 => w % (MAX_WIDTH + 1),
        Some(w) => w,
        None => width,
    };
    let reported_height = match run.reported_height {
        Some(h) if h <= bino_core::config::MAX_HEIGHT => h % (MAX_HEIGHT + 1),
        Some(h) => h,
        None => height,
    };
    // The arena a caller would size from the reported shape, nudged by the fuzzer; capped so
    // an absurd (saturated) size is not allocated: the pipeline must reject it anyway.
    let refine = run
        .refine
        .map(|i| pipeline::Refine::of(REFINE_INPUTS[usize::from(i) % REFINE_INPUTS.len()]));
    // The blob's own size (the shipped blob's passes of a few token rows), where a board sizes
    // its arena, so the nudges probe that size's edge.
    let wanted = pipeline.arena_bytes(reported_height, reported_width, &opts, refine.as_ref());
    let len = (wanted as i64 + i64::from(run.arena_delta)).clamp(0, 1 << 22) as usize;
    let mut arena = vec![0u8; len];
    let mut source = FuzzSource {
        width: reported_width,
        height: reported_height,
        pixels: &run.pixels,
        fail_at: run.fail_at.map(usize::from),
        row: 0,
    };
    let mut sink = CountSink::default();
    let report = match &refine {
        Some(r) => pipeline.run_refined(&mut source, &opts, r, &mut arena, &mut sink)?,
        None => pipeline.run(&mut source, &opts, &mut arena, &mut sink)?,
    };
    if refine.is_some() {
        // Every pixel row of the image was refined, once.
        assert_eq!(sink.refined_rows, report.rows * bino_core::config::PATCH_H);
    }
    // A finished run emitted one row per token row of each readout it ran (the native pathway
    // has only its head, the census run only the census) and stayed inside its arena.
    if refine.is_some_and(|r| r.input.census_only()) {
        assert_eq!((sink.rows, sink.head_rows, sink.census_rows), (0, 0, report.rows));
    } else if run.native {
        assert_eq!((sink.rows, sink.head_rows), (0, report.rows));
    } else {
        assert_eq!(sink.rows, report.rows);
        assert_eq!(sink.head_rows, if run.head { report.rows } else { 0 });
    }
    assert!(report.arena_used <= arena.len());
    Ok(report)
}
