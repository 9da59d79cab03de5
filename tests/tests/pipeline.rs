//! `bino_core::pipeline` (one arena, rows streamed in, every readout row by row) against the
//! host's whole-map steps over the same shipped blob: the streaming pipeline must give the
//! same descriptors, WTA, SGM and head outputs, for one band and for images taller than one.

use bino_core::band::Band;
use bino_core::blob::{Blob, BlobError};
use bino_core::lr::consistent_row;
use bino_core::model::encoder::GrayBand;
use bino_core::model::head::HeadRow;
use bino_core::model::ids;
use bino_core::pipeline::{
    arena_bytes, arena_bytes_for, arena_bytes_head_lr, BandEncoder, HeadChecked, MatchedRow, Options, Pathway,
    Pipeline, RowSource, Sink, SlicePair, Stage,
};
use bino_core::sgm::Penalties;
use bino_core::Error;
use bino_host::band_maps::BandedRows;
use bino_host::data::profile::View;
use bino_host::data::synthetic;
use bino_host::demo::{DEFAULT_BLOB, DEFAULT_PENALTIES};
use bino_host::int8::blob_writer::BlobWriter;
use bino_host::int8::{guide_map, match_rows, sgm_rows, Int8Model};

const MAX_COLS: usize = 16;

fn options() -> Options {
    Options {
        pathway: bino_core::pipeline::Pathway::Export,
        max_cols: MAX_COLS,
        penalties: DEFAULT_PENALTIES,
        lr_max_diff_q8: 256,
        head: true,
        head_lr: false,
        head_candidates: bino_core::config::HEAD_MAX_DISP,
    }
}

/// Everything the pipeline emits, gathered into whole maps.
#[derive(Default)]
struct Collect {
    stages: Vec<Stage>,
    bands: Vec<Band>,
    desc_left: Vec<(usize, Vec<i8>)>,
    desc_right: Vec<(usize, Vec<i8>)>,
    rows: Vec<usize>,
    wta: Vec<u16>,
    sgm: Vec<u16>,
    wta_mask: Vec<u8>,
    head_rows: Vec<usize>,
    head: Vec<u16>,
    checked_rows: Vec<usize>,
    head_right: Vec<u16>,
    head_mask: Vec<u8>,
    cols: usize,
}

impl Sink for Collect {
    fn stage(&mut self, stage: Stage) {
        self.stages.push(stage);
    }
    fn band(&mut self, band: Band, left: &[i8], right: &[i8]) {
        // Keep only the rows the band provides, as the host's banded encoder does.
        let row_len = left.len() / band.rows;
        for row in band.keep_from..band.keep_to {
            let at = (row - band.start) * row_len;
            self.desc_left.push((row, left[at..at + row_len].to_vec()));
            self.desc_right.push((row, right[at..at + row_len].to_vec()));
        }
        self.bands.push(band);
    }
    fn matched(&mut self, row: &MatchedRow<'_>) {
        self.rows.push(row.row);
        self.cols = row.wta_q8.len();
        self.wta.extend_from_slice(row.wta_q8);
        self.sgm.extend_from_slice(row.sgm_q8);
        self.wta_mask.extend_from_slice(row.wta_consistent);
    }
    fn head(&mut self, row: HeadRow<'_>) {
        self.head_rows.push(row.row);
        self.head.extend_from_slice(row.disparity_q8);
    }
    fn head_checked(&mut self, row: &HeadChecked<'_>) {
        assert!(self.head_rows.contains(&row.row), "a check comes after its head row");
        self.checked_rows.push(row.row);
        self.head_right.extend_from_slice(row.right_q8);
        self.head_mask.extend_from_slice(row.consistent);
    }
}

fn q8(values: &[u16]) -> Vec<f32> {
    values.iter().map(|&d| d as f32 / 256.0).collect()
}

fn view(pixels: &[u8], width: usize, height: usize) -> View {
    View {
        width,
        height,
        pixels: pixels.iter().map(|&p| p as f32 / 255.0).collect(),
    }
}

/// Runs the pipeline on the synthetic scene of the given size and checks every readout
/// against the host's whole-map computation.
fn pipeline_equals_whole_map_steps(width: usize, height: usize) -> Collect {
    pipeline_equals_whole_map_steps_with(width, height, options())
}

