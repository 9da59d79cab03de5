//! The firmware's workload, shared word for word by the firmware and by `build.rs` (which runs it
//! on the host to bake the expected digests in): one band pair through `bino_core::pipeline`
//! on either pathway of the learned preset, and a whole frame through the fast preset's
//! encoder-free census run, each with a CRC-32 digest of every output and the obstacle summary of
//! the refined rows (`bino_core::depth`: nearest depth and bearing in [`SECTORS`] column sectors).
//!
//! - Native (the board's preset): one encoder pass on (L, R) and the native head on its pair
//!   tokens, its left-right check read from the head's own logits (no second pass), the census
//!   SGM beside it, the two fused by their checks, and the pixel refinement of the fused grid
//!   (fuse-census+lr).
//! - Export: both encoder passes, (L, L) and (R, R), then WTA matching, SGM, the left-right
//!   check, the census SGM, the shared head and its own left-right check (the head on the
//!   mirrored pair, rerun on the head's arena), row by row, the head fused with the census and
//!   that with the SGM by their checks, and the pixel refinement of the fused grid
//!   (fuse-all+lr, `bino run --pathway export`'s default).
//! - Census (the fast preset, [`CENSUS_REFINE`]): no blob, no encoder; the census SGM of the
//!   pixels with its own left-right check and the pixel refinement of its grid (census+lr+ref,
//!   `bino run`'s and `bino sim`'s default), rows read as its token rows need them
//!   (`pipeline::run_census`), in [`census_arena_bytes`] whatever the frame's height.
//! - Frame (the learned preset on the whole frame): the native run on the fast preset's frame,
//!   band after band (`bino_core::band::BandPlan`), each band's head on its own rows, in
//!   [`frame_arena_bytes`].
//! - Census320 and Frame320 (the Alif E7's whole [`E7_FRAME`]): the fast and the learned preset
//!   with the options and the refinement of that width, as `bino run` and the board run them
//!   (`preset::options_for_width`: 16 head candidates, +-4 px refinement), in
//!   [`run_arena_bytes`]. Only the Cortex-M55 firmware runs them (feature `frame320`).
//!
//! The rows come from any `RowSource`: `build.rs` hands over the embedded band as a
//! `SlicePair`, the firmware the interrupt-fed camera (`camera.rs`); the digests must agree.

use bino_core::band::Band;
use bino_core::blob::Blob;
use bino_core::crc32::Crc32;
use bino_core::depth::{DepthModel, DisparityUnit, SectorSummary};
use bino_core::model::head::HeadRow;
use bino_core::pipeline::{
    self, CensusRow, FusedRow, HeadChecked, MatchedRow, Options, Pipeline, Refine, Report, RowSource, Sink,
};
use bino_core::Error;

// The readouts, the refinement, the example board's calibration and the sector count: the
// preset the board apps (`boards/`) run too.
use bino_core::preset::{census_refine_for_width, options_for_width, refine_for_width};
pub use bino_core::preset::{CALIBRATION, CENSUS_REFINE, EXPORT_OPTIONS, EXPORT_REFINE, OPTIONS, REFINE, SECTORS};

/// The Alif E7's frame, `(height, width)`: QVGA, what the board runs whole.
pub const E7_FRAME: (usize, usize) = (240, 320);

/// Arena bytes for a `height x width` band pair on both pathways (one arena serves each run).
pub const fn arena_bytes(height: usize, width: usize) -> usize {
    let export = bino_core::preset::export_arena_bytes(height, width);
    let native = bino_core::preset::arena_bytes(height, width);
    if export > native {
        export
    } else {
        native
    }
}

/// Arena bytes of the learned preset's native run on a `height x width` frame.
pub const fn frame_arena_bytes(height: usize, width: usize) -> usize {
    bino_core::preset::arena_bytes(height, width)
}

/// Arena bytes of the fast preset's census run on a `height x width` frame: the same for every
/// height from one band up.
pub const fn census_arena_bytes(height: usize, width: usize) -> usize {
    bino_core::preset::census_arena_bytes(height, width)
}

/// Arena bytes of `run` on a `height x width` pair: the preset's `const fn` for it.
pub const fn run_arena_bytes(run: Run, height: usize, width: usize) -> usize {
    match run {
        Run::Export | Run::Native => arena_bytes(height, width),
        Run::Census => census_arena_bytes(height, width),
        Run::Frame => frame_arena_bytes(height, width),
        Run::Census320 => bino_core::preset::census_arena_bytes_for_width(height, width),
        Run::Frame320 => bino_core::preset::arena_bytes_for_width(height, width),
    }
}

