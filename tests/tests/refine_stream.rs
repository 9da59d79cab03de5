//! The pixel refinement as a stage of `bino_core::pipeline` (issue 14): for every readout it can
//! refine, on one band and on images of several bands, with and without the head and its
//! left-right check, with and without the sharpness equalisation, the pixel rows it streams
//! equal the whole-map refinement (`refine::sharpness::refine_map_equalised` or
//! `refine::refine_map`) of that readout's token map (filled by its left-right check for the
//! `+lr` ones, whose rejected cells then keep the bilinear step: `refine::keep_rejected_map`),
//! computed from the same run's token rows; the other outputs do not change, and
//! the arena grows as documented. The fused rows the pipeline streams are `lr::fuse_row` of
//! its own head and SGM rows with their checks.

use bino_core::census;
use bino_core::lr::fuse_head_weight;
use bino_core::model::head::HeadRow;
use bino_core::pipeline::{
    arena_bytes_for, arena_bytes_head_lr, arena_bytes_refined, refine_bytes, FusedRow, HeadChecked, MatchedRow,
    Options, Pipeline, Refine, RefineInput, Sink, SlicePair, Stage,
};
use bino_core::refine::sharpness::decide_map_row;
use bino_core::refine::RefineParams;
use bino_core::Error;
use bino_host::demo::{DEFAULT_BLOB, DEFAULT_PENALTIES};
use bino_host::int8::Int8Model;
use bino_host::readout::fuse_grid;
use bino_tests::{census_whole_map, refine_whole_map, scene, Scene};

const MAX_COLS: usize = 16;

/// One band; 2 bands; 3 bands 8 token rows apart (the ring's worst case); an odd stride; 4.
const SIZES: [(usize, usize); 5] = [(160, 48), (32, 56), (32, 80), (48, 100), (32, 144)];

const INPUTS: [RefineInput; 7] = [
    RefineInput::Nolink,
    RefineInput::NolinkLr,
    RefineInput::Sgm,
    RefineInput::SgmLr,
    RefineInput::Head,
    RefineInput::HeadLr,
    RefineInput::FusedLr,
];

fn options(head: bool, head_lr: bool) -> Options {
    Options {
        pathway: bino_core::pipeline::Pathway::Export,
        max_cols: MAX_COLS,
        penalties: DEFAULT_PENALTIES,
        lr_max_diff_q8: 256,
        head,
        head_lr,
        head_candidates: bino_core::config::HEAD_MAX_DISP,
    }
}

/// Every token row by index, and the refined rows in arrival order.
#[derive(Default, PartialEq, Debug)]
struct Collect {
    width: usize,
    cols: usize,
    wta: Vec<u16>,
    wta_mask: Vec<u8>,
    sgm: Vec<u16>,
    sgm_mask: Vec<u8>,
    head: Vec<u16>,
    head_confidence: Vec<u16>,
    head_mask: Vec<u8>,
    fused: Vec<u16>,
    fused_mask: Vec<u8>,
    /// Token rows of the fused readout, in arrival order.
    fused_rows: Vec<usize>,
    refined_rows: Vec<usize>,
    refined: Vec<u16>,
    /// The stage of each refined row's arrival.
    refine_stage_ok: bool,
    stage: Option<Stage>,
}

impl Collect {
    fn new(width: usize, height: usize) -> Self {
        let cells = (height / 4) * (width / 4);
        Self {
            width,
            cols: width / 4,
            wta: vec![0; cells],
            wta_mask: vec![0; cells],
            sgm: vec![0; cells],
            sgm_mask: vec![0; cells],
            head: vec![0; cells],
            head_confidence: vec![0; cells],
            head_mask: vec![0; cells],
            fused: vec![0; cells],
            fused_mask: vec![0; cells],
            refine_stage_ok: true,
            ..Self::default()
        }
    }

    fn put<T: Copy>(map: &mut [T], cols: usize, row: usize, values: &[T]) {
        map[row * cols..(row + 1) * cols].copy_from_slice(values);
    }