fn pipeline_equals_whole_map_steps_with(width: usize, height: usize, opts: Options) -> Collect {
    let model = Int8Model::load(DEFAULT_BLOB.as_ref()).unwrap();
    let pipeline = Pipeline::new(model.blob().unwrap()).unwrap();
    let scene = synthetic::default_scene(width, height);
    let (l, r) = (&scene.left.pixels, &scene.right.pixels);
    let mut arena = vec![0u8; arena_bytes_for(height, width, &opts)];
    let mut out = Collect::default();
    let report = pipeline
        .run(
            &mut SlicePair::new(l, r, width, height).unwrap(),
            &opts,
            &mut arena,
            &mut out,
        )
        .unwrap();
    assert!(report.arena_used <= arena.len(), "{report:?}");

    let (cols, left_bands) = model.descriptor_bands(&view(l, width, height)).unwrap();
    let (_, right_bands) = model.descriptor_bands(&view(r, width, height)).unwrap();
    let (rows, left, right) = (left_bands.rows, left_bands.assemble(), right_bands.assemble());
    assert_eq!((report.rows, report.cols), (rows, cols));
    let streamed_left: Vec<i8> = out.desc_left.iter().flat_map(|(_, d)| d.clone()).collect();
    let streamed_right: Vec<i8> = out.desc_right.iter().flat_map(|(_, d)| d.clone()).collect();
    assert!(streamed_left == left, "left descriptors differ");
    assert!(streamed_right == right, "right descriptors differ");
    assert_eq!(out.rows, (0..rows).collect::<Vec<_>>(), "rows out of order");
    assert_eq!(out.head_rows, (0..rows).collect::<Vec<_>>(), "head rows out of order");

    let wta = match_rows(&left, &right, rows, cols, MAX_COLS).unwrap();
    assert_eq!(q8(&out.wta), wta.values, "WTA");
    let guide = opts
        .penalties
        .guided()
        .then(|| guide_map(&view(l, width, height)).unwrap());
    let sgm = sgm_rows(&left, &right, rows, cols, MAX_COLS, opts.penalties, guide.as_deref()).unwrap();
    assert_eq!(q8(&out.sgm), sgm.values, "SGM");
    // Each band's head on its own rows around those it keeps.
    let head = model
        .head_banded(&left_bands, &right_bands, cols, opts.head_candidates)
        .unwrap();
    assert_eq!(q8(&out.head), head.disparity, "head");
    if report.bands > 1 {
        // Not the head over the stitched maps: the bands' own rows differ in the overlaps.
        let stitched = model
            .head_with_candidates(&left, &right, (rows, cols), opts.head_candidates)
            .unwrap();
        assert_ne!(stitched.disparity, head.disparity);
    }
    assert_eq!(report.wta_kept, out.wta_mask.iter().map(|&m| m as usize).sum::<usize>());
    out
}

#[test]
fn one_band_streams_to_the_same_outputs_as_whole_maps() {
    let out = pipeline_equals_whole_map_steps(160, 48);
    assert_eq!(out.bands.len(), 1);
    // The encoder passes come first, then per-row readouts.
    assert_eq!(&out.stages[..3], [Stage::Rows, Stage::EncodeLeft, Stage::EncodeRight]);
    assert!(out.stages.contains(&Stage::Head));
}

#[test]
fn taller_images_go_band_by_band_to_the_same_outputs() {
    let out = pipeline_equals_whole_map_steps(96, 112);
    assert_eq!(out.bands.len(), 3);
}

/// The guided SGM (`Penalties::edge`): the pipeline's guide rows, taken from each band's pixel
/// buffer, give the whole-map SGM on the views' cell means, across band seams; the guides
/// cost two bytes per cell column beside the encoder's scratch (the previous rows' guides, in
/// a region rounded up to 16 bytes; the row's own live in the band's scratch) and change the
/// map.
#[test]
fn the_guided_sgm_streams_to_the_whole_map_across_bands() {
    let guided = Options {
        penalties: Penalties {
            edge: 8,
            ..DEFAULT_PENALTIES
        },
        ..options()
    };
    let out = pipeline_equals_whole_map_steps_with(96, 112, guided);
    assert_eq!(out.bands.len(), 3);
    let growth = arena_bytes_for(112, 96, &guided) - arena_bytes_for(112, 96, &options());
    assert!((2 * 96 / 4..2 * 96 / 4 + 16).contains(&growth), "{growth}");
    let plain = pipeline_equals_whole_map_steps(96, 112);
    assert_ne!(out.sgm, plain.sgm);
}

