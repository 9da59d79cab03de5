//! The pixel refinement with arbitrary sizes, parameters, views, token grids and buffer
//! lengths: `refine_map` over whole maps and `refine_row` with arbitrary windows and rows; and,
//! on well-formed inputs, `RowRefiner` against the reference `refine_row`, rows in any order;
//! and the sharpness-equalised whole-map refinement on the same inputs; and the `+lr+ref`
//! rule for rejected cells (`keep_rejected_map`) on the same grid.
#![no_main]

use arbitrary::Arbitrary;
use bino_core::refine::sharpness::refine_map_equalised;
use bino_core::refine::{
    keep_rejected_map, refine_map, refine_row, scratch_len, token_rows, window_row, RefineParams, RowRefiner,
    TokenRows, ViewRows,
};
use libfuzzer_sys::fuzz_target;

#[derive(Debug, Arbitrary)]
struct Input {
    width: u8,
    height: u8,
    /// Parameters as given (out-of-range values included).
    census_radius: u8,
    search: u8,
    lambda: u16,
    box_radius: u8,
    /// Length changes of the buffers (0: the right length).
    tokens_delta: i8,
    scratch_delta: i8,
    out_delta: i8,
    right_delta: i8,
    pixels: Vec<u8>,
    tokens: Vec<u16>,
    /// refine_row: the row asked for, and the window's rows as indices into the view.
    row: u16,
    window: Vec<u8>,
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
    let (w, h) = (usize::from(input.width % 64), usize::from(input.height % 40));
    let params = RefineParams {
        census_radius: usize::from(input.census_radius % 4),
        search: usize::from(input.search % 11),
        lambda: u32::from(input.lambda),
        box_radius: usize::from(input.box_radius % 5),
    };
    let left = resized(&input.pixels, w * h);
    let right: Vec<u8> = resized(&input.pixels, adjust(w * h, input.right_delta))
        .iter()
        .map(|p| p.wrapping_mul(7))
        .collect();
    let grid = w.div_ceil(4) * h.div_ceil(4);
    let tokens = resized(&input.tokens, adjust(grid, input.tokens_delta));
    let mut scratch = vec![0u32; adjust(scratch_len(w, &params), input.scratch_delta)];
    let mut out = vec![0u16; adjust(w * h, input.out_delta)];
    let whole = refine_map(&left, &right, w, &tokens, &params, &mut scratch, &mut out);
    let equalised = refine_map_equalised(&left, &right, w, &tokens, &params, &mut scratch, &mut out);
    // The same checks of sizes and parameters: both accept the same inputs.
    assert_eq!(whole.is_ok(), equalised.is_ok(), "{whole:?} {equalised:?}");
    if whole.is_ok() {
        faster_equals_reference(&input, &left, &right, &tokens, w, h, &params);
    }
    // The `+lr+ref` rule on the same grid, a mask from the pixels, the grid's length change.
    let kept: Vec<u8> = resized(&input.pixels, tokens.len()).iter().map(|p| p & 1).collect();
    let keep = keep_rejected_map(w, &tokens, &kept, &mut out);
    if whole.is_ok() {
        assert!(keep.is_ok(), "a map refine_map accepts: {keep:?}");
    }

    let rows: Vec<&[u8]> = input
        .window
        .iter()
        .take(16)
        .map(|&i| {
            let y = usize::from(i) % h.max(1);
            left.get(y * w..(y + 1) * w).unwrap_or(&[])
        })
        .collect();
    let view = ViewRows {
        height: h,
        left: &rows,
        right: &rows,
    };
    let cols = w.div_ceil(4);
    let token_rows = TokenRows {
        first: tokens.get(..cols).unwrap_or(&[]),
        second: tokens.get(cols..2 * cols).unwrap_or(&tokens),
    };
    let mut row_out = vec![0u16; adjust(w, input.out_delta)];
    let _ = refine_row(
        usize::from(input.row),
        &view,
        &token_rows,
        &params,
        &mut scratch,
        &mut row_out,
    );
});

/// `RowRefiner` gives the reference's rows bit for bit, for output rows in the order the input
/// names them (repeats and jumps included) over one image.
fn faster_equals_reference(
    input: &Input,
    left: &[u8],
    right: &[u8],
    tokens: &[u16],
    w: usize,
    h: usize,
    params: &RefineParams,
) {
    let cols = w.div_ceil(4);
    let grid_rows = h.div_ceil(4);
    let mut ring_scratch = vec![0u32; scratch_len(w, params)];
    let mut reference_scratch = vec![0u32; scratch_len(w, params)];
    let mut refiner = RowRefiner::new(&mut ring_scratch, w, params).expect("valid sizes");
    for &pick in input.window.iter().take(24) {
        let y = usize::from(pick) % h;
        let reach = params.reach();
        let (l, r) = (
            window(left, y, reach, w, h, params),
            window(right, y, reach, w, h, params),
        );
        let rows = ViewRows {
            height: h,
            left: &l,
            right: &r,
        };
        let (first, second) = token_rows(y, grid_rows);
        let toks = TokenRows {
            first: &tokens[first * cols..(first + 1) * cols],
            second: &tokens[second * cols..(second + 1) * cols],
        };
        let mut fast = vec![0u16; w];
        let mut slow = vec![0u16; w];
        refiner.refine_row(y, &rows, &toks, &mut fast).expect("refiner row");
        refine_row(y, &rows, &toks, params, &mut reference_scratch, &mut slow).expect("reference row");
        assert_eq!(fast, slow, "row {y}");
    }
}

fn window<'v>(view: &'v [u8], y: usize, reach: usize, w: usize, h: usize, params: &RefineParams) -> Vec<&'v [u8]> {
    (0..params.window_rows())
        .map(|e| {
            let v = window_row(y, e, reach, h);
            &view[v * w..(v + 1) * w]
        })
        .collect()
}
