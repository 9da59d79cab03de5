//! Tests of the refinement stage: token rows streamed band by band at every height give the
//! whole-map refinement, and a view ring one row short is an error, not a wrong row.

use super::*;
use crate::band::BandPlan;
use crate::config::BAND_TOKEN_ROWS;
use crate::lr::fill_rejected;
use crate::pipeline::layout::HEAD_LAG;
use crate::refine::sharpness::{decide_map_row, refine_map_equalised};
use crate::refine::{keep_rejected_map, refine_map};
use crate::testutil::Rng;

const W: usize = 16;
const MAX_H: usize = 400;
const BAND_PX: usize = BAND_TOKEN_ROWS * PATCH_H;

struct Rows<'o> {
    out: &'o mut [u16],
    next: usize,
    out_of_order: bool,
}

impl Sink for Rows<'_> {
    fn matched(&mut self, _: &super::super::MatchedRow<'_>) {}
    fn refined(&mut self, row: usize, disparity_q8: &[u16]) {
        self.out_of_order |= row != self.next || disparity_q8.len() != W;
        if let Some(dst) = self.out.get_mut(row * W..(row + 1) * W) {
            dst.copy_from_slice(disparity_q8);
        }
        self.next += 1;
    }
}

fn band_view<'b>(left: &'b [u8], right: &'b [u8], first: usize, loaded: usize) -> BandView<'b> {
    BandView {
        first,
        rows: loaded - first,
        width: W,
        left,
        right,
    }
}

/// The pipeline's order of events for an image of `height` rows whose readout trails the
/// bands by `lag` token rows: band loads (after the stage saved what they drop), the token
/// rows each band's push makes, the rest at the end. The pixel rows must equal
/// `refine_map` on the filled grid, and the ring must be large enough.
fn streams_like_the_whole_map(height: usize, lag: usize, params: &RefineParams, seed: u64) {
    streams_like_the_whole_map_with(height, lag, params, false, seed);
}

/// The same, with or without the sharpness equalisation; with it, the right view is
/// smoothed below the middle so that rows of both kinds occur.
fn streams_like_the_whole_map_with(height: usize, lag: usize, params: &RefineParams, equalise: bool, seed: u64) {
    let mut rng = Rng::new(seed);
    let (t_rows, cols) = (height / PATCH_H, W / CELL_W);
    let (mut left, mut right) = ([0u8; MAX_H * W], [0u8; MAX_H * W]);
    let n = height * W;
    for (l, r) in left.iter_mut().zip(right.iter_mut()).take(n) {
        (*l, *r) = (rng.range(0, 255) as u8, rng.range(0, 255) as u8);
    }
    if equalise {
        // Twice a 5-tap mean along the row: defocus that rule 4a does not take for a
        // contrast change.
        for y in height / 2..height {
            let row = &mut right[y * W..(y + 1) * W];
            for _ in 0..2 {
                let copy: [u8; W] = core::array::from_fn(|x| row[x]);
                for (x, v) in row.iter_mut().enumerate() {
                    let sum: u32 = (x..x + 5).map(|u| copy[u.saturating_sub(2).min(W - 1)] as u32).sum();
                    *v = ((sum + 2) / 5) as u8;
                }
            }
        }
    }
    let mut grid = [0u16; MAX_H / PATCH_H * W / CELL_W];
    let mut mask = [0u8; MAX_H / PATCH_H * W / CELL_W];
    for (g, m) in grid.iter_mut().zip(mask.iter_mut()).take(t_rows * cols) {
        (*g, *m) = (rng.range(0, 3 * 256) as u16, (rng.range(0, 3) > 0) as u8);
    }
    let mut filled = grid;
    for (row, m) in filled[..t_rows * cols]
        .chunks_exact_mut(cols)
        .zip(mask.chunks_exact(cols))
    {
        fill_rejected(row, m).unwrap();
    }
    let mut scratch = [0u32; 2 * (2 * crate::refine::MAX_BOX_RADIUS + 1) * W];
    let mut expected = [0u16; MAX_H * W];
    let len = scratch_len(W, params);
    if equalise && height >= 8 {
        let blurs = (0..height)
            .filter(|&y| decide_map_row(&left[..n], &right[..n], W, height, y).unwrap().radius > 0)
            .count();
        assert!(blurs > 0 && blurs < height, "h {height}: {blurs} rows blurred");
    }
    let whole = if equalise { refine_map_equalised } else { refine_map };
    whole(
        &left[..n],
        &right[..n],
        W,
        &filled[..t_rows * cols],
        params,
        &mut scratch[..len],
        &mut expected[..n],
    )
    .unwrap();
    // A `+lr` readout: the rejected cells' pixels keep the bilinear step.
    keep_rejected_map(W, &filled[..t_rows * cols], &mask[..t_rows * cols], &mut expected[..n]).unwrap();

    let plan = BandPlan::new(t_rows).unwrap();
    let ring = if plan.len() > 1 {
        ring_rows(stage_reach(params, equalise), lag)
    } else {
        0
    };
    let mut state = [0u8; 4096];
    let mut stage = RefineStage::new(*params, equalise, W, height, ring, &mut state).unwrap();
    let mut row_arena = [0u8; 2048];
    let mut got = [0u16; MAX_H * W];
    let mut sink = Rows {
        out: &mut got,
        next: 0,
        out_of_order: false,
    };
    let (mut buf_l, mut buf_r) = ([0u8; BAND_PX * W], [0u8; BAND_PX * W]);
    let (mut first, mut loaded) = (0usize, 0usize);
    let mut pushed = 0usize;
    let band_px = BAND_PX.min(height);
    for (i, band) in plan.iter().enumerate() {
        let start = band.start * PATCH_H;
        if i > 0 {
            let v = band_view(&buf_l, &buf_r, first, loaded);
            stage
                .keep_before(&v, start)
                .unwrap_or_else(|e| panic!("h {height} lag {lag}: {e}"));
        }
        // As BandRows::load: keep the overlap, read the rest.
        let keep = loaded.saturating_sub(start.max(first));
        let drop = loaded - first - keep;
        buf_l.copy_within(drop * W..(drop + keep) * W, 0);
        buf_r.copy_within(drop * W..(drop + keep) * W, 0);
        first = start;
        while loaded < (band.start + band.rows) * PATCH_H {
            let at = (loaded - first) * W;
            buf_l[at..at + W].copy_from_slice(&left[loaded * W..(loaded + 1) * W]);
            buf_r[at..at + W].copy_from_slice(&right[loaded * W..(loaded + 1) * W]);
            loaded += 1;
        }
        assert!(loaded - first <= band_px);
        let mut io = RefineIo {
            view: band_view(&buf_l, &buf_r, first, loaded),
            scratch: Scratch::new(&mut row_arena, W, height, params, equalise).unwrap(),
        };
        for row in band.keep_from..band.keep_to {
            if row >= lag {
                let t = row - lag;
                let at = t * cols..(t + 1) * cols;
                stage
                    .push(t, &grid[at.clone()], Some(&mask[at]), &mut io, &mut sink)
                    .unwrap_or_else(|e| panic!("h {height} lag {lag} row {t}: {e}"));
                pushed += 1;
            }
        }
    }
    let mut io = RefineIo {
        view: BandView {
            first,
            rows: loaded - first,
            width: W,
            left: &buf_l,
            right: &buf_r,
        },
        scratch: Scratch::new(&mut row_arena, W, height, params, equalise).unwrap(),
    };
    for t in pushed..t_rows {
        let at = t * cols..(t + 1) * cols;
        stage
            .push(t, &grid[at.clone()], Some(&mask[at]), &mut io, &mut sink)
            .unwrap();
    }
    stage.done().unwrap_or_else(|e| panic!("h {height} lag {lag}: {e}"));
    assert!(!sink.out_of_order, "h {height} lag {lag}");
    for y in 0..height {
        assert_eq!(
            got[y * W..(y + 1) * W],
            expected[y * W..(y + 1) * W],
            "h {height} lag {lag} row {y}"
        );
    }
}