/// A wide view's head searches further (w320: 16 candidates) and streams exactly as the
/// host's banded head; the extra candidates cost head stream, which each band starts afresh in
/// the encoder's scratch (no arena while the scratch holds it), and an absurd count is refused
/// before any row.
#[test]
fn more_head_candidates_stream_like_the_whole_map() {
    let opts = Options {
        head_candidates: 16,
        ..options()
    };
    let out = pipeline_equals_whole_map_steps_with(96, 112, opts);
    let trained = pipeline_equals_whole_map_steps(96, 112);
    assert_ne!(out.head, trained.head, "the extra candidates change the head's output");
    use bino_core::model::{head, ids::HeadKind};
    assert!(head::arena_bytes_with(HeadKind::Export, 24, 16) > head::arena_bytes_with(HeadKind::Export, 24, 12));
    assert_eq!(arena_bytes_for(112, 96, &opts), arena_bytes_for(112, 96, &options()));
    let model = Int8Model::load(DEFAULT_BLOB.as_ref()).unwrap();
    let pipeline = Pipeline::new(model.blob().unwrap()).unwrap();
    let scene = synthetic::default_scene(32, 48);
    for bad in [0, bino_core::config::HEAD_CANDIDATES_LIMIT + 1] {
        let opts = Options {
            head_candidates: bad,
            ..options()
        };
        let mut arena = vec![0u8; arena_bytes_for(48, 32, &options())];
        let mut source = SlicePair::new(&scene.left.pixels, &scene.right.pixels, 32, 48).unwrap();
        let err = pipeline.run(&mut source, &opts, &mut arena, &mut Collect::default());
        assert!(
            matches!(err, Err(Error::Candidates { requested, .. }) if requested == bad),
            "{bad}"
        );
    }
}

#[test]
fn arena_depends_on_the_width_not_the_height() {
    assert_eq!(arena_bytes(112, 160, MAX_COLS), arena_bytes(4000, 160, MAX_COLS));
    assert!(arena_bytes(48, 160, MAX_COLS) < arena_bytes(112, 160, MAX_COLS));
    // The paper's band-pair fits the AN547's 512 KiB of data TCM.
    assert!(
        arena_bytes(48, 160, MAX_COLS) <= 512 * 1024,
        "{}",
        arena_bytes(48, 160, MAX_COLS)
    );
}

#[test]
fn left_right_check_keeps_mostly_correct_matches() {
    let (width, height) = (160, 48);
    let scene = synthetic::default_scene(width, height);
    let out = pipeline_equals_whole_map_steps(width, height);
    // True disparity per token (pixel disparity of the cell's top-left pixel / 4 pixels per column).
    let truth: Vec<f32> = (0..out.rows.len() * out.cols)
        .map(|i| scene.disparity[(i / out.cols) * 4 * width + (i % out.cols) * 4] / 4.0)
        .collect();
    let err = |keep: u8| {
        let picked: Vec<f32> = (0..truth.len())
            .filter(|&i| out.wta_mask[i] == keep)
            .map(|i| (out.wta[i] as f32 / 256.0 - truth[i]).abs())
            .collect();
        (picked.iter().sum::<f32>() / picked.len().max(1) as f32, picked.len())
    };
    let ((kept_err, kept), (dropped_err, dropped)) = (err(1), err(0));
    assert!(kept > dropped, "kept {kept}, dropped {dropped}");
    assert!(
        kept_err < dropped_err,
        "kept cells err {kept_err} vs dropped {dropped_err}"
    );
}

/// Counts the rows asked of it; fails at row `fail_at`.
struct CountingSource<'a> {
    inner: SlicePair<'a>,
    read: usize,
    fail_at: usize,
}

impl RowSource for CountingSource<'_> {
    fn width(&self) -> usize {
        self.inner.width()
    }
    fn height(&self) -> usize {
        self.inner.height()
    }
    fn next_row(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), Error> {
        if self.read == self.fail_at {
            return Err(Error::PairMismatch);
        }
        self.read += 1;
        self.inner.next_row(left, right)
    }
}

