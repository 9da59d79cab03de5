use bino_core::config::DIM;

use super::comparer::split_bands;
use super::*;

fn metrics(epe: f64) -> Metrics {
    Metrics {
        epe,
        bad1tok: 10.0,
        bad2: 20.0,
        density: 100.0,
    }
}

#[test]
fn mean_is_unweighted_and_keeps_the_head_only_when_complete() {
    let a = Comparison {
        stage_cosine: vec![1.0; STAGE_COUNT],
        descriptor_cosine: 1.0,
        wta_agreement: 100.0,
        wta_flip_loss: 0.0,
        wta_top2_gap: 0.1,
        float: metrics(2.0),
        int8: metrics(2.0),
        float_ref: metrics(1.0),
        int8_ref: metrics(1.0),
        head: Some(HeadComparison {
            logit_cosine: 1.0,
            disparity_mean_abs: 0.0,
            float: metrics(1.0),
            int8: metrics(1.5),
            float_ref: metrics(0.5),
            int8_ref: metrics(0.75),
        }),
        native: None,
    };
    let a = Comparison {
        native: Some(NativeComparison {
            pair_token_cosine: 0.9,
            head: a.head.unwrap(),
        }),
        ..a
    };
    let b = Comparison {
        stage_cosine: vec![0.5; STAGE_COUNT],
        descriptor_cosine: 0.5,
        wta_agreement: 50.0,
        int8: metrics(3.0),
        int8_ref: metrics(2.0),
        ..a.clone()
    };
    let m = Comparison::mean([&a, &b]).unwrap();
    assert_eq!(m.stage_cosine, vec![0.75; STAGE_COUNT]);
    assert_eq!((m.descriptor_cosine, m.wta_agreement), (0.75, 75.0));
    assert_eq!((m.float.epe, m.int8.epe), (2.0, 2.5));
    assert_eq!(m.epe_change_pct(), 25.0);
    assert_eq!((m.float_ref.epe, m.int8_ref.epe), (1.0, 1.5));
    assert_eq!(m.head.map(|h| h.epe_change_pct()), Some(50.0));
    let native = m.native.expect("both pairs have the native pathway");
    assert_eq!((native.pair_token_cosine, native.head.epe_change_pct()), (0.9, 50.0));
    let c = Comparison {
        head: None,
        native: None,
        ..b
    };
    let partial = Comparison::mean([&a, &c]).unwrap();
    assert!(partial.head.is_none() && partial.native.is_none());
    assert!(Comparison::mean([]).is_err());
}

#[test]
fn split_bands_needs_every_stage_once_per_band() {
    let stage = |s: usize| (stages::stage_of_format(s), 1, 2, vec![s as i8; 2 * DIM]);
    let band: Vec<_> = (0..STAGE_COUNT).map(stage).collect();
    let two = [band.clone(), band.clone()].concat();
    let bands = split_bands(two).unwrap();
    assert_eq!(bands.len(), 2);
    assert_eq!(bands[1][3][0], 3);
    assert!(split_bands(band[..STAGE_COUNT - 1].to_vec()).is_err());
    assert!(split_bands(band[1..].to_vec()).is_err());
}