    /// The left-right mask of a `+lr` input, `None` for the others.
    fn mask(&self, input: RefineInput) -> Option<&[u8]> {
        match input {
            RefineInput::NolinkLr => Some(&self.wta_mask),
            RefineInput::SgmLr => Some(&self.sgm_mask),
            RefineInput::HeadLr => Some(&self.head_mask),
            RefineInput::FusedLr | RefineInput::FusedCensusLr | RefineInput::FusedAllLr => Some(&self.fused_mask),
            _ => None,
        }
    }

    /// The token grid `input` reads, filled where it is a `+lr` one.
    fn grid(&self, input: RefineInput) -> Vec<u16> {
        let (map, mask) = match input {
            RefineInput::Nolink | RefineInput::NolinkLr => (&self.wta, &self.wta_mask),
            RefineInput::Sgm | RefineInput::SgmLr => (&self.sgm, &self.sgm_mask),
            RefineInput::Head | RefineInput::HeadLr => (&self.head, &self.head_mask),
            RefineInput::FusedLr | RefineInput::FusedCensusLr | RefineInput::FusedAllLr => {
                (&self.fused, &self.fused_mask)
            }
            // The encoder-free census run has its own test (census_stream.rs).
            RefineInput::Census | RefineInput::CensusLr => unreachable!("not refined here"),
        };
        let mut grid = map.clone();
        if self.mask(input).is_some() {
            for (row, m) in grid.chunks_exact_mut(self.cols).zip(mask.chunks_exact(self.cols)) {
                input.fill().apply(row, m).unwrap();
            }
        }
        grid
    }
}

impl Sink for Collect {
    fn stage(&mut self, stage: Stage) {
        self.stage = Some(stage);
    }
    fn matched(&mut self, row: &MatchedRow<'_>) {
        let c = self.cols;
        Self::put(&mut self.wta, c, row.row, row.wta_q8);
        Self::put(&mut self.wta_mask, c, row.row, row.wta_consistent);
        Self::put(&mut self.sgm, c, row.row, row.sgm_q8);
        Self::put(&mut self.sgm_mask, c, row.row, row.sgm_consistent);
    }
    fn head(&mut self, row: HeadRow<'_>) {
        let c = self.cols;
        Self::put(&mut self.head, c, row.row, row.disparity_q8);
        Self::put(&mut self.head_confidence, c, row.row, row.confidence_q8);
    }
    fn head_checked(&mut self, row: &HeadChecked<'_>) {
        let c = self.cols;
        Self::put(&mut self.head_mask, c, row.row, row.consistent);
    }
    fn fused(&mut self, row: &FusedRow<'_>) {
        let c = self.cols;
        Self::put(&mut self.fused, c, row.row, row.disparity_q8);
        Self::put(&mut self.fused_mask, c, row.row, row.consistent);
        self.fused_rows.push(row.row);
    }
    fn refined(&mut self, row: usize, disparity_q8: &[u16]) {
        assert_eq!(disparity_q8.len(), self.width);
        self.refine_stage_ok &= self.stage == Some(Stage::Refine);
        self.refined_rows.push(row);
        self.refined.extend_from_slice(disparity_q8);
    }
}

/// [`scene`] with the right view's lower half defocused (twice a 5-tap mean along the row), so
/// that the equalisation blurs some rows and not others.
fn half_defocused_scene(width: usize, height: usize) -> Scene {
    let mut s = scene(width, height);
    for row in s.right.chunks_exact_mut(width).skip(height / 2) {
        for _ in 0..2 {
            let copy = row.to_vec();
            for (x, v) in row.iter_mut().enumerate() {
                let sum: u32 = (x as isize - 2..=x as isize + 2)
                    .map(|u| copy[u.clamp(0, width as isize - 1) as usize] as u32)
                    .sum();
                *v = ((sum + 2) / 5) as u8;
            }
        }
    }
    let blurred = (0..height)
        .filter(|&y| decide_map_row(&s.left, &s.right, width, height, y).unwrap().radius > 0)
        .count();
    assert!(
        blurred > 0 && blurred < height,
        "{width}x{height}: {blurred} rows blurred"
    );
    s
}