#[test]
fn rows_are_read_once_in_order_and_source_errors_stop_the_run() {
    let model = Int8Model::load(DEFAULT_BLOB.as_ref()).unwrap();
    let pipeline = Pipeline::new(model.blob().unwrap()).unwrap();
    let (width, height) = (32, 100);
    let scene = synthetic::default_scene(width, height);
    let (l, r) = (&scene.left.pixels, &scene.right.pixels);
    let mut arena = vec![0u8; arena_bytes(height, width, MAX_COLS)];
    let opts = Options {
        head: false,
        ..options()
    };
    let mut source = CountingSource {
        inner: SlicePair::new(l, r, width, height).unwrap(),
        read: 0,
        fail_at: usize::MAX,
    };
    pipeline
        .run(&mut source, &opts, &mut arena, &mut Collect::default())
        .unwrap();
    assert_eq!(source.read, height);
    let mut failing = CountingSource {
        inner: SlicePair::new(l, r, width, height).unwrap(),
        read: 0,
        fail_at: 60,
    };
    let err = pipeline.run(&mut failing, &opts, &mut arena, &mut Collect::default());
    assert_eq!(err.unwrap_err(), Error::PairMismatch);
}

#[test]
fn bad_inputs_are_errors() {
    let model = Int8Model::load(DEFAULT_BLOB.as_ref()).unwrap();
    let pipeline = Pipeline::new(model.blob().unwrap()).unwrap();
    let px = vec![0u8; 48 * 160];
    // The blob's own size: the shipped weights run a few token rows a pass, in less than the size
    // any weights fit in (`arena_bytes`).
    let exact = pipeline.arena_bytes(48, 160, &options(), None);
    assert!(exact < arena_bytes(48, 160, MAX_COLS));
    let mut arena = vec![0u8; exact];
    let mut sink = Collect::default();
    let mut run = |source: &mut SlicePair<'_>, opts: Options, arena: &mut [u8]| {
        pipeline.run(source, &opts, arena, &mut sink).unwrap_err()
    };
    let mut pair = SlicePair::new(&px, &px, 160, 48).unwrap();
    let short = arena.len() - 1;
    assert!(matches!(
        run(&mut pair, options(), &mut arena[..short]),
        Error::ArenaTooSmall { .. }
    ));
    let bad_cols = Options {
        max_cols: 0,
        ..options()
    };
    assert!(matches!(run(&mut pair, bad_cols, &mut arena), Error::Candidates { .. }));
    let mut odd = SlicePair::new(&px[..47 * 160], &px[..47 * 160], 160, 47).unwrap();
    assert!(matches!(
        run(&mut odd, options(), &mut arena),
        Error::NotMultiple { .. }
    ));
    let wide = vec![0u8; 4 * 4096];
    let mut too_wide = SlicePair::new(&wide, &wide, 4096, 4).unwrap();
    assert!(matches!(
        run(&mut too_wide, options(), &mut arena),
        Error::TooWide { .. }
    ));
    assert_eq!(
        SlicePair::new(&px, &px[..100], 160, 48).unwrap_err(),
        Error::PairMismatch
    );
    assert!(matches!(
        SlicePair::new(&px, &px, 160, 47),
        Err(Error::BufferSize { .. })
    ));
}

/// A stand-in encoder that answers every pass with `len` bytes of zeros.
struct WrongLength {
    len: usize,
}

impl BandEncoder for WrongLength {
    fn view_pass(&mut self, _view: GrayBand<'_>, arena: &mut [u8]) -> Result<(usize, usize), Error> {
        arena.iter_mut().take(self.len).for_each(|b| *b = 0);
        Ok((self.len.min(arena.len()), self.len))
    }

    fn pair_pass(
        &mut self,
        left: GrayBand<'_>,
        _right: GrayBand<'_>,
        arena: &mut [u8],
    ) -> Result<(usize, usize), Error> {
        self.view_pass(left, arena)
    }
}

