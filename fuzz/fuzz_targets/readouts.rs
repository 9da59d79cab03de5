//! The readouts' public functions with arbitrary lengths and values: inverse norms, WTA
//! matching, cost rows, streaming SGM, the right view and the left-right check, the census SGM,
//! band plans.
#![no_main]

use arbitrary::Arbitrary;
use bino_core::band::BandPlan;
use bino_core::census::{self, CensusSgm, WINDOW_ROWS};
use bino_core::config::DIM;
use bino_core::lr::{consistent_row, right_view_costs, wta_costs};
use bino_core::matching::{cost_row, inverse_norms, match_row, MAX_CANDIDATES};
use bino_core::sgm::{state_len, Penalties, SgmStream};
use libfuzzer_sys::fuzz_target;

#[derive(Debug, Arbitrary)]
struct Input {
    /// Cells of the descriptor rows (the row lengths are cells * DIM plus a ragged tail).
    cells: u8,
    tail: u8,
    /// Length changes of the other buffers (0: the right length).
    norms_delta: i8,
    out_delta: i8,
    candidates: u8,
    codes: Vec<i8>,
    /// Inverse norms as given, not as `inverse_norms` would make them.
    norms: Vec<u32>,
    costs: Vec<u16>,
    p1: u16,
    p2: u16,
    edge: u8,
    /// Each cell's grey level for the guided SGM (resized to the cells, and one short).
    guide: Vec<u8>,
    guide_delta: i8,
    /// SGM rows pushed.
    sgm_rows: u8,
    lr_max_diff_q8: u16,
    /// A band plan's token rows (any usize, absurd included).
    token_rows: usize,
    /// A band index to look up directly.
    band_index: usize,
}

fn resized<T: Copy + Default>(values: &[T], len: usize) -> Vec<T> {
    (0..len)
        .map(|i| values.get(i % values.len().max(1)).copied().unwrap_or_default())
        .collect()
}

fn adjust(len: usize, delta: i8) -> usize {
    (len as isize + delta as isize).max(0) as usize
}

fuzz_target!(|input: Input| {
    let cells = usize::from(input.cells % 48);
    let row_len = cells * DIM + usize::from(input.tail % 3) * usize::from(input.tail % DIM as u8);
    let left = resized(&input.codes, row_len);
    let right: Vec<i8> = resized(&input.codes, row_len)
        .iter()
        .map(|c| c.wrapping_mul(3))
        .collect();
    let candidates = usize::from(input.candidates % (MAX_CANDIDATES as u8 + 3));
    let norms_len = adjust(cells, input.norms_delta);
    let out_len = adjust(cells, input.out_delta);

    let mut made = vec![0u32; norms_len];
    let _ = inverse_norms(&right, &mut made);
    let norms = resized(&input.norms, norms_len);
    let mut out = vec![0u16; out_len];
    let _ = match_row(&left, &right, &norms, candidates, &mut out);
    let _ = match_row(&left, &right, &made, candidates, &mut out);
    let mut cost = vec![0u16; adjust(cells * candidates, input.out_delta)];
    let _ = cost_row(&left, &right, &norms, &made, candidates, &mut cost);

    // SGM over fuzzed cost rows (any u16 costs, not only those cost_row makes).
    let len = state_len(cells, candidates);
    let (mut v, mut d, mut s) = (
        vec![0u16; len],
        vec![0u16; len],
        vec![0u32; adjust(len, input.norms_delta)],
    );
    let penalties = Penalties {
        p1: input.p1,
        p2: input.p2,
        edge: input.edge,
    };
    let mut prev_guide = vec![0u8; adjust(cells, input.guide_delta)];
    let guide_fits = prev_guide.len() == cells;
    if let Ok(sgm) = SgmStream::new(cells, candidates, penalties, &mut v, &mut d, &mut s) {
        let costs = resized(&input.costs, adjust(len, input.out_delta));
        let guide = resized(&input.guide, adjust(cells, input.out_delta));
        let mut disparity = vec![0u16; cells];
        match sgm.with_guide(&mut prev_guide) {
            Ok(mut sgm) => {
                for i in 0..input.sgm_rows % 8 {
                    let _ = if i % 2 == 0 {
                        sgm.push_row_guided(&costs, &guide, &mut disparity)
                    } else {
                        sgm.push_row(&costs, &mut disparity)
                    };
                }
            }
            Err(_) => assert!(!guide_fits),
        }
    }

    let costs = resized(&input.costs, adjust(len, input.norms_delta));
    let mut right_costs = vec![0u16; adjust(costs.len(), input.out_delta)];
    let _ = right_view_costs(&costs, candidates, &mut right_costs);
    let mut wta_left = vec![0u16; cells];
    let _ = wta_costs(&costs, candidates, &mut wta_left);
    let wta_right = resized(&input.costs, adjust(cells, input.norms_delta));
    let mut mask = vec![0u8; out_len];
    if let Ok(kept) = consistent_row(&wta_left, &wta_right, input.lr_max_diff_q8, &mut mask) {
        assert!(kept <= cells);
    }

    // The census SGM over fuzzed pixels: a width of whole cells or not, any disparity count,
    // penalties and uniqueness, windows and rows of the right length or not.
    let width = cells * 4 + usize::from(input.tail % 4);
    let disparities = usize::from(input.candidates);
    let (mut s32, mut s16) = (
        vec![0u32; adjust(census::scratch_u32_len(width, disparities), input.guide_delta)],
        vec![0u16; census::scratch_u16_len(width, disparities)],
    );
    let pixels: Vec<u8> = resized(&input.guide, adjust(width, input.out_delta));
    let rows = adjust(WINDOW_ROWS, input.norms_delta % 2);
    if let Ok(sgm) = CensusSgm::new(width, disparities, penalties, input.lr_max_diff_q8, &mut s32, &mut s16) {
        let mut sgm = sgm.with_uniqueness(input.edge);
        let window: Vec<&[u8]> = (0..rows).map(|_| &pixels[..]).collect();
        let (mut disparity, mut kept) = (vec![0u16; out_len], vec![0u8; cells]);
        for _ in 0..input.sgm_rows % 4 {
            if let Ok(count) = sgm.push_row(&window, &window, &mut disparity, &mut kept) {
                assert!(count <= cells);
            }
        }
    }

    if let Ok(plan) = BandPlan::new(input.token_rows) {
        let _ = plan.get(input.band_index);
        // Walk at most a few thousand bands: a valid plan is short.
        assert!(plan.len() <= 1 + bino_core::config::MAX_TOKEN_ROWS / 8);
        let mut next = 0;
        for band in plan.iter() {
            assert_eq!(band.keep_from, next);
            next = band.keep_to;
        }
        assert_eq!(next, input.token_rows);
    }
});