/// The firmware's runs, in order: the learned preset's band pair on each pathway, then the fast
/// preset's whole frame, then the learned preset's; then, on the Cortex-M55, both on the E7's
/// frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Run {
    /// The export pathway's band pair.
    Export,
    /// The native pathway's band pair (the board's learned preset).
    Native,
    /// The fast preset's frame: the census readout, no encoder.
    Census,
    /// The learned preset's frame: the native pathway, band after band.
    Frame,
    /// The fast preset on the E7's frame, with the options of its width.
    Census320,
    /// The learned preset on the E7's frame, with the options and refinement of its width.
    Frame320,
}

impl Run {
    /// Every run, in the firmware's order.
    pub const ALL: [Run; 6] = [
        Run::Export,
        Run::Native,
        Run::Census,
        Run::Frame,
        Run::Census320,
        Run::Frame320,
    ];

    /// `export`, `native`, `census`, `frame`, `census320` or `frame320`: the `pathway` of its
    /// log lines and JSON.
    pub const fn name(self) -> &'static str {
        match self {
            Run::Export => "export",
            Run::Native => "native",
            Run::Census => "census",
            Run::Frame => "frame",
            Run::Census320 => "census320",
            Run::Frame320 => "frame320",
        }
    }

    /// Whether the run is on the E7's frame ([`E7_FRAME`]), which only the Cortex-M55 firmware
    /// runs.
    pub const fn on_e7_frame(self) -> bool {
        matches!(self, Run::Census320 | Run::Frame320)
    }
}

/// The readout options and refinement of `run`.
pub const fn preset(run: Run) -> (Options, Refine) {
    let e7 = E7_FRAME.1;
    match run {
        Run::Export => (EXPORT_OPTIONS, EXPORT_REFINE),
        Run::Native | Run::Frame => (OPTIONS, REFINE),
        Run::Census => (OPTIONS, CENSUS_REFINE),
        Run::Census320 => (options_for_width(e7), census_refine_for_width(e7)),
        Run::Frame320 => (options_for_width(e7), refine_for_width(e7)),
    }
}

/// The stages the firmware reports: blob loading (the learned runs), then each pathway's
/// pipeline stages, the native run's named `native_<stage>`, then the census run's three
/// (`census_rows`, `census_sgm`, `census_refine`), then the learned frame's (`frame_<stage>`),
/// then the same two runs' on the E7's frame (`census320_<stage>`, `frame320_<stage>`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stage {
    /// Blob header, CRC over the whole blob, tensor table, weights.
    Load,
    /// A stage of `bino_core::pipeline` on the export pathway.
    Pipeline(pipeline::Stage),
    /// A stage of `bino_core::pipeline` on the native pathway.
    Native(pipeline::Stage),
    /// A stage of the census run ([`CENSUS_STAGES`]).
    Census(pipeline::Stage),
    /// A stage of `bino_core::pipeline` in the learned preset's frame.
    Frame(pipeline::Stage),
    /// A stage of the census run on the E7's frame ([`CENSUS_STAGES`]).
    Census320(pipeline::Stage),
    /// A stage of `bino_core::pipeline` in the learned preset's E7 frame.
    Frame320(pipeline::Stage),
}

/// Pipeline stages per pathway.
const PIPELINE_STAGES: usize = pipeline::Stage::ALL.len();

/// The stages `pipeline::run_census` enters: rows, the census SGM, the refinement.
pub const CENSUS_STAGES: [pipeline::Stage; 3] = [pipeline::Stage::Rows, pipeline::Stage::Sgm, pipeline::Stage::Refine];

/// Where each run's stages start in run order ([`Stage::index`]): after `load`, the export
/// and native band pairs, the census frame, the learned frame, and the two on the E7's frame.
const FIRST_OF: [usize; 6] = {
    let census = 1 + 2 * PIPELINE_STAGES;
    let frame = census + CENSUS_STAGES.len();
    let census320 = frame + PIPELINE_STAGES;
    let frame320 = census320 + CENSUS_STAGES.len();
    [1, 1 + PIPELINE_STAGES, census, frame, census320, frame320]
};

impl Stage {
    /// Number of stages.
    pub const COUNT: usize = FIRST_OF[5] + PIPELINE_STAGES;

    /// The stage `stage` of `run`.
    pub const fn of(run: Run, stage: pipeline::Stage) -> Stage {
        match run {
            Run::Export => Stage::Pipeline(stage),
            Run::Native => Stage::Native(stage),
            Run::Census => Stage::Census(stage),
            Run::Frame => Stage::Frame(stage),
            Run::Census320 => Stage::Census320(stage),
            Run::Frame320 => Stage::Frame320(stage),
        }
    }

