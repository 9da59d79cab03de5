use super::refine::GrayViews;
use super::*;
use crate::eval::upsample_disparity;

#[test]
fn the_grid_fusion_is_fuse_row_per_row_and_checks_its_sizes() {
    let (head, sgm) = ([256u16, 512, 768, 1024], [512u16, 512, 256, 0]);
    let (head_kept, sgm_kept, confidence) = ([1u8, 0, 1, 0], [1u8, 1, 0, 0], [128u16; 4]);
    let (out, kept) = fuse_grid((&head, &head_kept), &confidence, (&sgm, &sgm_kept), 2, 128).unwrap();
    assert_eq!((out, kept), (vec![384, 512, 768, 1024], vec![1, 1, 1, 0]));
    assert!(fuse_grid((&head, &head_kept), &confidence, (&sgm, &sgm_kept), 3, 128).is_err());
    let short = &confidence[..3];
    assert!(fuse_grid((&head, &head_kept), short, (&sgm, &sgm_kept), 2, 128).is_err());
}

#[test]
fn names_round_trip_and_unknown_ones_are_errors() {
    for r in Readout::ALL {
        assert_eq!(r.name().parse::<Readout>().unwrap(), r);
        assert_eq!(r.to_string(), r.name());
    }
    let names: std::collections::BTreeSet<_> = Readout::ALL.iter().map(|r| r.name()).collect();
    assert_eq!(names.len(), 28, "distinct names");
    assert_eq!("head+lr".parse::<Readout>().unwrap(), Readout::HEAD_LR);
    assert_eq!(
        "head+lr+ref".parse::<Readout>().unwrap(),
        Readout::HEAD_LR.refined(true)
    );
    assert_eq!(Readout::ALL[1], Readout::NOLINK.refined(true), "each then its +ref");
    for bad in ["head+LR", "head+ref+lr", "ref", "sgm+ref+ref"] {
        let err = format!("{:#}", bad.parse::<Readout>().unwrap_err());
        assert!(err.contains("optionally with +lr, then optionally +ref"), "{err}");
    }
}

fn views(width: usize, height: usize) -> GrayViews {
    let left: Vec<u8> = (0..width * height)
        .map(|i| ((i * 97 + i / width * 31) % 251) as u8)
        .collect();
    let right = (0..width * height)
        .map(|i| left[(i / width) * width + (i % width + 5).min(width - 1)])
        .collect();
    GrayViews {
        width,
        height,
        left,
        right,
    }
}

/// The host's fill at the token grid is the core's integer `lr::fill_rejected`, value for
/// value (a copy of kept values, so exact in any precision).
#[test]
fn the_fill_is_the_cores() {
    let q8: Vec<u16> = (0..24).map(|i| (i * 37 % 11) as u16 * 64).collect();
    let mask: Vec<u8> = (0..24).map(|i| u8::from(i % 3 == 1 || i % 7 == 0)).collect();
    let map = DisparityMap {
        width: 8,
        height: 3,
        values: q8.iter().map(|&d| d as f32 / 256.0).collect(),
    };
    let maps = MethodMaps {
        nolink: Some(map.clone()),
        sgm: Some(map.clone()),
        head: None,
        nolink_consistent: mask.iter().map(|&m| m != 0).collect(),
        sgm_consistent: vec![true; 24],
        head_consistent: None,
        head_confidence: None,
        views: views(32, 12),
        census: Default::default(),
    };
    let host = maps.tokens(Readout::new(Method::Nolink, true)).unwrap();
    let mut core = q8.clone();
    for (row, m) in core.chunks_exact_mut(8).zip(mask.chunks_exact(8)) {
        bino_core::lr::fill_rejected(row, m).unwrap();
    }
    let core: Vec<f32> = core.iter().map(|&d| d as f32 / 256.0).collect();
    assert_eq!(host.values, core);
    assert!(maps.tokens(Readout::HEAD).is_err(), "no head in this run");
}

