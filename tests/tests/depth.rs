//! `bino_core::depth` against a plain f64 reference: depth in mm from Q8 disparities at a
//! profile's scale, the nearest depth and bearing per column sector, and no panic on any input.

use bino_core::depth::{Calibration, DepthModel, DisparityUnit, SectorSummary};
use bino_core::testutil::Rng;
use bino_core::Error;

/// A 640-px sensor with a 60 mm baseline, the firmware's example calibration.
const CAL: Calibration = Calibration {
    focal_px: 500.0,
    principal_x_px: 318.5,
    baseline_mm: 60.0,
    sensor_width_px: 640,
};

/// The f64 reference: depth_mm = f * B / (d_q8 / 256 * unit_px * sensor_width / profile_width).
fn reference_mm(cal: &Calibration, profile_width: usize, unit_px: usize, q8: u16) -> Option<f64> {
    if q8 == 0 || q8 == u16::MAX {
        return None;
    }
    let scale = cal.sensor_width_px as f64 / profile_width as f64;
    let d_px = q8 as f64 / 256.0 * unit_px as f64 * scale;
    Some(cal.focal_px as f64 * cal.baseline_mm as f64 / d_px)
}

fn reference_bearing(cal: &Calibration, profile_width: usize, x_profile_px: f64) -> f64 {
    let scale = cal.sensor_width_px as f64 / profile_width as f64;
    ((x_profile_px * scale - cal.principal_x_px as f64) / cal.focal_px as f64).atan()
}

#[test]
fn depth_matches_the_f64_reference_for_every_q8_value() {
    for (profile, unit) in [
        (160, DisparityUnit::Pixels),
        (160, DisparityUnit::PatchColumns),
        (320, DisparityUnit::Pixels),
    ] {
        let model = DepthModel::new(&CAL, profile, unit).unwrap();
        assert_eq!(model.scale(), 640.0 / profile as f32);
        for q8 in 0..=u16::MAX {
            let got = model.depth_mm(q8);
            match reference_mm(&CAL, profile, unit.pixels(), q8) {
                None => assert_eq!(got, None, "q8 {q8}: found {got:?}, expected no depth"),
                Some(want) => {
                    let got = got.unwrap_or_else(|| panic!("q8 {q8}: no depth, expected {want:.3} mm"));
                    // Rounded to the nearest mm from a numerator computed in f32 (relative
                    // error below 1e-7).
                    assert!(
                        (got as f64 - want).abs() <= 0.5 + want * 1e-6 + 1e-5,
                        "profile {profile} {unit:?} q8 {q8}: found {got} mm, expected {want:.3}"
                    );
                }
            }
        }
    }
}

#[test]
fn a_w160_profile_of_a_640_px_sensor_has_scale_4() {
    let model = DepthModel::new(&CAL, 160, DisparityUnit::Pixels).unwrap();
    // 10 px at w160 are 40 px of the sensor: 500 * 60 / 40 = 750 mm.
    assert_eq!(model.depth_mm(10 << 8), Some(750));
    // The same disparity in patch columns is 4x as many pixels: a quarter of the depth.
    let cols = DepthModel::new(&CAL, 160, DisparityUnit::PatchColumns).unwrap();
    assert_eq!(cols.depth_mm(10 << 8), Some(188)); // 187.5 rounds up
}

