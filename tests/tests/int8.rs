//! The int8 engine against the float model (tract) on the test fixture: a blob quantised
//! from the seed-0 random-init encoder, calibrated on train-split bands of ../shared/data.

use std::path::PathBuf;

use bino_host::int8::{dequantise_residual, Int8Model, StageRecorder};
use bino_host::profile::Profile;
use bino_host::quantize::{quantize, QuantizeOptions};
use bino_host::reference::ReferenceEncoder;
use bino_host::synthetic;
use bino_tests::fixtures;

fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data")
}

fn cosine(a: &[f32], b: &[f32]) -> f64 {
    let dot: f64 = a.iter().zip(b).map(|(x, y)| *x as f64 * *y as f64).sum();
    let na: f64 = a.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt();
    let nb: f64 = b.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt();
    dot / (na * nb).max(1e-30)
}

fn mean_cosine(a: &[f32], b: &[f32], dim: usize) -> f64 {
    let pairs: Vec<f64> = a.chunks(dim).zip(b.chunks(dim)).map(|(x, y)| cosine(x, y)).collect();
    pairs.iter().sum::<f64>() / pairs.len() as f64
}

#[test]
fn int8_descriptors_follow_float() {
    if !data_dir().join("PAIRS.tsv").is_file() {
        eprintln!("skipped: no calibration data at {}", data_dir().display());
        return;
    }
    let onnx = fixtures().join("encoder_random_seed0.onnx");
    let opts = QuantizeOptions {
        encoder: onnx.clone(),
        data: data_dir(),
        profile: Profile::W160,
        calib_pairs: 2,
        max_width: 160,
    };
    let (blob, _) = quantize(&opts, |_, _| {}).unwrap();
    let model = Int8Model::from_bytes(blob, "fixture blob").unwrap();
    let scene = synthetic::default_scene(160, 48);
    let view = Profile::W160.apply(&scene.left).unwrap();

    let mut recorder = StageRecorder::default();
    let (_, _, _) = model.descriptor_codes_probed(&view, &mut recorder).unwrap();
    let int8 = model.descriptors(&view).unwrap();
    let mut float = ReferenceEncoder::load(&onnx).unwrap();
    let expected = float.descriptors(&view).unwrap();
    let desc_cos = mean_cosine(&int8.data, &expected.data, 128);

    for (stage, _, _, codes) in &recorder.stages {
        let (scale, zero) = model.residual_format(stage.residual_format()).unwrap();
        let name = match stage {
            bino_core::model::probe::Stage::Embed => "embed".to_string(),
            bino_core::model::probe::Stage::Block(b) => format!("block{b}"),
            bino_core::model::probe::Stage::Attention(_) => continue,
        };
        let mut reference = ReferenceEncoder::load_stage(&onnx, &name).unwrap();
        let want = reference.tokens(&view, &view).unwrap();
        let got = dequantise_residual(codes, &scale, &zero);
        eprintln!("{name}: mean token cosine {:.5}", mean_cosine(&got, &want.data, 128));
    }
    eprintln!("descriptors: mean cosine {desc_cos:.5}");
    assert!(desc_cos >= 0.99, "int8 descriptors cosine {desc_cos}");
}