/// The scene a refinement is tested on: half defocused when it equalises.
fn scene_for(width: usize, height: usize, equalise: bool) -> Scene {
    if equalise {
        half_defocused_scene(width, height)
    } else {
        scene(width, height)
    }
}

fn run(pipeline: &Pipeline<'_>, s: &Scene, opts: &Options, refine: Option<&Refine>) -> Result<Collect, Error> {
    let mut out = Collect::new(s.width, s.height);
    let mut source = SlicePair::new(&s.left, &s.right, s.width, s.height)?;
    let report = match refine {
        Some(r) => {
            let needed = arena_bytes_refined(s.height, s.width, opts, r);
            let mut arena = vec![0u8; needed];
            let report = pipeline.run_refined(&mut source, opts, r, &mut arena, &mut out)?;
            assert!(report.arena_used <= needed, "{report:?} needed {needed}");
            // The sizing counts alignment slack the carving may not need.
            let sized = refine_bytes(s.height, s.width, r);
            assert!(
                report.refine <= sized && report.refine + 8 > sized,
                "{report:?}: {sized}"
            );
            report
        }
        None => {
            let mut arena = vec![0u8; arena_bytes_for(s.height, s.width, opts)];
            pipeline.run(&mut source, opts, &mut arena, &mut out)?
        }
    };
    assert_eq!(report.refine == 0, refine.is_none());
    Ok(out)
}

/// The whole-map refinement of `refine.input`'s grid from the run's own token rows.
fn whole_map(s: &Scene, out: &Collect, refine: &Refine) -> Vec<u16> {
    refine_whole_map(s, &out.grid(refine.input), out.mask(refine.input), refine)
}

/// Runs `s` refining `refine` and checks that every pixel row came once, in order, in the
/// refine stage, and equals the whole-map refinement of the run's own grid; returns the run.
fn refined_as_the_whole_map(
    pipeline: &Pipeline<'_>,
    s: &Scene,
    opts: &Options,
    refine: &Refine,
    what: &str,
) -> Collect {
    let out = run(pipeline, s, opts, Some(refine)).unwrap_or_else(|e| panic!("{what}: {e:?}"));
    assert_eq!(out.refined_rows, (0..s.height).collect::<Vec<_>>(), "{what}");
    assert!(out.refine_stage_ok, "{what}");
    let want = whole_map(s, &out, refine);
    assert!(
        out.refined == want,
        "{what}: {}",
        first_difference(&out.refined, &want, s.width)
    );
    out
}

/// The fused rows came once each, in order, and are `fuse_row` of the run's own head and SGM
/// rows, their checks and the head's confidence, with the head's share of the view width: the
/// host's whole-grid fusion (`bino_host::readout::fuse_grid`, what `bino run` reads out).
fn assert_fused_is_the_checked_mean(out: &Collect, width: usize, height: usize) {
    assert_eq!(out.fused_rows, (0..height / 4).collect::<Vec<_>>(), "{width}x{height}");
    let cells = out.cols * (height / 4);
    let c = out.cols;
    let (fused, kept) = fuse_grid(
        (&out.head, &out.head_mask),
        &out.head_confidence,
        (&out.sgm, &out.sgm_mask),
        c,
        fuse_head_weight(width),
    )
    .unwrap();
    assert!(
        (&fused, &kept) == (&out.fused, &out.fused_mask),
        "{width}x{height}: {}",
        first_difference(&out.fused, &fused, c)
    );
    // The scenes exercise every case: both pass, one passes, neither.
    let both = (0..cells)
        .filter(|&i| out.head_mask[i] == 1 && out.sgm_mask[i] == 1)
        .count();
    assert!(both > 0 && kept.contains(&1), "{width}x{height}");
}