#[test]
fn sectors_hold_the_nearest_kept_depth_and_the_bearing_of_their_centre() {
    let model = DepthModel::new(&CAL, 160, DisparityUnit::PatchColumns).unwrap();
    let cols = 40;
    let mut summary = SectorSummary::<6>::new(&model, cols).unwrap();
    let mut rng = Rng::new(0x9E37_79B9_7F4A_7C15);
    let mut want: [Option<(f64, usize)>; 6] = [None; 6];
    for row in 0..12 {
        let d: Vec<u16> = (0..cols)
            .map(|_| match rng.next_u64() % 10 {
                0 => 0,
                1 => u16::MAX,
                _ => (rng.next_u64() % 4096) as u16,
            })
            .collect();
        let keep: Vec<u8> = (0..cols).map(|_| u8::from(!rng.next_u64().is_multiple_of(4))).collect();
        summary.push_row(&d, Some(&keep)).unwrap();
        for (c, (&q8, &k)) in d.iter().zip(&keep).enumerate() {
            // Sector i holds columns [i * cols / 6, (i + 1) * cols / 6).
            let s = (0..6)
                .find(|&i| (i * cols / 6..(i + 1) * cols / 6).contains(&c))
                .unwrap();
            if let (1.., Some(mm)) = (k, reference_mm(&CAL, 160, 4, q8)) {
                if want[s].is_none_or(|(n, _)| mm < n) {
                    want[s] = Some((mm, row));
                }
            }
        }
    }
    assert_eq!(summary.rows(), 12);
    for (i, (s, w)) in summary.sectors().iter().zip(&want).enumerate() {
        assert_eq!(
            (s.first_col as usize, s.end_col as usize),
            (i * cols / 6, (i + 1) * cols / 6)
        );
        match (s.nearest_mm, w) {
            (Some(got), Some((mm, row))) => {
                assert!(
                    (got as f64 - mm).abs() <= 0.5 + mm * 1e-6 + 1e-5,
                    "sector {i}: found {got} mm, expected {mm:.3}"
                );
                assert_eq!(s.nearest_row as usize, *row, "sector {i}: row of the nearest depth");
            }
            (got, w) => assert_eq!(got.is_some(), w.is_some(), "sector {i}: found {got:?}, expected {w:?}"),
        }
        // The centre column in profile px (4 px per patch column).
        let centre = (s.first_col + s.end_col) as f64 * 0.5 * 4.0;
        let b = reference_bearing(&CAL, 160, centre);
        // micromath's atan: within 0.16 degrees.
        assert!(
            (s.bearing_rad as f64 - b).abs() <= 0.003,
            "sector {i}: bearing {} vs {b}",
            s.bearing_rad
        );
    }
    // Sectors left of the principal point look left, right of it right.
    assert!(summary.sectors()[0].bearing_rad < 0.0 && summary.sectors()[5].bearing_rad > 0.0);
    // The nearest sector is the first whose depth, in whole mm, is least (several sectors can
    // round to the same mm, so the f64 reference's nearest may be another of them).
    let least = summary.sectors().iter().filter_map(|s| s.nearest_mm).min();
    let first = summary
        .sectors()
        .iter()
        .position(|s| s.nearest_mm.is_some() && s.nearest_mm == least);
    assert_eq!(summary.nearest(), first.zip(least));
    let reference = want.iter().filter_map(|w| w.map(|(mm, _)| mm)).min_by(f64::total_cmp);
    match (least, reference) {
        (Some(got), Some(mm)) => assert!(
            (got as f64 - mm).abs() <= 0.5 + mm * 1e-6 + 1e-5,
            "nearest: found {got} mm, expected {mm:.3}"
        ),
        (got, mm) => assert_eq!(got.is_some(), mm.is_some(), "nearest: found {got:?}, expected {mm:?}"),
    }
}

#[test]
fn no_depth_rows_leave_sectors_empty() {
    let model = DepthModel::new(&CAL, 160, DisparityUnit::Pixels).unwrap();
    let mut summary = SectorSummary::<4>::new(&model, 160).unwrap();
    summary.push_row(&[0; 160], None).unwrap();
    summary.push_row(&[u16::MAX; 160], None).unwrap();
    summary.push_row(&[300; 160], Some(&[0; 160])).unwrap();
    assert!(summary.sectors().iter().all(|s| s.nearest_mm.is_none() && s.cells == 0));
    assert_eq!(summary.nearest(), None);
}