/// A `+ref` readout's pixels are the core's whole-map refinement (equalised:
/// `refine_map_equalised`) of the readout's token grid (after the fill) in Q8 on the views,
/// with `+lr` the rejected cells' pixels kept at the bilinear step (`keep_rejected_map`),
/// Q8 px / 256; without `+ref` the bilinear upsampling.
#[test]
fn the_refined_pixels_are_the_cores_equalised_whole_map() {
    use bino_core::refine::sharpness::refine_map_equalised;
    use bino_core::refine::{keep_rejected_map, scratch_len, RefineParams};
    let q8: Vec<u16> = (0..24).map(|i| 250 + (i * 37 % 11) as u16 * 9).collect();
    let mask: Vec<bool> = (0..24).map(|i| i % 5 != 2).collect();
    let map = DisparityMap {
        width: 8,
        height: 3,
        values: q8.iter().map(|&d| d as f32 / 256.0).collect(),
    };
    let maps = MethodMaps {
        nolink: Some(map.clone()),
        sgm: Some(map.clone()),
        head: Some(map.clone()),
        nolink_consistent: mask.clone(),
        sgm_consistent: mask.clone(),
        head_consistent: Some(mask.clone()),
        head_confidence: Some((0..24).map(|i| (i * 23 % 256) as u16).collect()),
        views: views(32, 12),
        census: Default::default(),
    };
    let v = &maps.views;
    // The census readouts' grids come from the views, not from `q8` (their own test).
    let from_q8 = Readout::ALL
        .into_iter()
        .filter(|r| !matches!(r.method, Method::Census | Method::CensusFused | Method::FusedAll));
    for readout in from_q8 {
        let pixels = maps.pixels(readout).unwrap();
        assert_eq!((pixels.width, pixels.height), (32, 12), "{readout}");
        let tokens = maps.tokens(readout).unwrap();
        if !readout.refine {
            assert_eq!(pixels, upsample_disparity(&tokens), "{readout}");
            continue;
        }
        let mut grid = q8.clone();
        if readout.lr {
            let m: Vec<u8> = mask.iter().map(|&k| u8::from(k)).collect();
            for (row, m) in grid.chunks_exact_mut(8).zip(m.chunks_exact(8)) {
                bino_core::lr::fill_rejected(row, m).unwrap();
            }
        }
        let params = RefineParams::for_width(32);
        let mut scratch = vec![0u32; scratch_len(32, &params)];
        let mut out = vec![0u16; 32 * 12];
        refine_map_equalised(&v.left, &v.right, 32, &grid, &params, &mut scratch, &mut out).unwrap();
        if readout.lr {
            let m: Vec<u8> = mask.iter().map(|&k| u8::from(k)).collect();
            keep_rejected_map(32, &grid, &m, &mut out).unwrap();
        }
        let core: Vec<f32> = out.iter().map(|&d| d as f32 / 256.0).collect();
        assert_eq!(pixels.values, core, "{readout}");
    }
    let refined = maps.pixels(Readout::SGM.refined(true)).unwrap();
    assert!(
        refined.values.iter().filter(|&&d| (d - 5.0).abs() < 0.25).count() > 32 * 12 / 2,
        "the refinement finds the views' 5 px shift"
    );
}

/// The rule `train/bino_train/head.py::head_candidates` repeats (its test pins the same
/// values): SGBM's range at the width, never below the trained 12, at most the limit.
#[test]
fn head_candidates_follow_the_sgbm_range_of_the_width() {
    let counts: Vec<usize> = [32, 160, 320, 400, 4000].into_iter().map(head_candidates).collect();
    assert_eq!(counts, [12, 12, 16, 20, 64]);
}

/// One readout, one fill: every `+lr` readout the core streams fills as the core's refinement
/// input does (census readouts from the background, the others from the left).
#[test]
fn each_readouts_fill_is_the_cores() {
    use crate::int8::pipeline_maps::streamed_input;
    use crate::readout::pathway::Pathway;
    let mut backgrounds = 0;
    for readout in Readout::ALL.into_iter().filter(|r| r.lr) {
        for pathway in [Pathway::Export, Pathway::Native] {
            if let Some(input) = streamed_input(readout, pathway) {
                assert_eq!(readout.method.fill(), input.fill(), "{readout} on {pathway:?}");
                backgrounds += usize::from(input.fill() == Fill::Background);
            }
        }
    }
    assert!(backgrounds > 0, "the census readouts fill from the background");
}