fn first_difference(got: &[u16], want: &[u16], width: usize) -> String {
    match got.iter().zip(want).position(|(a, b)| a != b) {
        Some(i) => format!(
            "first difference at row {} col {}: streamed {}, whole map {}",
            i / width,
            i % width,
            got[i],
            want[i]
        ),
        None => format!("lengths {} and {}", got.len(), want.len()),
    }
}

#[test]
fn every_readout_refines_as_the_whole_map_on_one_band_and_many() {
    let model = Int8Model::load(DEFAULT_BLOB.as_ref()).unwrap();
    let pipeline = Pipeline::new(model.blob().unwrap()).unwrap();
    let opts = options(true, true);
    for ((width, height), equalise) in SIZES.into_iter().flat_map(|size| [(size, false), (size, true)]) {
        let s = scene_for(width, height, equalise);
        let plain = run(&pipeline, &s, &opts, None).unwrap();
        assert_fused_is_the_checked_mean(&plain, width, height);
        for input in INPUTS {
            let refine = Refine {
                equalise,
                ..Refine::of(input)
            };
            let what = format!("{width}x{height} {} equalise {equalise}", input.name());
            let out = run(&pipeline, &s, &opts, Some(&refine)).unwrap_or_else(|e| panic!("{what}: {e:?}"));
            assert_eq!(
                out.refined_rows,
                (0..height).collect::<Vec<_>>(),
                "{what}: rows in order, once"
            );
            assert!(out.refine_stage_ok, "{what}: refined rows come in the refine stage");
            let want = whole_map(&s, &out, &refine);
            assert!(
                out.refined == want,
                "{what}: {}",
                first_difference(&out.refined, &want, width)
            );
            // The readouts themselves are untouched by the refinement.
            let Collect {
                wta,
                sgm,
                head,
                head_mask,
                fused,
                ..
            } = &out;
            assert!(
                (wta, sgm, head, head_mask, fused)
                    == (&plain.wta, &plain.sgm, &plain.head, &plain.head_mask, &plain.fused),
                "{what}"
            );
        }
    }
}

#[test]
fn without_the_head_the_rule_refines_sgm_lr_and_head_inputs_are_refused() {
    let model = Int8Model::load(DEFAULT_BLOB.as_ref()).unwrap();
    let pipeline = Pipeline::new(model.blob().unwrap()).unwrap();
    let s = scene(32, 80);
    let opts = options(false, false);
    let refine = Refine::for_options(&opts);
    assert_eq!(refine.input, RefineInput::SgmLr);
    assert_eq!(Refine::for_options(&options(true, true)).input, RefineInput::FusedAllLr);
    assert_eq!(Refine::for_options(&options(true, false)).input, RefineInput::SgmLr);
    let out = run(&pipeline, &s, &opts, Some(&refine)).unwrap();
    assert_eq!(out.refined, whole_map(&s, &out, &refine));
    // The head alone (no check): head is refinable, head+lr is not.
    let head_only = options(true, false);
    let head = Refine::of(RefineInput::Head);
    let out = run(&pipeline, &s, &head_only, Some(&head)).unwrap();
    assert_eq!(out.refined, whole_map(&s, &out, &head));
    for (opts, input) in [
        (opts, RefineInput::Head),
        (opts, RefineInput::HeadLr),
        (head_only, RefineInput::HeadLr),
        (opts, RefineInput::FusedLr),
        (head_only, RefineInput::FusedLr),
        (opts, RefineInput::FusedAllLr),
        (head_only, RefineInput::FusedAllLr),
    ] {
        let refine = Refine::of(input);
        let err = run(&pipeline, &s, &opts, Some(&refine)).err();
        assert_eq!(err, Some(Error::MissingReadout { readout: input.name() }));
    }
    let bad = Refine {
        input: RefineInput::Sgm,
        params: RefineParams {
            search: 99,
            ..RefineParams::DEFAULT
        },
        ..Refine::of(RefineInput::Sgm)
    };
    assert!(matches!(
        run(&pipeline, &s, &opts, Some(&bad)),
        Err(Error::OutOfRange { what: "search", .. })
    ));
}

