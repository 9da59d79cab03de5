//! Row attention (`AttentionSpan::Row`, the shipped encoder): each token row attends within
//! itself. A row's tokens depend on its own pixel rows and its place in the band only, and the
//! first row of a band is what band attention gives a band of that one row (the same blob
//! without its `ATTENTION_ROWS` entry).

use bino_core::blob::Blob;
use bino_core::model::encoder::{arena_bytes, Encoder, GrayBand};
use bino_core::model::ids::{self, kind};
use bino_core::model::probe::NoProbe;
use bino_core::model::weights::AttentionSpan;
use bino_core::testutil::Rng;
use bino_host::int8::blob_writer::BlobWriter;
use bino_tests::repo;

const WIDTH: usize = 160;
const HEIGHT: usize = 48;
const ROW_BYTES: usize = 2 * (WIDTH / 4) * 128;

fn shipped() -> Vec<u8> {
    let path = repo().join("weights/bino_int8.bin");
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// `blob` without its attention reach: the same weights read as band attention.
fn band_attention(blob: &Blob<'_>) -> Vec<u8> {
    let reach = ids::id(kind::ATTENTION_ROWS, 0);
    let mut out = BlobWriter::new();
    for info in blob.tensors().filter(|t| t.id != reach) {
        let (dtype, bytes) = blob.raw(info.id).unwrap();
        out.add_raw(info.id, dtype, info.elements, bytes.to_vec()).unwrap();
    }
    out.finish()
}

fn pixels(seed: u64, len: usize) -> Vec<u8> {
    let mut rng = Rng::new(seed);
    (0..len).map(|_| rng.next_u64() as u8).collect()
}

/// The pair tokens of a `height`-row band.
fn tokens(encoder: &Encoder<'_>, left: &[u8], right: &[u8], height: usize) -> Vec<i8> {
    let (l, r) = (
        GrayBand::new(left, WIDTH, height).unwrap(),
        GrayBand::new(right, WIDTH, height).unwrap(),
    );
    let mut arena = vec![0u8; arena_bytes(height, WIDTH)];
    let mut out = vec![0i8; height / 4 * ROW_BYTES];
    encoder.pair_tokens(l, r, &mut arena, &mut out, &mut NoProbe).unwrap();
    out
}

#[test]
fn the_shipped_encoder_attends_within_each_token_row() {
    let bytes = shipped();
    let blob = Blob::parse(&bytes).unwrap();
    assert_eq!(Encoder::new(blob).unwrap().weights().span(), AttentionSpan::Row);
    let band = band_attention(&blob);
    assert_eq!(
        Encoder::new(Blob::parse(&band).unwrap()).unwrap().weights().span(),
        AttentionSpan::Band
    );
}

#[test]
fn a_token_row_reads_only_its_own_pixel_rows() {
    let bytes = shipped();
    let encoder = Encoder::new(Blob::parse(&bytes).unwrap()).unwrap();
    let (left, right) = (pixels(1, WIDTH * HEIGHT), pixels(2, WIDTH * HEIGHT));
    let before = tokens(&encoder, &left, &right, HEIGHT);
    // Token row 5 (pixel rows 20..24) redrawn in both views: only its tokens change.
    let (mut left2, mut right2) = (left.clone(), right.clone());
    let rows = 20 * WIDTH..24 * WIDTH;
    left2[rows.clone()].copy_from_slice(&pixels(3, rows.len()));
    right2[rows.clone()].copy_from_slice(&pixels(4, rows.len()));
    let after = tokens(&encoder, &left2, &right2, HEIGHT);
    for (row, (a, b)) in before
        .chunks_exact(ROW_BYTES)
        .zip(after.chunks_exact(ROW_BYTES))
        .enumerate()
    {
        assert_eq!(a == b, row != 5, "token row {row}");
    }
}

#[test]
fn a_bands_first_row_is_band_attention_on_that_row_alone() {
    let bytes = shipped();
    let blob = Blob::parse(&bytes).unwrap();
    let band = band_attention(&blob);
    let (row_encoder, band_encoder) = (
        Encoder::new(blob).unwrap(),
        Encoder::new(Blob::parse(&band).unwrap()).unwrap(),
    );
    let (left, right) = (pixels(5, WIDTH * HEIGHT), pixels(6, WIDTH * HEIGHT));
    let rows = tokens(&row_encoder, &left, &right, HEIGHT);
    let alone = tokens(&band_encoder, &left[..4 * WIDTH], &right[..4 * WIDTH], 4);
    assert!(rows[..ROW_BYTES] == alone[..]);
    // Band attention over all twelve rows mixes them: it is not row attention.
    let mixed = tokens(&band_encoder, &left, &right, HEIGHT);
    assert!(mixed[..ROW_BYTES] != rows[..ROW_BYTES]);
}
