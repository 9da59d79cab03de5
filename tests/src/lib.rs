//! Helpers shared by the workspace-level integration tests.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use bino_host::data::profile::View;
use bino_host::io::npy::{self, Array};

/// The folder of committed test fixtures.
pub fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("fixtures")
}

/// Reads a `.npy` fixture.
pub fn read_npy(path: &Path) -> Result<Array> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read fixture {}", path.display()))?;
    npy::decode(&bytes).with_context(|| format!("fixture {}", path.display()))
}

/// A (1, 3, H, W) view tensor with the gray channel replicated, as a [`View`] (channel 0).
pub fn view_from_nchw(array: &Array) -> Result<View> {
    let [n, c, h, w] = array.shape[..] else {
        anyhow::bail!("expected a 4-D array, got {:?}", array.shape)
    };
    anyhow::ensure!(n == 1 && c == 3, "expected shape (1, 3, H, W), got {:?}", array.shape);
    Ok(View {
        width: w,
        height: h,
        pixels: array.data[..h * w].to_vec(),
    })
}

/// Whether a test must fail instead of skipping when an input outside the repository is missing
/// (`../shared/data`, the project's Python environment): under `CI=true` or `BINO_REQUIRE_DATA=1`
/// (which `scripts/test.sh` sets).
pub fn inputs_required() -> bool {
    let set = |name: &str, values: &[&str]| std::env::var(name).is_ok_and(|v| values.contains(&v.as_str()));
    set("CI", &["true", "1"]) || set("BINO_REQUIRE_DATA", &["1", "true"])
}

/// `present`, after a `skipped:` note on stderr when it is false; panics instead when
/// [`inputs_required`], so a missing input never passes in CI.
pub fn available(what: &str, present: bool) -> bool {
    if !present {
        assert!(
            !inputs_required(),
            "{what} is missing (CI=true or BINO_REQUIRE_DATA=1: not skipped)"
        );
        eprintln!("skipped: {what} is missing (set BINO_REQUIRE_DATA=1 to fail instead)");
    }
    present
}

/// The census SGM's grid and mask over a whole `height x width` pair, token row after token row
/// (`bino_core::census`), independent of the pipeline's streaming of it.
pub fn census_whole_map(
    left: &[u8],
    right: &[u8],
    width: usize,
    height: usize,
    candidates: usize,
) -> (Vec<u16>, Vec<u8>) {
    let n = bino_core::census::disparities(candidates);
    let (mut s32, mut s16) = (
        vec![0u32; bino_core::census::scratch_u32_len(width, n)],
        vec![0u16; bino_core::census::scratch_u16_len(width, n)],
    );
    let mut sgm =
        bino_core::census::CensusSgm::new(width, n, bino_core::census::DEFAULT_PENALTIES, 256, &mut s32, &mut s16)
            .unwrap();
    let cols = width / 4;
    let (mut grid, mut mask) = (vec![0u16; height / 4 * cols], vec![0u8; height / 4 * cols]);
    // View rows clamp(4 t + j - 2), j = 0..8: the token row's pixel rows and the census reach.
    fn window(view: &[u8], width: usize, height: usize, t: usize) -> Vec<&[u8]> {
        (0..bino_core::census::WINDOW_ROWS)
            .map(|j| {
                let y = bino_core::census::window_row(t, j, height);
                &view[y * width..(y + 1) * width]
            })
            .collect()
    }
    for t in 0..height / 4 {
        let at = t * cols..(t + 1) * cols;
        sgm.push_row(
            &window(left, width, height, t),
            &window(right, width, height, t),
            &mut grid[at.clone()],
            &mut mask[at],
        )
        .unwrap();
    }
    (grid, mask)
}

/// A pair in memory: two `width x height` grey views.
pub struct Scene {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Left view, row by row.
    pub left: Vec<u8>,
    /// Right view.
    pub right: Vec<u8>,
}

/// The built-in procedural scene (`bino_host::data::synthetic::default_scene`) at this size.
pub fn scene(width: usize, height: usize) -> Scene {
    let s = bino_host::data::synthetic::default_scene(width, height);
    Scene {
        width,
        height,
        left: s.left.pixels,
        right: s.right.pixels,
    }
}

/// The whole-map refinement (`refine_map_equalised` or `refine_map`) of the token `grid` (Q8
/// patch columns, already filled for a `+lr` readout) on `s`; with the readout's check `mask`,
/// the pixels of its rejected cells keep the bilinear step (`keep_rejected_map`): what the
/// pipeline's refinement stage must stream.
pub fn refine_whole_map(
    s: &Scene,
    grid: &[u16],
    mask: Option<&[u8]>,
    refine: &bino_core::pipeline::Refine,
) -> Vec<u16> {
    use bino_core::refine::{keep_rejected_map, refine_map, scratch_len, sharpness::refine_map_equalised};
    let mut scratch = vec![0u32; scratch_len(s.width, &refine.params)];
    let mut expected = vec![0u16; s.width * s.height];
    let whole = if refine.equalise {
        refine_map_equalised
    } else {
        refine_map
    };
    whole(
        &s.left,
        &s.right,
        s.width,
        grid,
        &refine.params,
        &mut scratch,
        &mut expected,
    )
    .unwrap();
    if let Some(mask) = mask {
        keep_rejected_map(s.width, grid, mask, &mut expected).unwrap();
    }
    expected
}

/// The repository's root (the folder holding `tests/`).
pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}
