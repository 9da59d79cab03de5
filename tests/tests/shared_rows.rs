//! Shared token rows. With the shipped blob (attention within each token row, one row
//! embedding for every token row) a token row's codes do not depend on where its band starts,
//! so a frame's overlapping bands encode each token row once, a few token rows a pass in an
//! arena that holds one pass's work, and every band the pipeline hands on is exactly the encoder's pass
//! over that whole band.

use bino_core::band::{Band, BandPlan};
use bino_core::blob::Blob;
use bino_core::model::encoder::{arena_bytes, Encoder, GrayBand};
use bino_core::model::ids::{self, kind, Linear};
use bino_core::model::probe::NoProbe;
use bino_core::pipeline::{
    arena_bytes_for, BandEncoder, Options, Passes, Pathway, Pipeline, Sink, SlicePair, TOKEN_ROWS_PER_PASS,
};
use bino_core::testutil::Rng;
use bino_core::Error;
use bino_host::int8::blob_writer::BlobWriter;
use bino_tests::repo;

const WIDTH: usize = 160;
const DIM: usize = bino_core::config::DIM;

fn shipped() -> Vec<u8> {
    let path = repo().join("weights/bino_int8.bin");
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// `blob` with tensor `id` dropped, or with its byte `at` changed.
fn edited(blob: &Blob<'_>, id: bino_core::blob::TensorId, at: Option<usize>) -> Vec<u8> {
    let mut out = BlobWriter::new();
    for info in blob.tensors() {
        let (dtype, bytes) = blob.raw(info.id).unwrap();
        let mut bytes = bytes.to_vec();
        if info.id == id {
            let Some(at) = at else { continue };
            bytes[at] = bytes[at].wrapping_add(1);
        }
        out.add_raw(info.id, dtype, info.elements, bytes).unwrap();
    }
    out.finish()
}

fn independent(bytes: &[u8]) -> bool {
    Encoder::new(Blob::parse(bytes).unwrap()).unwrap().rows_independent()
}

fn pixels(seed: u64, len: usize) -> Vec<u8> {
    let mut rng = Rng::new(seed);
    (0..len).map(|_| rng.next_u64() as u8).collect()
}

#[test]
fn the_shipped_encoder_shares_rows_and_an_edited_one_does_not() {
    let bytes = shipped();
    assert!(independent(&bytes));
    let blob = Blob::parse(&bytes).unwrap();
    // Band attention mixes the rows; a row embedding that differs in one row (the embedding's
    // folded bias, or the descriptors' row offsets, token row 7) ties a row to its place.
    let row7 = 4 * (7 * DIM + 3);
    for (id, at) in [
        (ids::id(kind::ATTENTION_ROWS, 0), None),
        (Linear::Embed.id(kind::LINEAR_BIAS), Some(row7)),
        (ids::id(kind::DESC_ROW_OFFSET, 0), Some(row7)),
    ] {
        assert!(!independent(&edited(&blob, id, at)), "{id:?}");
    }
}

#[test]
fn a_token_row_is_the_same_wherever_its_band_starts() {
    let bytes = shipped();
    let encoder = Encoder::new(Blob::parse(&bytes).unwrap()).unwrap();
    let (left, right) = (pixels(1, WIDTH * 48), pixels(2, WIDTH * 48));
    let pair = |from: usize| {
        let rows = 48 - from;
        let (l, r) = (
            GrayBand::new(&left[from * WIDTH..], WIDTH, rows).unwrap(),
            GrayBand::new(&right[from * WIDTH..], WIDTH, rows).unwrap(),
        );
        let mut arena = vec![0u8; arena_bytes(rows, WIDTH)];
        let mut out = vec![0i8; rows / 4 * 2 * (WIDTH / 4) * DIM];
        encoder.pair_tokens(l, r, &mut arena, &mut out, &mut NoProbe).unwrap();
        out
    };
    let describe = |from: usize| {
        let rows = 48 - from;
        let view = GrayBand::new(&left[from * WIDTH..], WIDTH, rows).unwrap();
        let mut arena = vec![0u8; arena_bytes(rows, WIDTH)];
        let mut out = vec![0i8; rows / 4 * (WIDTH / 4) * DIM];
        encoder.describe(view, &mut arena, &mut out, &mut NoProbe).unwrap();
        out
    };
    let (whole, whole_desc) = (pair(0), describe(0));
    for from in [4, 16, 44] {
        let tail = pair(from);
        assert!(
            whole[whole.len() - tail.len()..] == tail[..],
            "pair pass from pixel row {from}"
        );
        let tail = describe(from);
        assert!(
            whole_desc[whole_desc.len() - tail.len()..] == tail[..],
            "descriptors from row {from}"
        );
    }
}

/// The blob's encoder, counting the token rows its passes encode and the tallest pass.
struct Counting<'w> {
    encoder: Encoder<'w>,
    token_rows: usize,
    tallest: usize,
}

impl<'w> Counting<'w> {
    fn new(encoder: Encoder<'w>) -> Self {
        Self {
            encoder,
            token_rows: 0,
            tallest: 0,
        }
    }

    fn count(&mut self, pixel_rows: usize) {
        self.token_rows += pixel_rows / 4;
        self.tallest = self.tallest.max(pixel_rows);
    }
}

impl BandEncoder for Counting<'_> {
    fn view_pass(&mut self, view: GrayBand<'_>, arena: &mut [u8]) -> Result<(usize, usize), Error> {
        self.count(view.height());
        self.encoder.view_pass(view, arena)
    }

    fn pair_pass(&mut self, l: GrayBand<'_>, r: GrayBand<'_>, arena: &mut [u8]) -> Result<(usize, usize), Error> {
        self.count(l.height());
        self.encoder.pair_pass(l, r, arena)
    }
}