#[test]
fn every_height_streams_like_the_whole_map_with_a_ring_just_large_enough() {
    // The default box (9x9) and the 5x5 box it replaced.
    let narrow = RefineParams {
        box_radius: 2,
        ..RefineParams::DEFAULT
    };
    for height in (4..=MAX_H).step_by(4) {
        for lag in [0, 1, HEAD_LAG] {
            streams_like_the_whole_map(height, lag, &RefineParams::DEFAULT, height as u64);
        }
        if height % 20 == 0 {
            streams_like_the_whole_map(height, HEAD_LAG, &narrow, 7);
            streams_like_the_whole_map(height, 0, &narrow, 7);
        }
    }
    // With the sharpness equalisation (reach 8): every height, both lags that matter.
    for height in (4..=MAX_H).step_by(12) {
        for lag in [0, HEAD_LAG] {
            streams_like_the_whole_map_with(height, lag, &RefineParams::DEFAULT, true, height as u64);
        }
    }
    assert_eq!(stage_reach(&RefineParams::DEFAULT, true), 8);
    assert_eq!(ring_rows(8, 0), 2, "the matching readouts keep two rows of each view");
    // The sizes the budget quotes.
    assert_eq!(ring_rows(8, HEAD_LAG), 26);
    assert_eq!(ring_rows(RefineParams::DEFAULT.reach(), HEAD_LAG), 24);
    assert_eq!(ring_rows(RefineParams::DEFAULT.reach(), 0), 0);
    assert_eq!(ring_rows(6, 0), 0);
}

#[test]
fn a_ring_one_row_short_is_an_error_not_a_wrong_row() {
    // 80 rows: three bands 32 rows apart (stride 8), the worst case of the ring.
    let params = RefineParams::DEFAULT;
    let ring = ring_rows(params.reach(), HEAD_LAG) - 1;
    let mut state = [0u8; 4096];
    let mut stage = RefineStage::new(params, false, W, 80, ring, &mut state).unwrap();
    let (buf_l, buf_r) = ([0u8; BAND_PX * W], [0u8; BAND_PX * W]);
    let view = BandView {
        first: 0,
        rows: BAND_PX,
        width: W,
        left: &buf_l,
        right: &buf_r,
    };
    let mut row_arena = [0u8; 2048];
    let mut io = RefineIo {
        view,
        scratch: Scratch::new(&mut row_arena, W, 80, &params, false).unwrap(),
    };
    let mut out = [0u16; 80 * W];
    let mut sink = Rows {
        out: &mut out,
        next: 0,
        out_of_order: false,
    };
    // Band 0 keeps token rows 0..10; the head has given 0..4 when band 1 (start 8) loads.
    for t in 0..4 {
        stage.push(t, &[256; W / CELL_W], None, &mut io, &mut sink).unwrap();
    }
    assert!(matches!(
        stage.keep_before(&view, 32),
        Err(Error::BufferSize {
            what: "refinement view ring",
            ..
        })
    ));
    assert!(
        stage.push(5, &[0; W / CELL_W], None, &mut io, &mut sink).is_err(),
        "rows in order"
    );
    assert!(stage.done().is_err(), "rows missing");
}
