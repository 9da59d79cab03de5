//! tract-onnx runs the exported encoder as PyTorch does: the fixture written by
//! `python -m bino_train.export --intermediates --fixture tests/fixtures/parity` holds an input
//! pair and the PyTorch outputs; tract must reproduce them within 1e-4.

use bino_host::float::reference::ReferenceEncoder;
use bino_tests::{fixtures, read_npy, view_from_nchw};

const TOLERANCE: f32 = 1e-4;

fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

fn check_stage(stage: &str) {
    let dir = fixtures().join("parity");
    let left = view_from_nchw(&read_npy(&dir.join("left.npy")).unwrap()).unwrap();
    let right = view_from_nchw(&read_npy(&dir.join("right.npy")).unwrap()).unwrap();
    let expected = read_npy(&dir.join(format!("{stage}.npy"))).unwrap();
    let onnx = fixtures().join("encoder_random_seed0.onnx");
    let mut encoder = ReferenceEncoder::load_stage(&onnx, stage).unwrap();
    let got = encoder.tokens(&left, &right).unwrap();
    assert_eq!(expected.shape, [1, got.rows, got.cols, 128]);
    let diff = max_abs_diff(&got.data, &expected.data);
    let scale = expected.data.iter().fold(0.0f32, |m, v| m.max(v.abs()));
    assert!(scale > 0.1, "fixture {stage} is degenerate (max |value| {scale})");
    eprintln!(
        "{stage}: max abs(tract - pytorch) = {diff:.3e} over {} values",
        got.data.len()
    );
    assert!(
        diff <= TOLERANCE,
        "{stage}: tract differs from PyTorch by {diff} (> {TOLERANCE})"
    );
}

#[test]
fn tokens_match_pytorch() {
    check_stage("tokens");
}

#[test]
fn patch_embedding_matches_pytorch() {
    check_stage("embed");
}

#[test]
fn swapping_the_views_changes_the_tokens() {
    // Guards against a wiring slip (e.g. both inputs bound to `left`), which the parity
    // fixture alone could miss for a symmetric pair.
    let dir = fixtures().join("parity");
    let left = view_from_nchw(&read_npy(&dir.join("left.npy")).unwrap()).unwrap();
    let right = view_from_nchw(&read_npy(&dir.join("right.npy")).unwrap()).unwrap();
    let mut encoder = ReferenceEncoder::load(&fixtures().join("encoder_random_seed0.onnx")).unwrap();
    let forward = encoder.tokens(&left, &right).unwrap();
    let swapped = encoder.tokens(&right, &left).unwrap();
    assert!(max_abs_diff(&forward.data, &swapped.data) > 1e-2);
}

#[test]
fn missing_stage_and_missing_file_are_errors() {
    let onnx = fixtures().join("encoder_random_seed0.onnx");
    let err = ReferenceEncoder::load_stage(&onnx, "block99")
        .err()
        .expect("no such output");
    assert!(format!("{err:#}").contains("block99"));
    let err = ReferenceEncoder::load(&fixtures().join("nope.onnx"))
        .err()
        .expect("missing file");
    assert!(format!("{err:#}").contains("nope.onnx"));
}
