//! Parity with the Python reference (`train/bino_train/probe.py`, `profile.py`) and OpenCV:
//! expected values were computed once with the Python code and opencv-python-headless 5.0.0
//! and are hard-coded here.

use std::path::{Path, PathBuf};

use super::*;
use crate::data::pairs::read_index;
use crate::data::profile::Profile;
use crate::float::reference::FeatureMap;

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data")
}

#[test]
fn ground_truth_at_w160_matches_python_resize_gt() {
    let dir = data_dir();
    if !dir.join("PAIRS.tsv").is_file() {
        crate::test_inputs::skip(&format!("{}/PAIRS.tsv", dir.display()));
        return;
    }
    // (pair, rows, sum of valid disparity, valid pixels) of resize_gt(*load_gt(pair), 160), summed
    // in float64. Tsukuba (288 rows -> 120) has rows where OpenCV's nearest-exact rounding picks
    // a different source row than exact pixel centres; Art is a PNG map.
    let expected = [
        ("mb2001_tsukuba", 120, 43197.91501188278, 15330),
        ("mb2005_Art", 128, 313554.1528224945, 20452),
    ];
    let records = read_index(&dir).unwrap();
    for (id, rows, sum, count) in expected {
        let record = records.iter().find(|r| r.pair_id == id).unwrap();
        let item = load_eval_item(record, Profile::W160).unwrap();
        let gt = &item.gt;
        assert_eq!((gt.width, gt.height), (160, rows), "{id}");
        assert_eq!((item.left.width, item.left.height), (160, rows), "{id}");
        assert_eq!(gt.valid_count(), count, "{id}");
        let total: f64 = (gt.disparity.iter().zip(&gt.valid))
            .filter(|(_, &v)| v)
            .map(|(&d, _)| d as f64)
            .sum();
        assert!((total - sum).abs() <= 1e-3 * sum, "{id}: {total} vs {sum}");
    }
}