    /// The run the stage belongs to (`None` for `load`, which the learned runs share).
    pub const fn run(self) -> Option<Run> {
        match self {
            Stage::Load => None,
            Stage::Pipeline(_) => Some(Run::Export),
            Stage::Native(_) => Some(Run::Native),
            Stage::Census(_) => Some(Run::Census),
            Stage::Frame(_) => Some(Run::Frame),
            Stage::Census320(_) => Some(Run::Census320),
            Stage::Frame320(_) => Some(Run::Frame320),
        }
    }

    /// Stage `i` in run order.
    pub const fn at(i: usize) -> Stage {
        const fn census(at: usize) -> pipeline::Stage {
            CENSUS_STAGES[at % CENSUS_STAGES.len()]
        }
        const fn all(at: usize) -> pipeline::Stage {
            pipeline::Stage::ALL[at % PIPELINE_STAGES]
        }
        if i == 0 {
            Stage::Load
        } else if i < FIRST_OF[1] {
            Stage::Pipeline(all(i - FIRST_OF[0]))
        } else if i < FIRST_OF[2] {
            Stage::Native(all(i - FIRST_OF[1]))
        } else if i < FIRST_OF[3] {
            Stage::Census(census(i - FIRST_OF[2]))
        } else if i < FIRST_OF[4] {
            Stage::Frame(all(i - FIRST_OF[3]))
        } else if i < FIRST_OF[5] {
            Stage::Census320(census(i - FIRST_OF[4]))
        } else {
            Stage::Frame320(all(i - FIRST_OF[5]))
        }
    }

    /// The stage's name in logs, JSON and its marker symbol `bino_mark_<name>`.
    pub const fn name(self) -> &'static str {
        use pipeline::Stage as P;
        match self {
            Stage::Load => "load",
            Stage::Pipeline(s) => s.name(),
            Stage::Native(s) => match s {
                P::Rows => "native_rows",
                P::EncodeLeft => "native_encode_left",
                P::EncodeRight => "native_encode_right",
                P::Match => "native_match",
                P::Sgm => "native_sgm",
                P::LeftRight => "native_left_right",
                P::Head => "native_head",
                P::Refine => "native_refine",
                P::EncodePair => "native_encode_pair",
            },
            Stage::Census(s) => match s {
                P::Rows => "census_rows",
                P::Refine => "census_refine",
                // The census SGM; run_census enters no other stage.
                _ => "census_sgm",
            },
            Stage::Frame(s) => match s {
                P::Rows => "frame_rows",
                P::EncodeLeft => "frame_encode_left",
                P::EncodeRight => "frame_encode_right",
                P::Match => "frame_match",
                P::Sgm => "frame_sgm",
                P::LeftRight => "frame_left_right",
                P::Head => "frame_head",
                P::Refine => "frame_refine",
                P::EncodePair => "frame_encode_pair",
            },
            Stage::Census320(s) => match s {
                P::Rows => "census320_rows",
                P::Refine => "census320_refine",
                _ => "census320_sgm",
            },
            Stage::Frame320(s) => match s {
                P::Rows => "frame320_rows",
                P::EncodeLeft => "frame320_encode_left",
                P::EncodeRight => "frame320_encode_right",
                P::Match => "frame320_match",
                P::Sgm => "frame320_sgm",
                P::LeftRight => "frame320_left_right",
                P::Head => "frame320_head",
                P::Refine => "frame320_refine",
                P::EncodePair => "frame320_encode_pair",
            },
        }
    }

    /// Index in run order (`Stage::at(s.index()) == s`).
    pub fn index(self) -> usize {
        let position = |s: pipeline::Stage| pipeline::Stage::ALL.iter().position(|&x| x == s).unwrap_or(0);
        // run_census enters no other stage; were it to, it would count as the SGM's.
        let census = |s: pipeline::Stage| CENSUS_STAGES.iter().position(|&x| x == s).unwrap_or(1);
        match self {
            Stage::Load => 0,
            Stage::Pipeline(s) => FIRST_OF[0] + position(s),
            Stage::Native(s) => FIRST_OF[1] + position(s),
            Stage::Census(s) => FIRST_OF[2] + census(s),
            Stage::Frame(s) => FIRST_OF[3] + position(s),
            Stage::Census320(s) => FIRST_OF[4] + census(s),
            Stage::Frame320(s) => FIRST_OF[5] + position(s),
        }
    }
}

