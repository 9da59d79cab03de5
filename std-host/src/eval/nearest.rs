//! Nearest-neighbour resize exactly as OpenCV 5's `INTER_NEAREST_EXACT`, which `resize_gt`
//! uses for ground truth.
//!
//! OpenCV follows Pillow: the source coordinate starts at half a step and grows by
//! `src / dst` in f64 each pixel, truncated. The accumulated rounding sometimes lands just
//! below an exact integer where the rational centre rule `floor((d + 0.5) * src / dst)` of
//! `profile::resize_nearest` would not (Tsukuba's 288 rows -> 120 at w160: row 12 reads source
//! row 29, not 30), so ground truth uses this rule to select the same pixels as the Python.

/// Source index of every destination index along one axis (`src`, `dst` > 0).
pub fn nearest_exact_indices(src: usize, dst: usize) -> Vec<usize> {
    let step = src as f64 / dst as f64;
    let mut position = step * 0.5;
    (0..dst)
        .map(|_| {
            let index = (position.floor() as usize).min(src - 1);
            position += step;
            index
        })
        .collect()
}

/// Resizes a row-major `sw` x `sh` image to `dw` x `dh` by OpenCV's `INTER_NEAREST_EXACT`.
pub fn resize_nearest_exact<T: Copy>(src: &[T], sw: usize, sh: usize, dw: usize, dh: usize) -> Vec<T> {
    assert_eq!(src.len(), sw * sh, "{sw}x{sh} image needs {} values", sw * sh);
    let xs = nearest_exact_indices(sw, dw);
    nearest_exact_indices(sh, dh)
        .into_iter()
        .flat_map(|y| xs.iter().map(move |&x| src[y * sw + x]))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn indices_match_opencv() {
        // cv2.resize(np.arange(s, dtype=np.float32)[None], (n, 1), interpolation=INTER_NEAREST_EXACT)
        // in opencv-python-headless 5.0.0.
        assert_eq!(
            nearest_exact_indices(288, 120)[10..18],
            [25, 27, 29, 32, 34, 37, 39, 41]
        );
        assert_eq!(nearest_exact_indices(370, 265)[78..81], [109, 110, 112]);
        assert_eq!(nearest_exact_indices(2, 5), vec![0, 0, 1, 1, 1]);
        assert_eq!(nearest_exact_indices(6, 3), vec![1, 3, 5]);
        assert_eq!(nearest_exact_indices(2, 4), vec![0, 0, 1, 1]);
    }

    #[test]
    fn resizes_both_axes() {
        let src: Vec<u8> = (0..12).collect();
        assert_eq!(resize_nearest_exact(&src, 4, 3, 2, 1), vec![5, 7]);
    }
}
