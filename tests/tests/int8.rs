//! The int8 engine against the float model (tract) on the test fixture: a blob quantised
//! from the seed-0 random-init encoder, calibrated on train-split bands of ../shared/data.

use std::path::PathBuf;

use bino_core::model::encoder::{arena_bytes, GrayBand};
use bino_core::model::probe::NoProbe;
use bino_core::Error;
use bino_host::compare::head::{compare_heads, FloatHeadRunner, HeadAgreement};
use bino_host::data::profile::Profile;
use bino_host::data::synthetic;
use bino_host::float::reference::ReferenceEncoder;
use bino_host::int8::{dequantise_residual, Int8Model, StageRecorder};
use bino_host::quantize::{quantize, QuantizeOptions};
use bino_tests::{available, fixtures};

fn data_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data")
}

/// Quantising the fixture encoder (calibrated on two train pairs) with the shared head and,
/// when given, the native head.
fn fixture_options(native_head: Option<PathBuf>) -> QuantizeOptions {
    QuantizeOptions {
        encoder: fixtures().join("encoder_random_seed0.onnx"),
        data: data_dir(),
        profile: Profile::W160,
        calib_pairs: 2,
        max_width: 160,
        head: Some(fixtures().join("head_random_seed0.onnx")),
        native_head,
        head_calib_pairs: 2,
        head_calib_nuisances: Vec::new(),
    }
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
    if !available(
        &format!("calibration data at {}", data_dir().display()),
        data_dir().join("PAIRS.tsv").is_file(),
    ) {
        return;
    }
    let onnx = fixtures().join("encoder_random_seed0.onnx");
    let opts = fixture_options(None);
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

    // The head end to end: int8 descriptors -> int8 head versus float -> float.
    let right = Profile::W160.apply(&scene.right).unwrap();
    let (rows, cols, codes_left) = model.descriptor_codes(&view).unwrap();
    let (_, _, codes_right) = model.descriptor_codes(&right).unwrap();
    let head = model.head(&codes_left, &codes_right, rows, cols).unwrap();
    let float_right = float.descriptors(&right).unwrap();
    let mut float_head = FloatHeadRunner::load(&fixtures().join("head_random_seed0.onnx")).unwrap();
    let float_out = float_head.run(&expected, &float_right).unwrap();
    let HeadAgreement {
        logit_cosine: logit_cos,
        disparity_mean_abs: mean_abs,
    } = compare_heads(&head, &float_out).unwrap();
    eprintln!("head: logit cosine {logit_cos:.5}, mean |disparity int8 - float| {mean_abs:.4} patch columns");
    assert!(logit_cos >= 0.98, "head logits cosine {logit_cos}");
    assert!(
        mean_abs <= 0.25,
        "head disparity differs by {mean_abs} patch columns on average"
    );

    // Bad input is an error value, never a panic, and names the problem.
    let encoder = model.encoder().unwrap();
    let pixels = vec![128u8; 160 * 48];
    let band = GrayBand::new(&pixels, 160, 48).unwrap();
    let needed = arena_bytes(48, 160);
    let mut small = vec![0u8; needed - 1];
    let mut out = vec![0i8; 12 * 40 * 128];
    let err = encoder.describe(band, &mut small, &mut out, &mut NoProbe).unwrap_err();
    assert_eq!(
        err,
        Error::ArenaTooSmall {
            needed,
            available: needed - 1
        }
    );
    let mut arena = vec![0u8; needed];
    let report = encoder.describe(band, &mut arena, &mut out, &mut NoProbe).unwrap();
    // Everything but unused alignment slack is used: the const fn is tight.
    assert!(
        report.arena_used <= needed && report.arena_used + 8 >= needed,
        "{report:?} vs {needed}"
    );
    assert!(matches!(
        encoder.describe(band, &mut arena, &mut out[1..], &mut NoProbe),
        Err(Error::BufferSize { .. })
    ));
    assert!(matches!(GrayBand::new(&pixels, 160, 44), Err(Error::BufferSize { .. })));
    assert!(matches!(
        GrayBand::new(&vec![0u8; 160 * 52], 160, 52),
        Err(Error::BandTooTall { .. })
    ));
    let wide = vec![0u8; 164 * 48];
    let too_wide = GrayBand::new(&wide, 164, 48).unwrap();
    let mut big_arena = vec![0u8; arena_bytes(48, 164)];
    let mut wide_out = vec![0i8; 12 * 41 * 128];
    assert!(matches!(
        encoder.describe(too_wide, &mut big_arena, &mut wide_out, &mut NoProbe),
        Err(Error::TooWide { width: 164, max: 160 })
    ));
}