/// Each band's maps as the pipeline hands them on.
#[derive(Default)]
struct Bands(Vec<(Band, Vec<i8>, Vec<i8>)>);

impl Sink for Bands {
    fn band(&mut self, band: Band, left: &[i8], right: &[i8]) {
        self.0.push((band, left.to_vec(), right.to_vec()));
    }

    fn pair_band(&mut self, band: Band, tokens: &[i8]) {
        self.0.push((band, tokens.to_vec(), Vec::new()));
    }
}

#[test]
fn a_frame_encodes_each_token_row_once_and_hands_on_whole_band_passes() {
    let bytes = shipped();
    let blob = Blob::parse(&bytes).unwrap();
    let pipeline = Pipeline::new(blob).unwrap();
    let encoder = Encoder::new(blob).unwrap();
    let height = 120;
    let (left, right): (&'static [u8], &'static [u8]) =
        (pixels(3, WIDTH * height).leak(), pixels(4, WIDTH * height).leak());
    let plan = BandPlan::new(height / 4).unwrap();
    assert_eq!(plan.len(), 4);
    for (pathway, views) in [(Pathway::Native, 1), (Pathway::Export, 2)] {
        let opts = Options {
            pathway,
            head: true,
            head_lr: true,
            ..bino_core::preset::OPTIONS
        };
        // A few token rows a pass: the arena holds one pass's encoder work beside the band's
        // outputs, less than the whole-band passes any weights fit in; a byte less is an error.
        assert_eq!(pipeline.passes(), Passes::TokenRows);
        let needed = pipeline.arena_bytes(height, WIDTH, &opts, None);
        assert!(needed < arena_bytes_for(height, WIDTH, &opts), "{pathway:?}");
        let mut arena = vec![0u8; needed];
        let mut source = SlicePair::new(left, right, WIDTH, height).unwrap();
        let err = pipeline.run(&mut source, &opts, &mut arena[..needed - 1], &mut Bands::default());
        assert!(matches!(err, Err(Error::ArenaTooSmall { .. })), "{err:?}");
        let mut counting = Counting::new(encoder);
        let mut bands = Bands::default();
        let mut source = SlicePair::new(left, right, WIDTH, height).unwrap();
        let report = pipeline
            .run_encoded(&mut source, &opts, None, &mut counting, &mut arena, &mut bands)
            .unwrap();
        assert!(report.arena_used <= needed);
        // 30 token rows, each once (four whole bands would be 48), a few a pass.
        assert_eq!(counting.token_rows, views * 30, "{pathway:?}");
        assert_eq!(counting.tallest, 4 * TOKEN_ROWS_PER_PASS, "{pathway:?}");
        assert_eq!(bands.0.len(), plan.len());
        for ((band, first, second), expected) in bands.0.iter().zip(plan.iter()) {
            assert_eq!(*band, expected);
            let rows = band.start * 4 * WIDTH..(band.start + band.rows) * 4 * WIDTH;
            let view = |px: &'static [u8]| GrayBand::new(&px[rows.clone()], WIDTH, band.rows * 4).unwrap();
            let mut scratch = vec![0u8; arena_bytes(band.rows * 4, WIDTH)];
            let mut whole = vec![0i8; band.rows * (WIDTH / 4) * DIM * (3 - views)];
            match pathway {
                Pathway::Native => {
                    encoder
                        .pair_tokens(view(left), view(right), &mut scratch, &mut whole, &mut NoProbe)
                        .unwrap();
                    assert!(*first == whole, "band {band:?}: pair tokens");
                }
                Pathway::Export => {
                    for (px, got) in [(left, first), (right, second)] {
                        encoder
                            .describe(view(px), &mut scratch, &mut whole, &mut NoProbe)
                            .unwrap();
                        assert!(*got == whole, "band {band:?}: descriptors");
                    }
                }
            }
        }
    }
}

/// Weights whose rows depend on their band are encoded a whole band a pass, in the size any
/// weights fit in.
#[test]
fn weights_that_do_not_share_rows_take_whole_band_passes() {
    let bytes = shipped();
    let band_attention = edited(&Blob::parse(&bytes).unwrap(), ids::id(kind::ATTENTION_ROWS, 0), None);
    let blob = Blob::parse(&band_attention).unwrap();
    let pipeline = Pipeline::new(blob).unwrap();
    assert_eq!(pipeline.passes(), Passes::Band);
    let height = 56;
    let (left, right) = (pixels(5, WIDTH * height), pixels(6, WIDTH * height));
    let opts = Options {
        pathway: Pathway::Native,
        ..bino_core::preset::OPTIONS
    };
    let needed = pipeline.arena_bytes(height, WIDTH, &opts, None);
    assert_eq!(needed, arena_bytes_for(height, WIDTH, &opts));
    let mut arena = vec![0u8; needed];
    let mut counting = Counting::new(Encoder::new(blob).unwrap());
    let mut source = SlicePair::new(&left, &right, WIDTH, height).unwrap();
    pipeline
        .run_encoded(
            &mut source,
            &opts,
            None,
            &mut counting,
            &mut arena,
            &mut Bands::default(),
        )
        .unwrap();
    // Two whole bands of 12 token rows.
    assert_eq!((counting.token_rows, counting.tallest), (24, 48));
}