#[test]
fn the_arena_grows_by_the_refinements_buffers_and_not_at_all_for_one_48x160_band() {
    let model = Int8Model::load(DEFAULT_BLOB.as_ref()).unwrap();
    let pipeline = Pipeline::new(model.blob().unwrap()).unwrap();
    let head_lr = options(true, true);
    let refine = Refine::of(RefineInput::FusedLr);
    // One band: the refinement (and for fuse-all the census SGM) fits beside the streams in the
    // encoder's scratch.
    assert_eq!(arena_bytes_head_lr(48, 160, MAX_COLS), 486_918);
    assert_eq!(arena_bytes_refined(48, 160, &head_lr, &refine), 486_918);
    let fuse_all = Refine::for_options(&head_lr);
    assert_eq!(arena_bytes_refined(48, 160, &head_lr, &fuse_all), 486_918);
    // Several bands: the census SGM's state and its rows kept for the head's check add to it.
    assert!(arena_bytes_refined(96, 160, &head_lr, &fuse_all) > arena_bytes_refined(96, 160, &head_lr, &refine));
    let sgm = options(false, false);
    assert_eq!(
        arena_bytes_refined(48, 160, &sgm, &Refine::for_options(&sgm)),
        arena_bytes_for(48, 160, &sgm)
    );
    // The equalisation's smoothed rows: one window, 13 rows of 160 px (the 9x9 box), beyond the
    // plain 12,085 (6,965 with the 5x5 box: the census scratch holds 2 x 9 rows of 160 codes;
    // 80 B of it the two token rows' left-right masks).
    assert_eq!(refine_bytes(48, 160, &refine), 12_085 + 13 * 160);
    let plain = Refine {
        equalise: false,
        ..refine
    };
    assert_eq!(refine_bytes(48, 160, &plain), 12_085);
    // Several bands: the state (with the equalised reach the view ring) adds to the streams'
    // region, rounded up to its alignment; the row scratch lives in the encoder's.
    for (height, opts, r) in [
        (96, head_lr, refine),
        (96, sgm, Refine::for_options(&sgm)),
        (480, head_lr, refine),
    ] {
        let growth = arena_bytes_refined(height, 160, &opts, &r) - arena_bytes_for(height, 160, &opts);
        let state = refine_bytes(height, 160, &r) - refine_bytes(48, 160, &r) + 241; // token rows 161 B, masks 80 B
        assert!(growth.abs_diff(state) < 16, "{height} {}: {growth}", r.input.name());
    }
    // Every readout's rows leave with the band that made them (each band's head ends with it),
    // so the ring holds only what the equalised reach of 8 reads beyond the band plan's
    // margin: 2 + reach - 4 CUT_MARGIN rows of both views (none at the plain reach of 6).
    assert_eq!(refine_bytes(96, 160, &refine), 12_085 + 13 * 160 + 2 * 160 * 2);
    assert_eq!(refine_bytes(96, 160, &plain), 12_085);
    // Too small by a byte is an error, not a wrong row.
    let s = scene(32, 80);
    let needed = pipeline.arena_bytes(80, 32, &head_lr, Some(&refine));
    let mut arena = vec![0u8; needed - 1];
    let mut source = SlicePair::new(&s.left, &s.right, 32, 80).unwrap();
    let err = pipeline.run_refined(&mut source, &head_lr, &refine, &mut arena, &mut Collect::new(32, 80));
    assert!(matches!(err, Err(Error::ArenaTooSmall { .. })), "{err:?}");
}