/// The outputs the firmware digests: one slot each, filled by the runs that make it.
pub const OUTPUTS: [&str; 12] = [
    "descriptors_left",
    "descriptors_right",
    "wta",
    "sgm",
    "left_right",
    "head",
    "head_left_right",
    "refined",
    "sectors",
    "pair_tokens",
    "fused",
    "census",
];

/// The slots of [`OUTPUTS`] `run` fills, in order.
pub const fn outputs(run: Run) -> &'static [usize] {
    match run {
        Run::Export => &[0, 1, 2, 3, 4, 5, 6, 10, 7, 8],
        Run::Native | Run::Frame | Run::Frame320 => &[9, 5, 6, 10, 7, 8],
        Run::Census | Run::Census320 => &[11, 7, 8],
    }
}

/// What the workload tells its caller about where it is.
pub trait Hooks {
    /// `stage` starts now (the previous one, if any, is over).
    fn enter(&mut self, stage: Stage);
    /// Work outside the stages starts (digests); `resume` follows.
    fn pause(&mut self);
    /// The stage that was paused goes on.
    fn resume(&mut self, stage: Stage);
    /// The last stage is over.
    fn finish(&mut self);
}

/// What a run produced: a digest per output, the pipeline's report.
#[derive(Debug, Clone, Copy)]
pub struct Outcome {
    /// CRC-32 of each of [`OUTPUTS`], over all its rows in order.
    pub digests: [u32; OUTPUTS.len()],
    /// Arena use and left-right counts, from the pipeline.
    pub report: Report,
    /// Nearest depth per column sector of the refined rows.
    pub sectors: SectorSummary<SECTORS>,
}

struct Recorder<'h, H> {
    hooks: &'h mut H,
    run: Run,
    current: Stage,
    crcs: [Crc32; OUTPUTS.len()],
    sectors: SectorSummary<SECTORS>,
    /// The first error of the sector summary (a row of the wrong length).
    depth_error: Option<Error>,
}

impl<H: Hooks> Recorder<'_, H> {
    /// Digests `f`'s updates outside the current stage.
    fn digest(&mut self, f: impl FnOnce(&mut [Crc32; OUTPUTS.len()])) {
        self.hooks.pause();
        f(&mut self.crcs);
        self.hooks.resume(self.current);
    }
}

impl<H: Hooks> Sink for Recorder<'_, H> {
    fn stage(&mut self, stage: pipeline::Stage) {
        self.current = Stage::of(self.run, stage);
        self.hooks.enter(self.current);
    }

    fn band(&mut self, band: Band, left: &[i8], right: &[i8]) {
        // The rows this band provides (one band here: all of them).
        let row_len = left.len() / band.rows.max(1);
        let rows = (band.keep_from - band.start) * row_len..(band.keep_to - band.start) * row_len;
        self.digest(|c| {
            update_i8(&mut c[0], left.get(rows.clone()).unwrap_or_default());
            update_i8(&mut c[1], right.get(rows).unwrap_or_default());
        });
    }

    fn pair_band(&mut self, band: Band, tokens: &[i8]) {
        let row_len = tokens.len() / band.rows.max(1);
        let rows = (band.keep_from - band.start) * row_len..(band.keep_to - band.start) * row_len;
        self.digest(|c| update_i8(&mut c[9], tokens.get(rows).unwrap_or_default()));
    }

    fn matched(&mut self, row: &MatchedRow<'_>) {
        self.digest(|c| {
            update_u16(&mut c[2], row.wta_q8);
            update_u16(&mut c[3], row.sgm_q8);
            c[4].update(row.wta_consistent).update(row.sgm_consistent);
        });
    }

    fn head(&mut self, row: HeadRow<'_>) {
        self.digest(|c| {
            update_u16(&mut c[5], row.disparity_q8);
            update_u16(&mut c[5], row.confidence_q8);
            for &l in row.logits {
                c[5].update(&l.to_le_bytes());
            }
        });
    }

    fn head_checked(&mut self, row: &HeadChecked<'_>) {
        self.digest(|c| {
            update_u16(&mut c[6], row.right_q8);
            c[6].update(row.consistent);
        });
    }

    fn fused(&mut self, row: &FusedRow<'_>) {
        self.digest(|c| {
            update_u16(&mut c[10], row.disparity_q8);
            c[10].update(row.consistent);
        });
    }

    fn census(&mut self, row: &CensusRow<'_>) {
        self.digest(|c| {
            update_u16(&mut c[11], row.disparity_q8);
            c[11].update(row.consistent);
        });
    }

    fn refined(&mut self, _row: usize, disparity_q8: &[u16]) {
        self.hooks.pause();
        update_u16(&mut self.crcs[7], disparity_q8);
        if let Err(e) = self.sectors.push_row(disparity_q8, None) {
            self.depth_error.get_or_insert(e);
        }
        self.hooks.resume(self.current);
    }
}