#[test]
fn bilinear_resize_matches_opencv() {
    // cv2.resize(grid, (20, 12), interpolation=cv2.INTER_LINEAR) in opencv-python-headless 5.0.0,
    // grid = np.round(np.random.default_rng(0).uniform(-2, 10, (3, 5)), 3).astype(np.float32).
    let grid = [
        5.644, 1.237, -1.508, -1.802, 7.759, 8.953, 5.28, 6.754, 4.523, 9.221, 7.79, -1.967, 8.289, -1.597, 6.756,
    ];
    #[rustfmt::skip]
    let expected: [f32; 240] = [
        5.644, 5.644, 5.093125, 3.991375, 2.889625, 1.7878749, 0.893875, 0.20762503, -0.47862494, -1.1648749,
        -1.54475, -1.61825, -1.69175, -1.7652501, -0.60687506, 1.7833749, 4.173625, 6.5638747, 7.759, 7.759,
        5.644, 5.644, 5.093125, 3.991375, 2.889625, 1.7878749, 0.893875, 0.20762503, -0.47862494, -1.1648749,
        -1.54475, -1.61825, -1.69175, -1.7652501, -0.60687506, 1.7833749, 4.173625, 6.5638747, 7.759, 7.759,
        6.057625, 6.057625, 5.5182185, 4.4394064, 3.3605938, 2.2817812, 1.4651718, 0.9107657, 0.35635942, -0.19804674,
        -0.54226553, -0.6762969, -0.8103282, -0.9443595, 0.107765496, 2.346047, 4.584328, 6.822609, 7.9417496, 7.9417496,
        6.8848753, 6.8848753, 6.3684063, 5.335469, 4.3025312, 3.2695937, 2.6077657, 2.317047, 2.026328, 1.7356095,
        1.4627033, 1.2076094, 0.95251554, 0.6974217, 1.5370467, 3.4713907, 5.405734, 7.340078, 8.30725, 8.30725,
        7.712125, 7.712125, 7.218594, 6.231531, 5.244469, 4.257406, 3.7503593, 3.7233284, 3.696297, 3.669266,
        3.4676723, 3.0915155, 2.7153592, 2.339203, 2.9663277, 4.5967345, 6.2271404, 7.857547, 8.6727495, 8.6727495,
        8.539375, 8.539375, 8.068782, 7.1275935, 6.1864066, 5.2452188, 4.892953, 5.1296096, 5.366266, 5.6029224,
        5.472641, 4.975422, 4.478203, 3.9809842, 4.395609, 5.7220783, 7.0485463, 8.375015, 9.03825, 9.03825,
        8.807625, 8.807625, 8.253438, 7.1450624, 6.036688, 4.928313, 4.695594, 5.3385315, 5.9814687, 6.6244063,
        6.547391, 5.750422, 4.953453, 4.156484, 4.402359, 5.691078, 6.9797964, 8.268516, 8.912875, 8.912875,
        8.516875, 8.516875, 7.772563, 6.2839375, 4.795313, 3.3066876, 3.1582813, 4.350094, 5.5419064, 6.733719,
        6.6919217, 5.416516, 4.141109, 2.8657026, 2.9865777, 4.503734, 6.02089, 7.538047, 8.296625, 8.296625,
        8.226125, 8.226125, 7.2916875, 5.4228125, 3.5539377, 1.6850626, 1.6209688, 3.3616562, 5.1023436, 6.843031,
        6.836453, 5.082609, 3.3287654, 1.5749215, 1.5707967, 3.3163905, 5.061984, 6.807578, 7.680375, 7.680375,
        7.935375, 7.935375, 6.8108125, 4.5616875, 2.3125625, 0.06343752, 0.08365631, 2.3732185, 4.6627812, 6.9523435,
        6.9809837, 4.748703, 2.5164216, 0.28414023, 0.15501553, 2.1290464, 4.103078, 6.0771093, 7.064125, 7.064125,
        7.79, 7.79, 6.570375, 4.131125, 1.691875, -0.747375, -0.68500006, 1.8789998, 4.443, 7.0069995,
        7.0532494, 4.58175, 2.1102498, -0.36125016, -0.55287504, 1.5353749, 3.6236248, 5.711875, 6.756, 6.756,
        7.79, 7.79, 6.570375, 4.131125, 1.691875, -0.747375, -0.68500006, 1.8789998, 4.443, 7.0069995,
        7.0532494, 4.58175, 2.1102498, -0.36125016, -0.55287504, 1.5353749, 3.6236248, 5.711875, 6.756, 6.756,
    ];
    let out = resize_bilinear(&grid, 5, 3, 20, 12);
    for (i, (got, want)) in out.iter().zip(expected).enumerate() {
        assert!(
            (got - want).abs() < 1e-5,
            "pixel ({}, {}): {got} vs {want}",
            i / 20,
            i % 20
        );
    }
}

const ROWS: usize = 3;
const COLS: usize = 16;
const DIM: usize = 8;
const SHIFT: usize = 3;

// Descriptor maps with D_R[r, p] = D_L[r, p + 3]: a base map `gen(r, c, j)` over COLS + 3
// columns, the left view its first COLS columns, the right view shifted by 3. Values are
// computed in f64 and rounded to f32, as the Python reference did with math.sin / math.cos.
fn shifted_maps(gen: fn(f64, f64, f64) -> f64) -> (FeatureMap, FeatureMap) {
    let map = |offset: usize| FeatureMap {
        rows: ROWS,
        cols: COLS,
        dim: DIM,
        data: (0..ROWS)
            .flat_map(|r| (0..COLS).flat_map(move |p| (0..DIM).map(move |j| (r, p + offset, j))))
            .map(|(r, c, j)| gen(r as f64, c as f64, j as f64) as f32)
            .collect(),
    };
    (map(0), map(SHIFT))
}

fn generic(r: f64, c: f64, j: f64) -> f64 {
    (1.7 * c + 0.3 * j + 0.5 * r).sin() + 0.5 * (0.45 * c * (j + 1.0) + r).sin()
}