/// [`Pipeline::run_encoded`] with the blob's encoder is [`Pipeline::run`]; a stand-in whose
/// passes have the wrong length (short, long, beyond the arena) is an error on either pathway,
/// never a panic or a row read from the wrong bytes.
#[test]
fn a_stand_in_encoder_must_answer_as_the_encoder() {
    let model = Int8Model::load(DEFAULT_BLOB.as_ref()).unwrap();
    let pipeline = Pipeline::new(model.blob().unwrap()).unwrap();
    let scene = synthetic::default_scene(160, 48);
    let (left, right) = (&scene.left.pixels, &scene.right.pixels);
    for pathway in [Pathway::Export, Pathway::Native] {
        let opts = Options {
            pathway,
            head_lr: true,
            ..options()
        };
        let mut arena = vec![0u8; arena_bytes_for(48, 160, &opts)];
        let mut plain = Collect::default();
        let report = pipeline
            .run(
                &mut SlicePair::new(left, right, 160, 48).unwrap(),
                &opts,
                &mut arena,
                &mut plain,
            )
            .unwrap();
        let mut encoder = model.encoder().unwrap();
        let mut stood_in = Collect::default();
        let mut source = SlicePair::new(left, right, 160, 48).unwrap();
        let again = pipeline
            .run_encoded(&mut source, &opts, None, &mut encoder, &mut arena, &mut stood_in)
            .unwrap();
        assert_eq!(
            (again, &stood_in.head, &stood_in.head_mask),
            (report, &plain.head, &plain.head_mask)
        );
        // One band's passes: 12 token rows of 40 cells, DIM codes each (twice that for a pair).
        let right_len = 12 * 40 * bino_core::config::DIM;
        for len in [
            right_len - 1,
            right_len + 1,
            2 * right_len - 1,
            2 * right_len + 1,
            arena.len() + 1,
        ] {
            let mut source = SlicePair::new(left, right, 160, 48).unwrap();
            let result = pipeline.run_encoded(
                &mut source,
                &opts,
                None,
                &mut WrongLength { len },
                &mut arena,
                &mut Collect::default(),
            );
            assert!(result.is_err(), "{pathway:?}: a pass of {len} bytes ran: {result:?}");
        }
    }
}

/// Each row's cells in reverse order, band by band: the descriptor map of the mirrored view.
fn mirror_rows(map: &BandedRows<i8>, cols: usize) -> BandedRows<i8> {
    let dim = bino_core::config::DIM;
    let bands = (map.bands.iter())
        .map(|(band, codes)| {
            let mirrored = (codes.chunks_exact(cols * dim))
                .flat_map(|row| row.chunks_exact(dim).rev().flatten().copied().collect::<Vec<_>>())
                .collect();
            (*band, mirrored)
        })
        .collect();
    BandedRows { bands, ..map.clone() }
}

/// `head_lr`: the head on the mirrored pair gives the right view (the left head's output is
/// untouched), and the check is `consistent_row` of the two, row by row, for one band and many.
#[test]
fn the_heads_left_right_check_is_the_head_on_the_mirrored_pair() {
    let model = Int8Model::load(DEFAULT_BLOB.as_ref()).unwrap();
    let pipeline = Pipeline::new(model.blob().unwrap()).unwrap();
    let opts = Options {
        head_lr: true,
        ..options()
    };
    for (width, height) in [(160, 48), (64, 112)] {
        let scene = synthetic::default_scene(width, height);
        let (l, r) = (&scene.left.pixels, &scene.right.pixels);
        let needed = arena_bytes_head_lr(height, width, MAX_COLS);
        // The mirrored head reruns each band on the left head's stream, inside the encoder's
        // scratch: one band's arena does not grow; several bands' by the check's rows only
        // (they sit beside the scratch with the other readouts' state).
        let growth = needed - arena_bytes(height, width, MAX_COLS);
        match height <= 48 {
            true => assert_eq!(growth, 0),
            false => assert!(growth > 0 && growth < 4 * 1024, "{growth}"),
        }
        // The shipped blob runs a few token rows a pass, in its own smaller size.
        let exact = pipeline.arena_bytes(height, width, &opts, None);
        assert!(exact < needed, "{exact} {needed}");
        let mut arena = vec![0u8; exact];
        let err = pipeline.run(
            &mut SlicePair::new(l, r, width, height).unwrap(),
            &opts,
            &mut arena[..exact - 1],
            &mut Collect::default(),
        );
        assert!(matches!(err, Err(Error::ArenaTooSmall { .. })), "{err:?}");
        let mut out = Collect::default();
        let report = pipeline
            .run(
                &mut SlicePair::new(l, r, width, height).unwrap(),
                &opts,
                &mut arena,
                &mut out,
            )
            .unwrap();
        assert!(report.arena_used <= exact);
        let (cols, left) = model.descriptor_bands(&view(l, width, height)).unwrap();
        let (_, right) = model.descriptor_bands(&view(r, width, height)).unwrap();
        let (rows, nd) = (left.rows, opts.head_candidates);
        assert_eq!(out.checked_rows, (0..rows).collect::<Vec<_>>(), "{width}x{height}");
        let head = model.head_banded(&left, &right, cols, nd).unwrap();
        assert_eq!(q8(&out.head), head.disparity, "the left head is unchanged");
        // Each band's head on the mirrored pair, each row's cells reversed.
        let mirrored = model
            .head_banded(&mirror_rows(&right, cols), &mirror_rows(&left, cols), cols, nd)
            .unwrap();
        let right_view: Vec<f32> = mirrored
            .disparity
            .chunks_exact(cols)
            .flat_map(|row| row.iter().rev().copied().collect::<Vec<_>>())
            .collect();
        assert_eq!(q8(&out.head_right), right_view, "{width}x{height}: right view");
        let mut expected = vec![0u8; rows * cols];
        let mut kept = 0;
        for ((left_row, right_row), mask) in out
            .head
            .chunks_exact(cols)
            .zip(out.head_right.chunks_exact(cols))
            .zip(expected.chunks_exact_mut(cols))
        {
            kept += consistent_row(left_row, right_row, opts.lr_max_diff_q8, mask).unwrap();
        }
        assert_eq!(out.head_mask, expected);
        // The whole-map helper the demo uses computes the same check.
        let whole = model.head_check(&left, &right, &head, nd, opts.lr_max_diff_q8).unwrap();
        assert_eq!(whole, out.head_mask.iter().map(|&m| m != 0).collect::<Vec<_>>());
        assert_eq!(report.head_kept, kept);
        assert!(
            kept > rows * cols / 2,
            "{width}x{height}: the head mostly agrees with itself ({kept})"
        );
    }
}

