//! Depth and the sector summary with arbitrary calibrations (NaN, infinities, zero and huge
//! values included), profile widths, sector rows, masks and row lengths: an error or a result,
//! never a panic; every depth it gives is what its f64 formula gives, rounded.
#![no_main]

use arbitrary::Arbitrary;
use bino_core::depth::{Calibration, DepthModel, DisparityUnit, SectorSummary};
use libfuzzer_sys::fuzz_target;

#[derive(Debug, Arbitrary)]
struct Input {
    focal_px: f32,
    principal_x_px: f32,
    baseline_mm: f32,
    sensor_width_px: u32,
    profile_width_px: u16,
    patch_columns: bool,
    cols: u16,
    rows: Vec<Vec<u16>>,
    masks: Vec<Vec<u8>>,
}

fuzz_target!(|input: Input| {
    let cal = Calibration {
        focal_px: input.focal_px,
        principal_x_px: input.principal_x_px,
        baseline_mm: input.baseline_mm,
        sensor_width_px: input.sensor_width_px,
    };
    let unit = if input.patch_columns {
        DisparityUnit::PatchColumns
    } else {
        DisparityUnit::Pixels
    };
    let Ok(model) = DepthModel::new(&cal, usize::from(input.profile_width_px), unit) else {
        return;
    };
    let scale = f64::from(cal.sensor_width_px) / f64::from(input.profile_width_px);
    for row in &input.rows {
        for &q8 in row.iter().take(64) {
            let got = model.depth_mm(q8);
            if q8 == 0 || q8 == u16::MAX {
                assert_eq!(got, None);
                continue;
            }
            let want = f64::from(cal.focal_px) * f64::from(cal.baseline_mm)
                / (f64::from(q8) / 256.0 * unit.pixels() as f64 * scale);
            let got = f64::from(got.unwrap());
            if want < f64::from(u32::MAX) * 0.99 {
                // The documented bound of `depth_mm`.
                assert!(
                    (got - want).abs() <= 0.5 + want * 1e-6 + 1e-5,
                    "q8 {q8}: {got} mm, expected {want}"
                );
            }
        }
    }
    let cols = usize::from(input.cols % 512);
    let Ok(mut summary) = SectorSummary::<7>::new(&model, cols) else {
        return;
    };
    for (i, row) in input.rows.iter().enumerate() {
        let mask = input.masks.get(i).map(Vec::as_slice);
        let ok = row.len() == cols && mask.is_none_or(|m| m.len() == cols);
        assert_eq!(summary.push_row(row, mask).is_ok(), ok);
    }
    for s in summary.sectors() {
        assert!(s.first_col < s.end_col && usize::from(s.end_col) <= cols);
        assert!(
            s.bearing_rad.abs() <= core::f32::consts::FRAC_PI_2 + 1e-3,
            "{}",
            s.bearing_rad
        );
    }
});
