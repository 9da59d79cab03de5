//! The encoder-free census readout as the core streams it (`bino_core::pipeline::run_census`):
//! on one band and on images of several bands, its token rows equal a census SGM computed
//! independently over the whole map, its refined pixel rows equal the whole-map refinement of
//! that grid (filled by its check for `census+lr`, rejected cells keeping the bilinear step), it
//! never enters an encoder stage, `Pipeline::run_refined` with a census input is the same run,
//! and its arena does not grow with the image's height.

use bino_core::lr::fill_background;
use bino_core::pipeline::{
    arena_bytes_refined, census_arena_bytes, run_census, CensusRow, Options, Pathway, Pipeline, Refine, RefineInput,
    Report, Sink, SlicePair, Stage,
};
use bino_core::Error;
use bino_host::demo::{DEFAULT_BLOB, DEFAULT_PENALTIES};
use bino_host::int8::Int8Model;
use bino_tests::{census_whole_map, refine_whole_map, scene, Scene};

/// One band; 2 bands; 3 bands 8 token rows apart; an odd stride; 4; a 160x120 frame.
const SIZES: [(usize, usize); 6] = [(160, 48), (32, 56), (32, 80), (48, 100), (32, 144), (160, 120)];

fn options(pathway: Pathway) -> Options {
    Options {
        pathway,
        max_cols: 16,
        penalties: DEFAULT_PENALTIES,
        lr_max_diff_q8: 256,
        head: false,
        head_lr: false,
        head_candidates: bino_core::config::HEAD_MAX_DISP,
    }
}

#[derive(Default, Debug)]
struct Collect {
    census_rows: Vec<usize>,
    grid: Vec<u16>,
    mask: Vec<u8>,
    refined_rows: Vec<usize>,
    refined: Vec<u16>,
    stage: Option<Stage>,
    encoded: bool,
    refined_outside_stage: bool,
}

impl Sink for Collect {
    fn stage(&mut self, stage: Stage) {
        self.encoded |= stage.encodes();
        self.stage = Some(stage);
    }
    fn census(&mut self, row: &CensusRow<'_>) {
        self.census_rows.push(row.row);
        self.grid.extend_from_slice(row.disparity_q8);
        self.mask.extend_from_slice(row.consistent);
    }
    fn refined(&mut self, row: usize, disparity_q8: &[u16]) {
        self.refined_outside_stage |= self.stage != Some(Stage::Refine);
        self.refined_rows.push(row);
        self.refined.extend_from_slice(disparity_q8);
    }
}

fn run(s: &Scene, opts: &Options, refine: Option<&Refine>) -> Result<(Collect, Report), Error> {
    let mut out = Collect::default();
    let mut source = SlicePair::new(&s.left, &s.right, s.width, s.height)?;
    let needed = census_arena_bytes(s.height, s.width, opts, refine);
    let mut arena = vec![0u8; needed];
    let report = run_census(&mut source, opts, refine, &mut arena, &mut out)?;
    assert!(report.arena_used <= needed, "{report:?} needed {needed}");
    Ok((out, report))
}

/// The whole-map refinement of the census grid (filled by its check for `census+lr`).
fn whole_map(s: &Scene, grid: &[u16], mask: &[u8], refine: &Refine) -> Vec<u16> {
    if refine.input != RefineInput::CensusLr {
        return refine_whole_map(s, grid, None, refine);
    }
    let mut filled = grid.to_vec();
    for (row, m) in filled.chunks_exact_mut(s.width / 4).zip(mask.chunks_exact(s.width / 4)) {
        fill_background(row, m).unwrap();
    }
    refine_whole_map(s, &filled, Some(mask), refine)
}

#[test]
fn the_census_streams_and_refines_as_the_whole_map_on_one_band_and_many() {
    for (width, height) in SIZES {
        let s = scene(width, height);
        let (want_grid, want_mask) = census_whole_map(&s.left, &s.right, width, height, 12);
        let (plain, report) = run(&s, &options(Pathway::Export), None).unwrap();
        let what = format!("{width}x{height}");
        assert_eq!(plain.census_rows, (0..height / 4).collect::<Vec<_>>(), "{what}");
        assert!((&plain.grid, &plain.mask) == (&want_grid, &want_mask), "{what}");
        assert!(!plain.encoded && plain.refined.is_empty(), "{what}");
        let kept = want_mask.iter().filter(|&&k| k == 1).count();
        assert!(kept > 0 && kept < want_mask.len(), "{what}: {kept} kept");
        assert_eq!(report.census_kept, kept, "{what}");
        for input in [RefineInput::Census, RefineInput::CensusLr] {
            for equalise in [false, true] {
                let refine = Refine {
                    equalise,
                    ..Refine::for_width(input, width)
                };
                let what = format!("{what} {} equalise {equalise}", input.name());
                let (out, _) = run(&s, &options(Pathway::Native), Some(&refine)).unwrap();
                assert_eq!(out.refined_rows, (0..height).collect::<Vec<_>>(), "{what}");
                assert!(!out.refined_outside_stage && !out.encoded, "{what}");
                assert!((&out.grid, &out.mask) == (&want_grid, &want_mask), "{what}");
                assert!(out.refined == whole_map(&s, &want_grid, &want_mask, &refine), "{what}");
            }
        }
    }
}