/// Runs every stage of `run` on the rows of `source` in `arena` (the census run reads no blob).
pub fn run(
    blob: &[u8],
    run: Run,
    source: &mut impl RowSource,
    arena: &mut [u8],
    hooks: &mut impl Hooks,
) -> Result<Outcome, Error> {
    let first = match run {
        Run::Census | Run::Census320 => Stage::of(run, pipeline::Stage::Rows),
        _ => Stage::Load,
    };
    hooks.enter(first);
    // Refined rows are Q8 pixels at the band's width.
    let depth = DepthModel::new(&CALIBRATION, source.width(), DisparityUnit::Pixels)?;
    let mut recorder = Recorder {
        hooks,
        run,
        current: first,
        crcs: [Crc32::new(); OUTPUTS.len()],
        sectors: SectorSummary::new(&depth, source.width())?,
        depth_error: None,
    };
    let (options, refine) = preset(run);
    let report = match run {
        Run::Census | Run::Census320 => pipeline::run_census(source, &options, Some(&refine), arena, &mut recorder),
        Run::Export | Run::Native | Run::Frame | Run::Frame320 => {
            match Blob::parse(blob).map_err(Error::from).and_then(Pipeline::new) {
                Ok(pipeline) => pipeline.run_refined(source, &options, &refine, arena, &mut recorder),
                Err(e) => Err(e),
            }
        }
    };
    recorder.hooks.finish();
    let report = report?;
    if let Some(e) = recorder.depth_error {
        return Err(e);
    }
    let mut digests = recorder.crcs.map(|c| c.finish());
    digests[8] = sectors_digest(&recorder.sectors);
    Ok(Outcome {
        digests,
        report,
        sectors: recorder.sectors,
    })
}

/// CRC-32 of every sector's columns, bearing bits, nearest depth (`u32::MAX` for none), its
/// row and cell count: the float bearings must agree to the bit as well.
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

/// Arena bytes in use during each stage (index as [`Stage::index`]), from the pipeline report
/// of each run (`None`: the run did not run; its stages used none). Export: the pixel band,
/// plus the left descriptors and the encoder's scratch while encoding, plus both descriptor maps
/// and the readout streams afterwards, and the refinement's buffers while it refines. Native:
/// the pixel band and the head check's rows, plus the encoder's scratch while encoding; the
/// whole high-water after (the head's stream and the refinement's row scratch follow the tokens
/// in that scratch). Census: the pixel band, plus the census SGM's stream, plus the
/// refinement's state and row scratch while it refines. Frame: as native. The E7 frame's runs:
/// as census and frame.
pub fn arena_per_stage(report_of: impl Fn(Run) -> Option<Report>) -> [usize; Stage::COUNT] {
    use pipeline::Stage as P;
    let mut out = [0; Stage::COUNT];
    for (i, o) in out.iter_mut().enumerate() {
        let stage = Stage::at(i);
        let Some(r) = stage.run().and_then(&report_of) else {
            continue;
        };
        *o = match stage {
            Stage::Native(s) | Stage::Frame(s) | Stage::Frame320(s) => match s {
                P::Rows => r.pixels,
                P::EncodePair => r.pixels + r.streams + r.encoder,
                _ => r.arena_used,
            },
            Stage::Pipeline(s) => match s {
                P::Rows => r.pixels,
                P::EncodeLeft | P::EncodeRight | P::EncodePair => r.pixels + r.descriptors + r.encoder,
                P::Refine => r.pixels + 2 * r.descriptors + r.streams + r.refine,
                _ => r.pixels + 2 * r.descriptors + r.streams,
            },
            Stage::Census(s) | Stage::Census320(s) => match s {
                P::Rows => r.pixels,
                P::Refine => r.arena_used,
                _ => r.pixels + r.streams,
            },
            Stage::Load => 0,
        };
    }
    out
}

fn update_i8(crc: &mut Crc32, codes: &[i8]) {
    let mut buf = [0u8; 64];
    for chunk in codes.chunks(buf.len()) {
        for (b, &c) in buf.iter_mut().zip(chunk) {
            *b = c as u8;
        }
        crc.update(&buf[..chunk.len()]);
    }
}

fn update_u16(crc: &mut Crc32, values: &[u16]) {
    for &v in values {
        crc.update(&v.to_le_bytes());
    }
}