// Pairs of (cos, sin) at four frequencies: the dot product of two columns depends only on their
// distance, so the similarities either side of the true match are equal and the parabola adds 0.
fn stationary(r: f64, c: f64, j: f64) -> f64 {
    let phase = [0.5, 1.1, 1.7, 2.3][j as usize / 2] * c + 0.2 * r;
    if (j as usize).is_multiple_of(2) {
        phase.cos()
    } else {
        phase.sin()
    }
}

// Scores a synthetic prediction against 12 px everywhere, the first 4 pixel columns unlabeled.
fn score_against_shift(tokens: &DisparityMap) -> Metrics {
    let pixels = upsample_disparity(tokens);
    let (w, h) = (pixels.width, pixels.height);
    let gt = GroundTruthMap {
        width: w,
        height: h,
        disparity: vec![12.0; w * h],
        valid: (0..w * h).map(|i| i % w >= 4).collect(),
    };
    score(&pixels, &gt).unwrap()
}

fn assert_close(got: &[f32], want: &[f32]) {
    assert_eq!(got.len(), want.len());
    for (i, (g, w)) in got.iter().zip(want).enumerate() {
        assert!((g - w).abs() < 1e-5, "token ({}, {}): {g} vs {w}", i / COLS, i % COLS);
    }
}

#[test]
fn no_linkage_readout_matches_python_on_generic_descriptors() {
    // probe.wta_subtoken(probe.similarity_volume(dl, dr, 10)) on the same maps.
    #[rustfmt::skip]
    let expected: [f32; ROWS * COLS] = [
        0.0, 0.0, 0.0, 3.0, 3.0014658, 2.97082, 3.0444186, 2.9264271, 3.090592, 2.8825026, 3.1072628, 2.908812,
        3.1474485, 2.8261206, 3.1359003, 2.9042082,
        0.0, 0.0, 0.0, 3.0, 3.1167207, 2.8888185, 3.1011398, 2.9122279, 3.0894556, 2.89948, 3.0661652, 2.9915624,
        2.9432352, 3.1573727, 2.824015, 3.0502574,
        0.0, 0.0, 0.0, 3.0, 3.105873, 2.8746011, 3.0655189, 3.0304513, 2.974518, 3.0025787, 2.987487, 3.0409162,
        2.7398317, 3.3210592, 2.844183, 3.0395954,
    ];
    let (left, right) = shifted_maps(generic);
    let tokens = no_linkage_disparity(&left, &right, DEFAULT_MAX_COLS).unwrap();
    assert_eq!((tokens.width, tokens.height), (COLS, ROWS));
    assert_close(&tokens.values, &expected);
    // probe.score(probe.upsample_disparity(tokens), 12 px, valid[:, :4] = False).
    let m = score_against_shift(&tokens);
    assert!((m.epe - 1.7597893476486206).abs() < 1e-5, "{m:?}");
    assert!((m.bad1tok - 15.0).abs() < 1e-9 && (m.bad2 - 15.0).abs() < 1e-9, "{m:?}");
}

#[test]
fn no_linkage_readout_finds_the_exact_shift() {
    // Python gives exactly 3 patch columns wherever the true match is a candidate (p >= 3); at
    // p = 2 the best remaining candidate is the right view's column 0, at p < 2 candidate 0.
    let (left, right) = shifted_maps(stationary);
    let tokens = no_linkage_disparity(&left, &right, DEFAULT_MAX_COLS).unwrap();
    let row: Vec<f32> = [0.0, 0.0, 2.0].into_iter().chain([3.0; COLS - 3]).collect();
    assert_close(&tokens.values, &row.repeat(ROWS));
    let m = score_against_shift(&tokens);
    assert!((m.epe - 1.0666667222976685).abs() < 1e-5, "{m:?}");
    assert!((m.bad1tok - 10.0).abs() < 1e-9, "{m:?}");
    assert!((m.bad2 - 13.333333333333334).abs() < 1e-9, "{m:?}");
}
