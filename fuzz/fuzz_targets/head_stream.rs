//! The shared head's stream on the shipped blob: any width, candidate count, arena size, row
//! lengths and codes, rows pushed after `finish`.
#![no_main]

use arbitrary::Arbitrary;
use bino_core::blob::Blob;
use bino_core::config::DIM;
use bino_core::model::head::{arena_bytes_with, HeadRow, HeadSink, HeadStream, HeadView, HeadWeights};
use bino_core::model::ids::HeadKind;
use bino_fuzz::SHIPPED_BLOB;
use libfuzzer_sys::fuzz_target;

#[derive(Debug, Arbitrary)]
struct Input {
    cols: u8,
    candidates: u8,
    arena_delta: i16,
    /// (length change of the row, rows to push) per step; a `None` step calls `finish`.
    steps: Vec<Option<(i8, u8)>>,
    codes: Vec<i8>,
}

struct Count(usize);

impl HeadSink for Count {
    fn row(&mut self, row: HeadRow<'_>) {
        assert_eq!(row.row, self.0, "rows leave the head in order");
        assert_eq!(row.disparity_q8.len(), row.confidence_q8.len());
        assert_eq!(row.logits.len(), row.disparity_q8.len() * row.candidates);
        // Soft-argmin stays inside the candidates (Q8 patch columns).
        assert!(row
            .disparity_q8
            .iter()
            .all(|&d| usize::from(d) < row.candidates.max(1) * 256));
        self.0 += 1;
    }
}

fuzz_target!(|input: Input| {
    let Ok(blob) = Blob::parse(SHIPPED_BLOB) else {
        panic!("the shipped blob must parse")
    };
    let Ok(weights) = HeadWeights::new(blob) else {
        panic!("the shipped blob has a head")
    };
    let cols = usize::from(input.cols % 50);
    let candidates = usize::from(input.candidates % 80);
    let needed = arena_bytes_with(HeadKind::Export, cols, candidates);
    let len = (needed as i64 + i64::from(input.arena_delta)).clamp(0, 1 << 22) as usize;
    let mut arena = vec![0u8; len];
    let Ok(mut stream) = HeadStream::with_candidates(weights, cols, candidates, HeadView::Left, &mut arena) else {
        return;
    };
    let mut sink = Count(0);
    let mut pushed = 0usize;
    let mut finished = false;
    for step in input.steps.iter().take(24) {
        match *step {
            None => {
                let _ = stream.finish(&mut sink);
                finished = true;
            }
            Some((delta, rows)) => {
                let row_len = (cols * DIM) as isize + isize::from(delta) * isize::from(delta % 2);
                let row_len = row_len.max(0) as usize;
                let row: Vec<i8> = (0..row_len)
                    .map(|i| input.codes.get(i % input.codes.len().max(1)).copied().unwrap_or(0))
                    .collect();
                for _ in 0..rows % 4 {
                    if stream.push_row(&row, &row, &mut sink).is_ok() {
                        assert!(!finished, "a finished stream must refuse rows");
                        pushed += 1;
                    }
                }
            }
        }
    }
    let _ = stream.finish(&mut sink);
    // Every pushed row comes out once the stream is finished.
    assert_eq!(sink.0, pushed);
    assert_eq!(stream.rows_out(), pushed);
});