/// Pair tokens (native pathway) by band, kept rows only, in arrival order.
#[derive(Default)]
struct Native {
    collect: Collect,
    tokens: Vec<i8>,
}

impl Sink for Native {
    fn stage(&mut self, stage: Stage) {
        self.collect.stage(stage);
    }
    fn band(&mut self, _: Band, _: &[i8], _: &[i8]) {
        panic!("the native pathway makes no descriptor maps");
    }
    fn pair_band(&mut self, band: Band, tokens: &[i8]) {
        let row_len = tokens.len() / band.rows;
        for row in band.keep_from..band.keep_to {
            let at = (row - band.start) * row_len;
            self.tokens.extend_from_slice(&tokens[at..at + row_len]);
        }
        self.collect.bands.push(band);
    }
    fn matched(&mut self, _: &MatchedRow<'_>) {
        panic!("the native pathway has no matching readouts");
    }
    fn head(&mut self, row: HeadRow<'_>) {
        self.collect.head(row);
    }
    fn head_checked(&mut self, row: &HeadChecked<'_>) {
        self.collect.head_checked(row);
    }
}

/// The native pathway: one encoder pass per band on (L, R), the native head streamed over the
/// pair tokens and, with its check, the right view read from the head's own logits; every
/// output equals the host's whole-map steps (`pair_token_bands`, `native_head_banded` and its
/// logit diagonal), for one band and several, in an arena smaller than the export pathway's.
#[test]
fn the_native_pathway_streams_like_the_whole_map_steps() {
    let model = Int8Model::load(DEFAULT_BLOB.as_ref()).unwrap();
    let pipeline = Pipeline::new(model.blob().unwrap()).unwrap();
    assert!(
        pipeline.has_head_of(Pathway::Native),
        "the shipped blob carries the native head"
    );
    for head_lr in [false, true] {
        let opts = Options {
            pathway: Pathway::Native,
            head: false, // implied on the native pathway
            head_lr,
            ..options()
        };
        for (width, height) in [(160, 48), (64, 112)] {
            let what = format!("{width}x{height} head_lr {head_lr}");
            let scene = synthetic::default_scene(width, height);
            let (l, r) = (&scene.left.pixels, &scene.right.pixels);
            let needed = arena_bytes_for(height, width, &opts);
            let export = Options {
                pathway: Pathway::Export,
                head: true,
                ..opts
            };
            assert!(needed < arena_bytes_for(height, width, &export), "{what}");
            let needed = pipeline.arena_bytes(height, width, &opts, None);
            let mut arena = vec![0u8; needed];
            let err = pipeline.run(
                &mut SlicePair::new(l, r, width, height).unwrap(),
                &opts,
                &mut arena[..needed - 1],
                &mut Native::default(),
            );
            assert!(matches!(err, Err(Error::ArenaTooSmall { .. })), "{what}: {err:?}");
            let mut out = Native::default();
            let report = pipeline
                .run(
                    &mut SlicePair::new(l, r, width, height).unwrap(),
                    &opts,
                    &mut arena,
                    &mut out,
                )
                .unwrap();
            assert!(report.arena_used <= needed, "{what}: {report:?}");
            let (cols, bands) = model
                .pair_token_bands(&view(l, width, height), &view(r, width, height))
                .unwrap();
            let (rows, tokens) = (bands.rows, bands.assemble());
            assert!(out.tokens == tokens, "{what}: pair tokens differ");
            // One encoder pass per band, with or without the check.
            let passes = out.collect.stages.iter().filter(|&&s| s == Stage::EncodePair).count();
            assert_eq!(passes, report.bands, "{what}");
            assert!(out
                .collect
                .stages
                .iter()
                .all(|s| !matches!(s, Stage::EncodeLeft | Stage::EncodeRight | Stage::Match | Stage::Sgm)));
            assert_eq!(out.collect.head_rows, (0..rows).collect::<Vec<_>>(), "{what}");
            // Each band's head on its own rows around those it keeps.
            let head = model
                .native_head_banded(&bands, cols, bino_core::config::HEAD_MAX_DISP)
                .unwrap();
            assert_eq!(q8(&out.collect.head), head.disparity, "{what}: head");
            if report.bands > 1 {
                // Not the head over the stitched map: the bands' own rows differ in the overlaps.
                let stitched = model.native_head(&tokens, rows, cols).unwrap();
                assert_ne!(stitched.disparity, head.disparity, "{what}");
            }
            if !head_lr {
                assert!(out.collect.checked_rows.is_empty());
                continue;
            }
            // The right view from the same pass: the whole-map head's logit diagonal.
            assert_eq!(out.collect.checked_rows, (0..rows).collect::<Vec<_>>(), "{what}");
            assert_eq!(q8(&out.collect.head_right), head.right_view, "{what}: right view");
            let mut expected = vec![0u8; rows * cols];
            let mut kept = 0;
            for ((left_row, right_row), mask) in out
                .collect
                .head
                .chunks_exact(cols)
                .zip(out.collect.head_right.chunks_exact(cols))
                .zip(expected.chunks_exact_mut(cols))
            {
                kept += consistent_row(left_row, right_row, opts.lr_max_diff_q8, mask).unwrap();
            }
            assert_eq!(out.collect.head_mask, expected, "{what}");
            assert_eq!(report.head_kept, kept);
            assert!(
                kept > rows * cols / 2,
                "{what}: the head mostly agrees with itself ({kept})"
            );
        }
    }
}