/// The native pathway (issue 15): one encoder pass on the pair, its de-positioned fused grid in
/// descriptor codes, and the native head on it, against the float encoder and head (tract).
#[test]
fn int8_native_pathway_follows_float() {
    use bino_core::model::head::{arena_bytes_for, HeadRow, HeadSink, HeadStream, HeadWeights};
    use bino_core::model::ids::HeadKind;

    if !available(
        &format!("calibration data at {}", data_dir().display()),
        data_dir().join("PAIRS.tsv").is_file(),
    ) {
        return;
    }
    let onnx = fixtures().join("encoder_random_seed0.onnx");
    let native_onnx = fixtures().join("native_head_random_seed0.onnx");
    let opts = fixture_options(Some(native_onnx.clone()));
    let (blob, report) = quantize(&opts, |_, _| {}).unwrap();
    assert!(report.head_choice.is_some() && report.native_head_choice.is_some());
    let model = Int8Model::from_bytes(blob, "fixture blob").unwrap();
    assert!(model.has_head_of(HeadKind::Export) && model.has_head_of(HeadKind::Native));
    let scene = synthetic::default_scene(160, 48);
    let left = Profile::W160.apply(&scene.left).unwrap();
    let right = Profile::W160.apply(&scene.right).unwrap();

    // The fused grid of one pass on (L, R), de-positioned, against the float reference's.
    let tokens = model.pair_tokens(&left, &right).unwrap();
    let mut float = ReferenceEncoder::load(&onnx).unwrap();
    let expected = float.tokens(&left, &right).unwrap();
    assert_eq!((tokens.rows, tokens.cols), (expected.rows, expected.cols));
    let token_cos = mean_cosine(&tokens.data, &expected.data, 128);
    eprintln!("pair tokens: mean cosine {token_cos:.5}");
    assert!(token_cos >= 0.99, "int8 pair tokens cosine {token_cos}");

    // The native head end to end: int8 tokens -> int8 head versus float -> float.
    let (rows, cols, codes) = model.pair_token_codes(&left, &right).unwrap();
    let head = model.native_head(&codes, rows, cols).unwrap();
    let (even, odd) = expected.phase_maps();
    let float_out = FloatHeadRunner::load(&native_onnx).unwrap().run(&even, &odd).unwrap();
    let HeadAgreement {
        logit_cosine,
        disparity_mean_abs,
    } = compare_heads(&head, &float_out).unwrap();
    eprintln!("native head: logit cosine {logit_cosine:.5}, mean |disparity int8 - float| {disparity_mean_abs:.4}");
    assert!(logit_cosine >= 0.98, "native head logits cosine {logit_cosine}");
    assert!(
        disparity_mean_abs <= 0.25,
        "native head disparity differs by {disparity_mean_abs}"
    );

    // `bino compare --native-head` on an eval pair: the same agreement through the CLI's code.
    let blob_path = std::env::temp_dir().join(format!("bino-native-{}.bin", std::process::id()));
    std::fs::write(&blob_path, model.bytes()).unwrap();
    let compared = bino_host::compare::compare(
        &bino_host::compare::CompareOptions {
            onnx: onnx.clone(),
            blob: blob_path.clone(),
            head: None,
            native_head: Some(native_onnx.clone()),
            data: data_dir(),
            split: "eval".into(),
            profile: Profile::W160,
            max_cols: 10,
            limit: Some(1),
            nuisance: None,
        },
        |_, _, _| {},
    );
    std::fs::remove_file(&blob_path).unwrap();
    let native = compared.unwrap().mean.native.expect("the native pathway was compared");
    eprintln!(
        "compare --native-head, first eval pair: pair token cosine {:.5}, logit cosine {:.5}",
        native.pair_token_cosine, native.head.logit_cosine
    );
    assert!(
        native.pair_token_cosine >= 0.99 && native.head.logit_cosine >= 0.98,
        "{native:?}"
    );

    // In place (what a pipeline keeps in its arena) equals the copy, code for code; on (I, I)
    // the mean of a cell's two phase codes is its descriptor code, up to rounding.
    let encoder = model.encoder().unwrap();
    let pixels = bino_host::int8::to_u8(&left.pixels);
    let band = GrayBand::new(&pixels, 160, 48).unwrap();
    let mut arena = vec![0u8; arena_bytes(48, 160)];
    let mut copied = vec![0i8; 12 * 80 * 128];
    encoder
        .pair_tokens(band, band, &mut arena, &mut copied, &mut NoProbe)
        .unwrap();
    let (_, len) = encoder
        .pair_tokens_in_place(band, band, &mut arena, &mut NoProbe)
        .unwrap();
    let in_place: Vec<i8> = arena[..len].iter().map(|&b| b as i8).collect();
    assert_eq!(in_place, copied);
    let mut desc = vec![0i8; 12 * 40 * 128];
    encoder.describe(band, &mut arena, &mut desc, &mut NoProbe).unwrap();
    for (cell, d) in copied.chunks_exact(256).zip(desc.chunks_exact(128)) {
        for c in 0..128 {
            let mean = (cell[c] as i32 + cell[128 + c] as i32) as f64 / 2.0;
            assert!(
                (mean - d[c] as f64).abs() <= 1.0,
                "descriptor {} vs phase mean {mean}",
                d[c]
            );
        }
    }

    // Bad input: each head takes only its own pathway's rows, and a blob without the native
    // head says how to add one.
    struct Ignore;
    impl HeadSink for Ignore {
        fn row(&mut self, _: HeadRow<'_>) {}
    }
    let weights = HeadWeights::for_kind(model.blob().unwrap(), HeadKind::Native).unwrap();
    let mut head_arena = vec![0u8; arena_bytes_for(HeadKind::Native, 40)];
    let mut stream = HeadStream::new(weights, 40, &mut head_arena).unwrap();
    let row = vec![0i8; 40 * 128];
    assert_eq!(
        stream.push_row(&row, &row, &mut Ignore).unwrap_err(),
        Error::PathwayMismatch {
            head: "native",
            input: "export"
        }
    );
    assert!(matches!(
        stream.push_pair_row(&row, &mut Ignore),
        Err(Error::BufferSize { .. })
    ));
    let (blob, _) = quantize(&fixture_options(None), |_, _| {}).unwrap();
    let model = Int8Model::from_bytes(blob, "export-only blob").unwrap();
    assert!(!model.has_head_of(HeadKind::Native));
    let err = model.native_head(&codes, rows, cols).unwrap_err();
    assert!(format!("{err:#}").contains("quantise with --native-head"), "{err:#}");
}

#[test]
fn head_calibration_adds_each_pair_again_per_nuisance_with_only_its_right_view_changed() {
    use bino_core::model::ids::HeadKind;
    use bino_host::data::nuisance::Nuisance;
    use bino_host::quantize::head::calibration_maps;
    if !available(
        &format!("calibration data at {}", data_dir().display()),
        data_dir().join("PAIRS.tsv").is_file(),
    ) {
        return;
    }
    let onnx = fixtures().join("encoder_random_seed0.onnx");
    let maps = |nuisances: &[Nuisance]| {
        calibration_maps(&onnx, HeadKind::Export, &data_dir(), Profile::W160, 2, nuisances).unwrap()
    };
    let clean = maps(&[]);
    let degraded = maps(&[Nuisance::Blur, Nuisance::Noise]);
    assert_eq!(degraded.len(), 3 * clean.len());
    for (pair, group) in clean.iter().zip(degraded.chunks(3)) {
        assert_eq!(group[0].0.data, pair.0.data);
        assert_eq!(group[0].1.data, pair.1.data);
        for (left, right) in &group[1..] {
            assert_eq!(left.data, pair.0.data, "the left view is never degraded");
            assert_ne!(right.data, pair.1.data, "the right view is");
        }
    }
}

#[test]
fn compare_under_a_nuisance_degrades_the_right_views_and_says_so() {
    use bino_host::compare::{compare, CompareOptions};
    use bino_host::data::nuisance::Nuisance;
    if !available(
        &format!("data at {}", data_dir().display()),
        data_dir().join("PAIRS.tsv").is_file(),
    ) {
        return;
    }
    let (blob, _) = quantize(&fixture_options(None), |_, _| {}).unwrap();
    let blob_path = std::env::temp_dir().join(format!("bino-nuisance-{}.bin", std::process::id()));
    std::fs::write(&blob_path, &blob).unwrap();
    let run = |nuisance| {
        let opts = CompareOptions {
            onnx: fixtures().join("encoder_random_seed0.onnx"),
            blob: blob_path.clone(),
            head: None,
            native_head: None,
            data: data_dir(),
            split: "eval".into(),
            profile: Profile::W160,
            max_cols: 10,
            limit: Some(1),
            nuisance,
        };
        compare(&opts, |_, _, _| {}).unwrap()
    };
    let (clean, blurred) = (run(None), run(Some(Nuisance::Blur)));
    std::fs::remove_file(&blob_path).unwrap();
    assert_ne!(clean.mean.float.epe, blurred.mean.float.epe);
    assert!(blurred.table().contains("right views under blur"));
    assert!(blurred.to_json().contains("\"nuisance\": \"blur\""));
    assert!(!clean.to_json().contains("\"nuisance\""));
}