/// The native pathway: its head and head+lr grids refine as the whole map, on one band and
/// many (with the check on, a head refinement still gets every row); the matching readouts it
/// does not have are refused.
#[test]
fn the_native_pathway_refines_its_head_as_the_whole_map() {
    let model = Int8Model::load(DEFAULT_BLOB.as_ref()).unwrap();
    let pipeline = Pipeline::new(model.blob().unwrap()).unwrap();
    let opts = Options {
        pathway: bino_core::pipeline::Pathway::Native,
        ..options(false, true)
    };
    let unchecked = Options { head_lr: false, ..opts };
    assert_eq!(Refine::for_options(&opts).input, RefineInput::FusedCensusLr);
    assert_eq!(Refine::for_options(&unchecked).input, RefineInput::Head);
    for ((width, height), equalise) in SIZES.into_iter().flat_map(|size| [(size, false), (size, true)]) {
        let s = scene_for(width, height, equalise);
        let plain = run(&pipeline, &s, &opts, None).unwrap();
        for input in INPUTS {
            let refine = Refine {
                equalise,
                ..Refine::of(input)
            };
            let what = format!("native {width}x{height} {} equalise {equalise}", input.name());
            // The native pathway has its head only: no SGM to fuse with.
            if !matches!(input, RefineInput::Head | RefineInput::HeadLr) {
                let err = run(&pipeline, &s, &opts, Some(&refine)).unwrap_err();
                assert_eq!(err, Error::MissingReadout { readout: input.name() }, "{what}");
                continue;
            }
            let out = run(&pipeline, &s, &opts, Some(&refine)).unwrap_or_else(|e| panic!("{what}: {e:?}"));
            assert_eq!(out.refined_rows, (0..height).collect::<Vec<_>>(), "{what}");
            assert!(out.refine_stage_ok, "{what}");
            let want = whole_map(&s, &out, &refine);
            assert!(
                out.refined == want,
                "{what}: {}",
                first_difference(&out.refined, &want, width)
            );
            assert!((&out.head, &out.head_mask) == (&plain.head, &plain.head_mask), "{what}");
        }
        let head_lr = Refine::of(RefineInput::HeadLr);
        let err = run(&pipeline, &s, &unchecked, Some(&head_lr)).unwrap_err();
        assert_eq!(err, Error::MissingReadout { readout: "head+lr" });
    }
}

/// The native pathway's fusion with the census SGM (`fuse-census+lr`): streamed beside the
/// head over one band and many, every pixel row refined as the whole map of its fused grid,
/// the head's rows unchanged by it; the export pathway, and the native one without the head's
/// check, refuse it.
#[test]
fn the_native_pathway_refines_its_fusion_with_the_census_as_the_whole_map() {
    let model = Int8Model::load(DEFAULT_BLOB.as_ref()).unwrap();
    let pipeline = Pipeline::new(model.blob().unwrap()).unwrap();
    let opts = Options {
        pathway: bino_core::pipeline::Pathway::Native,
        ..options(false, true)
    };
    for ((width, height), equalise) in SIZES.into_iter().flat_map(|size| [(size, false), (size, true)]) {
        let s = scene_for(width, height, equalise);
        let plain = run(&pipeline, &s, &opts, None).unwrap();
        let refine = Refine {
            equalise,
            ..Refine::of(RefineInput::FusedCensusLr)
        };
        let what = format!("native {width}x{height} fuse-census+lr equalise {equalise}");
        let out = refined_as_the_whole_map(&pipeline, &s, &opts, &refine, &what);
        assert_eq!(out.fused.len(), out.head.len(), "{what}: a fused row per head row");
        assert!((&out.head, &out.head_mask) == (&plain.head, &plain.head_mask), "{what}");
        let unchecked = Options { head_lr: false, ..opts };
        let missing = Error::MissingReadout {
            readout: "fuse-census+lr",
        };
        assert_eq!(run(&pipeline, &s, &unchecked, Some(&refine)).unwrap_err(), missing);
        assert_eq!(
            run(&pipeline, &s, &options(true, true), Some(&refine)).unwrap_err(),
            missing
        );
    }
}