#[test]
fn the_native_pathway_needs_the_native_head() {
    // A blob without it: the error names the head's first tensor, before any row is read.
    let model = Int8Model::load(DEFAULT_BLOB.as_ref()).unwrap();
    let shipped = model.blob().unwrap();
    let native_norm = ids::id(ids::kind::LAYERNORM, Pathway::Native.layernorm());
    let mut writer = BlobWriter::new();
    for t in shipped.tensors().filter(|t| t.id != native_norm) {
        let (dtype, bytes) = shipped.raw(t.id).unwrap();
        writer.add_raw(t.id, dtype, t.elements, bytes.to_vec()).unwrap();
    }
    let blob = writer.finish();
    let pipeline = Pipeline::new(Blob::parse(&blob).unwrap()).unwrap();
    assert!(!pipeline.has_head_of(Pathway::Native));
    let opts = Options {
        pathway: Pathway::Native,
        ..options()
    };
    let (l, r) = (vec![0u8; 32 * 48], vec![0u8; 32 * 48]);
    let mut arena = vec![0u8; arena_bytes_for(48, 32, &opts)];
    let err = pipeline
        .run(
            &mut SlicePair::new(&l, &r, 32, 48).unwrap(),
            &opts,
            &mut arena,
            &mut Native::default(),
        )
        .unwrap_err();
    assert_eq!(err, Error::Blob(BlobError::MissingTensor { id: native_norm }));
    assert!(pipeline.has_head_of(Pathway::Export), "the export pathway still runs");
}