#[test]
fn bad_calibrations_and_rows_are_errors_naming_the_value() {
    let bad = |c: Calibration, profile: usize| DepthModel::new(&c, profile, DisparityUnit::Pixels).unwrap_err();
    for (cal, what) in [
        (Calibration { focal_px: 0.0, ..CAL }, "focal length (px)"),
        (Calibration { focal_px: 0.5, ..CAL }, "focal length (px)"),
        (
            Calibration {
                focal_px: f32::NAN,
                ..CAL
            },
            "focal length (px)",
        ),
        (
            Calibration {
                focal_px: f32::INFINITY,
                ..CAL
            },
            "focal length (px)",
        ),
        (
            Calibration {
                baseline_mm: -60.0,
                ..CAL
            },
            "baseline (mm)",
        ),
        (
            Calibration {
                principal_x_px: f32::NAN,
                ..CAL
            },
            "principal point (px)",
        ),
        (
            Calibration {
                principal_x_px: 700.0,
                ..CAL
            },
            "principal point (px)",
        ),
    ] {
        assert!(
            matches!(bad(cal, 160), Error::OutOfRange { what: w, .. } if w == what),
            "{what}"
        );
    }
    assert!(matches!(
        bad(CAL, 0),
        Error::OutOfRange {
            what: "profile width (px)",
            ..
        }
    ));
    assert!(matches!(
        bad(CAL, 641),
        Error::OutOfRange {
            what: "profile width (px)",
            max: 640,
            ..
        }
    ));

    let model = DepthModel::new(&CAL, 160, DisparityUnit::Pixels).unwrap();
    assert!(matches!(
        SectorSummary::<0>::new(&model, 160),
        Err(Error::OutOfRange { what: "sectors", .. })
    ));
    assert!(matches!(
        SectorSummary::<5>::new(&model, 4),
        Err(Error::OutOfRange {
            what: "sectors",
            max: 4,
            ..
        })
    ));
    let mut s = SectorSummary::<4>::new(&model, 160).unwrap();
    assert_eq!(
        s.push_row(&[1; 159], None),
        Err(Error::BufferSize {
            what: "sector disparity row",
            expected: 160,
            found: 159
        })
    );
    assert_eq!(
        s.push_row(&[1; 160], Some(&[1; 3])),
        Err(Error::BufferSize {
            what: "sector keep mask",
            expected: 160,
            found: 3
        })
    );
    assert_eq!(s.rows(), 0, "a rejected row is not counted");
}

#[test]
fn extreme_calibrations_never_panic() {
    let mut rng = Rng::new(7);
    for _ in 0..2000 {
        let f = f32::from_bits(rng.next_u64() as u32);
        let b = f32::from_bits(rng.next_u64() as u32);
        let cx = f32::from_bits(rng.next_u64() as u32);
        let width = (rng.next_u64() % 5000) as u32;
        let profile = (rng.next_u64() % 5000) as usize;
        let cal = Calibration {
            focal_px: f,
            principal_x_px: cx,
            baseline_mm: b,
            sensor_width_px: width,
        };
        for unit in [DisparityUnit::Pixels, DisparityUnit::PatchColumns] {
            if let Ok(model) = DepthModel::new(&cal, profile, unit) {
                for q8 in [1, 2, 255, 256, 65534] {
                    let _ = model.depth_mm(q8);
                }
                let cols = profile.min(64);
                if let Ok(mut s) = SectorSummary::<8>::new(&model, cols) {
                    let row: Vec<u16> = (0..cols).map(|_| rng.next_u64() as u16).collect();
                    s.push_row(&row, None).unwrap();
                    assert!(s.sectors().iter().all(|x| x.bearing_rad.is_finite()));
                }
            }
        }
    }
    // The largest calibration: depth saturates instead of wrapping.
    let cal = Calibration {
        focal_px: 1e6,
        principal_x_px: 0.0,
        baseline_mm: 1e6,
        sensor_width_px: 1,
    };
    let model = DepthModel::new(&cal, 1, DisparityUnit::Pixels).unwrap();
    assert_eq!(model.depth_mm(1), Some(u32::MAX));
}