/// The export pathway's three-way fusion (`fuse-all+lr`, the rule's and `bino run`'s default):
/// the census SGM streamed beside the matching over one band and many, its fused rows `fuse_row`
/// of the run's own head with a census SGM computed independently over the whole map, then of
/// that with the run's SGM; every pixel row refined as the whole map of that grid; the other
/// readouts unchanged by it. The native pathway refuses it.
#[test]
fn the_export_pathway_refines_the_head_fused_with_the_census_and_the_sgm_as_the_whole_map() {
    let model = Int8Model::load(DEFAULT_BLOB.as_ref()).unwrap();
    let pipeline = Pipeline::new(model.blob().unwrap()).unwrap();
    let opts = options(true, true);
    for ((width, height), equalise) in SIZES.into_iter().flat_map(|size| [(size, false), (size, true)]) {
        let s = scene_for(width, height, equalise);
        let plain = run(&pipeline, &s, &opts, None).unwrap();
        let refine = Refine {
            equalise,
            ..Refine::of(RefineInput::FusedAllLr)
        };
        let what = format!("{width}x{height} fuse-all+lr equalise {equalise}");
        let out = refined_as_the_whole_map(&pipeline, &s, &opts, &refine, &what);
        assert_eq!(out.fused_rows, (0..height / 4).collect::<Vec<_>>(), "{what}");
        let c = out.cols;
        let (census, census_mask) = census_whole_map(&s.left, &s.right, width, height, opts.head_candidates);
        let head = (&out.head[..], &out.head_mask[..]);
        let (first, first_mask) = fuse_grid(
            head,
            &out.head_confidence,
            (&census, &census_mask),
            c,
            census::FUSE_HEAD_WEIGHT,
        )
        .unwrap();
        let (fused, kept) = fuse_grid(
            (&first, &first_mask),
            &out.head_confidence,
            (&out.sgm, &out.sgm_mask),
            c,
            census::FUSE_ALL_FIRST_WEIGHT,
        )
        .unwrap();
        assert!(
            (&fused, &kept) == (&out.fused, &out.fused_mask),
            "{what}: {}",
            first_difference(&out.fused, &fused, c)
        );
        assert_ne!(out.fused, plain.fused, "{what}: the census moved some cells");
        assert!(
            (&out.wta, &out.sgm, &out.head, &out.head_mask) == (&plain.wta, &plain.sgm, &plain.head, &plain.head_mask),
            "{what}"
        );
        let native = Options {
            pathway: bino_core::pipeline::Pathway::Native,
            ..opts
        };
        let missing = Error::MissingReadout { readout: "fuse-all+lr" };
        assert_eq!(run(&pipeline, &s, &native, Some(&refine)).unwrap_err(), missing);
    }
}

/// Beyond 200 px the host's commands search wider (`Refine::for_width`): the streamed stage with
/// that radius equals the whole map, as `bino sim` (streamed) and `bino run` (whole map) need.
#[test]
fn a_width_dependent_search_streams_as_the_whole_map() {
    let model = Int8Model::load(DEFAULT_BLOB.as_ref()).unwrap();
    let pipeline = Pipeline::new(model.blob().unwrap()).unwrap();
    let opts = options(true, true);
    let (width, height) = (320, 56);
    let refine = Refine::for_width(RefineInput::HeadLr, width);
    assert_eq!(refine.params.search, 4);
    assert_eq!(
        Refine::for_width(RefineInput::HeadLr, 160),
        Refine::of(RefineInput::HeadLr)
    );
    let s = scene_for(width, height, true);
    let out = run(&pipeline, &s, &opts, Some(&refine)).unwrap();
    let want = whole_map(&s, &out, &refine);
    assert!(out.refined == want, "{}", first_difference(&out.refined, &want, width));
    let narrow = whole_map(&s, &out, &Refine::of(RefineInput::HeadLr));
    assert_ne!(want, narrow, "the wider search changes some pixels");
}