#[test]
fn run_refined_with_a_census_input_is_the_encoder_free_run() {
    let model = Int8Model::load(DEFAULT_BLOB.as_ref()).unwrap();
    let pipeline = Pipeline::new(model.blob().unwrap()).unwrap();
    for pathway in [Pathway::Export, Pathway::Native] {
        let s = scene(48, 100);
        let opts = options(pathway);
        let refine = Refine::of(RefineInput::CensusLr);
        let needed = arena_bytes_refined(s.height, s.width, &opts, &refine);
        assert_eq!(needed, census_arena_bytes(s.height, s.width, &opts, Some(&refine)));
        let mut arena = vec![0u8; needed];
        let mut out = Collect::default();
        let mut source = SlicePair::new(&s.left, &s.right, s.width, s.height).unwrap();
        pipeline
            .run_refined(&mut source, &opts, &refine, &mut arena, &mut out)
            .unwrap();
        let (direct, _) = run(&s, &opts, Some(&refine)).unwrap();
        assert!(!out.encoded, "{pathway:?}");
        assert!(out.refined == direct.refined && out.grid == direct.grid, "{pathway:?}");
    }
}

#[test]
fn the_arena_does_not_grow_with_the_height_and_bad_runs_are_refused() {
    let opts = options(Pathway::Native);
    let refine = Refine::of(RefineInput::CensusLr);
    let band = census_arena_bytes(48, 160, &opts, Some(&refine));
    // Taller than a band: a few view rows kept for the refinement across band loads, the same
    // for every height.
    let frame = census_arena_bytes(52, 160, &opts, Some(&refine));
    assert!(frame > band && frame - band <= 4 * 160, "{band} {frame}");
    for height in [96, 120, 240, 480, 4000] {
        assert_eq!(census_arena_bytes(height, 160, &opts, Some(&refine)), frame, "{height}");
    }
    // Far below the encoder's: the pixel band, the census stage and the refinement.
    let native = arena_bytes_refined(48, 160, &opts, &Refine::of(RefineInput::FusedCensusLr));
    assert!(band * 4 < native, "{band} against {native}");

    let s = scene(160, 48);
    let head = Refine::of(RefineInput::HeadLr);
    assert_eq!(
        run(&s, &opts, Some(&head)).unwrap_err(),
        Error::MissingReadout { readout: "head+lr" }
    );
    let mut arena = vec![0u8; band - 1];
    let mut source = SlicePair::new(&s.left, &s.right, s.width, s.height).unwrap();
    let err = run_census(&mut source, &opts, Some(&refine), &mut arena, &mut Collect::default()).unwrap_err();
    assert_eq!(
        err,
        Error::ArenaTooSmall {
            needed: band,
            available: band - 1
        }
    );
    let none = Options {
        head_candidates: 0,
        ..opts
    };
    assert!(run(&s, &none, None).is_err());
    // Rows that stop early: the source's error, no panic.
    let mut short = SlicePair::new(&s.left[..160 * 40], &s.right[..160 * 40], 160, 40).unwrap();
    let mut tall = TallerThanItIs(&mut short);
    let mut arena = vec![0u8; band];
    assert!(matches!(
        run_census(&mut tall, &opts, Some(&refine), &mut arena, &mut Collect::default()),
        Err(Error::EndOfRows { .. })
    ));
}

/// A source that claims 48 rows and delivers 40.
struct TallerThanItIs<'a, 'p>(&'a mut SlicePair<'p>);

impl bino_core::pipeline::RowSource for TallerThanItIs<'_, '_> {
    fn width(&self) -> usize {
        self.0.width()
    }
    fn height(&self) -> usize {
        48
    }
    fn next_row(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), Error> {
        self.0.next_row(left, right)
    }
}

/// A source that counts the rows it delivered.
struct Counting<'a, 'p> {
    source: &'a mut SlicePair<'p>,
    read: &'a std::cell::Cell<usize>,
}

impl bino_core::pipeline::RowSource for Counting<'_, '_> {
    fn width(&self) -> usize {
        self.source.width()
    }
    fn height(&self) -> usize {
        self.source.height()
    }
    fn next_row(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), Error> {
        self.read.set(self.read.get() + 1);
        self.source.next_row(left, right)
    }
}

/// Rows read when each census token row came out.
struct ReadAt<'a> {
    read: &'a std::cell::Cell<usize>,
    at: Vec<usize>,
}

impl Sink for ReadAt<'_> {
    fn census(&mut self, _row: &CensusRow<'_>) {
        self.at.push(self.read.get());
    }
}

/// The rows are read as the token rows need them, not a band at a time: before token row `t`
/// the run has read its census window and the rows its refined pixel rows reach (`4 t + 10` with
/// the shipped refinement), then four rows per token row: a camera with a few line buffers
/// delivering rows no faster than they are worked on never overflows, whatever the frame's
/// height.
#[test]
fn the_rows_are_read_as_the_token_rows_need_them() {
    let s = scene(160, 120);
    let opts = options(Pathway::Native);
    let refine = Refine::of(RefineInput::CensusLr);
    let reach = refine.reach();
    let read = std::cell::Cell::new(0);
    let mut pair = SlicePair::new(&s.left, &s.right, s.width, s.height).unwrap();
    let mut source = Counting {
        source: &mut pair,
        read: &read,
    };
    let mut arena = vec![0u8; census_arena_bytes(s.height, s.width, &opts, Some(&refine))];
    let mut sink = ReadAt {
        read: &read,
        at: Vec::new(),
    };
    run_census(&mut source, &opts, Some(&refine), &mut arena, &mut sink).unwrap();
    assert_eq!(sink.at.len(), s.height / 4);
    for (t, &n) in sink.at.iter().enumerate() {
        assert_eq!(n, (4 * t + 2 + reach).min(s.height), "token row {t}");
    }
    assert_eq!(read.get(), s.height, "every row read once");
    let burst = sink.at.windows(2).map(|w| w[1] - w[0]).max().unwrap();
    assert_eq!(burst, 4, "rows read per token row after the first");
}
