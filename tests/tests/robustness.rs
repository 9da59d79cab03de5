//! Regression tests of every crash fuzzing found in `bino-core` (issue 12), on the shipped
//! blob: absurd sizes are errors returned before any work, sizing helpers never return a
//! small wrong size, and nothing loops on a source that lies about its height.

use bino_core::config::{MAX_HEIGHT, MAX_TOKEN_ROWS};
use bino_core::model::encoder::{self, GrayBand};
use bino_core::model::head;
use bino_core::pipeline::{arena_bytes, MatchedRow, Options, Pipeline, RowSource, Sink};
use bino_core::Error;
use bino_host::demo::{DEFAULT_BLOB, DEFAULT_PENALTIES};
use bino_host::int8::Int8Model;

/// A source of constant rows that reports whatever size it is told to, and counts reads.
struct LyingSource {
    width: usize,
    height: usize,
    reads: usize,
}

impl RowSource for LyingSource {
    fn width(&self) -> usize {
        self.width
    }
    fn height(&self) -> usize {
        self.height
    }
    fn next_row(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), Error> {
        self.reads += 1;
        left.fill(100);
        right.fill(100);
        Ok(())
    }
}

struct Rows(usize);

impl Sink for Rows {
    fn matched(&mut self, _: &MatchedRow<'_>) {
        self.0 += 1;
    }
}

fn options(max_cols: usize) -> Options {
    Options {
        pathway: bino_core::pipeline::Pathway::Export,
        max_cols,
        penalties: DEFAULT_PENALTIES,
        lr_max_diff_q8: 256,
        head: false,
        head_lr: false,
        head_candidates: bino_core::config::HEAD_MAX_DISP,
    }
}

/// `band.rs:68`: a source reporting ~2^34 token rows overflowed the band plan, and in release
/// builds the run went on for ~2^59 bands. Now it is refused before a row is read.
#[test]
fn a_source_reporting_a_huge_height_is_refused_at_once() {
    let model = Int8Model::load(DEFAULT_BLOB.as_ref()).unwrap();
    let pipeline = Pipeline::new(model.blob().unwrap()).unwrap();
    let mut arena = vec![0u8; arena_bytes(96, 16, 8)];
    for height in [MAX_HEIGHT + 4, 1 << 36, usize::MAX - 3] {
        let mut source = LyingSource {
            width: 16,
            height,
            reads: 0,
        };
        let err = pipeline.run(&mut source, &options(8), &mut arena, &mut Rows(0));
        assert_eq!(
            err.unwrap_err(),
            Error::TooTall {
                height,
                max: MAX_HEIGHT
            }
        );
        assert_eq!(source.reads, 0);
    }
    // The maximum itself is a valid (tall, narrow) image: every row read once, every token
    // row emitted, in an arena sized for one band's width.
    let mut source = LyingSource {
        width: 8,
        height: MAX_HEIGHT,
        reads: 0,
    };
    let mut rows = Rows(0);
    let mut arena = vec![0u8; arena_bytes(MAX_HEIGHT, 8, 2)];
    let report = pipeline.run(&mut source, &options(2), &mut arena, &mut rows).unwrap();
    assert_eq!(
        (source.reads, rows.0, report.rows),
        (MAX_HEIGHT, MAX_TOKEN_ROWS, MAX_TOKEN_ROWS)
    );
}

/// `pipeline.rs:246/262`, `encoder.rs:52`, `head.rs:63`, `sgm.rs:41`: the sizing helpers
/// overflowed for absurd widths or candidate counts (and wrapped to small sizes in release
/// builds). They saturate now, and the run refuses such a size.
#[test]
fn sizing_helpers_saturate_instead_of_wrapping() {
    // The firmware's static arena (48x160, 16 candidates) is unchanged by the rewrite.
    assert_eq!(arena_bytes(48, 160, 16), 486_918);
    assert_eq!(arena_bytes(48, usize::MAX, 16), usize::MAX);
    assert_eq!(arena_bytes(4000, usize::MAX / 2, 16), usize::MAX);
    assert_eq!(arena_bytes(48, 160, usize::MAX), usize::MAX);
    assert_eq!(encoder::arena_bytes(48, usize::MAX), usize::MAX);
    assert_eq!(head::arena_bytes(usize::MAX), usize::MAX);
    assert_eq!(bino_core::sgm::state_len(usize::MAX, 64), usize::MAX);
    // Monotone where they do fit: a wider image never needs less.
    let mut last = 0;
    for width in (4..=4096).step_by(4) {
        let bytes = arena_bytes(48, width, 16);
        assert!(bytes > last, "width {width}: {bytes} after {last}");
        last = bytes;
    }
    let model = Int8Model::load(DEFAULT_BLOB.as_ref()).unwrap();
    let pipeline = Pipeline::new(model.blob().unwrap()).unwrap();
    let mut arena = vec![0u8; arena_bytes(48, 160, 16)];
    let mut source = LyingSource {
        width: 160,
        height: 48,
        reads: 0,
    };
    let err = pipeline.run(&mut source, &options(usize::MAX), &mut arena, &mut Rows(0));
    assert!(matches!(err, Err(Error::Candidates { .. })), "{err:?}");
    let mut wide = LyingSource {
        width: usize::MAX - 3,
        height: 48,
        reads: 0,
    };
    let err = pipeline.run(&mut wide, &options(16), &mut arena, &mut Rows(0));
    assert!(matches!(err, Err(Error::TooWide { .. })), "{err:?}");
    assert_eq!(source.reads + wide.reads, 0);
}

/// `encoder.rs:78`: `GrayBand::new` multiplied width by height before checking the length.
#[test]
fn a_band_view_with_an_absurd_width_is_a_size_error() {
    let err = GrayBand::new(&[0u8; 16], usize::MAX - 3, 4).unwrap_err();
    assert!(matches!(err, Error::BufferSize { .. }), "{err:?}");
    assert!(matches!(
        GrayBand::new(&[0u8; 16], 4, 52),
        Err(Error::BandTooTall { .. })
    ));
}
