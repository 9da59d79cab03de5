//! False colour for disparity and error maps (RGB bytes, row-major).

/// Disparities in `[0, max]` through the Turbo colour map (near = red, far = blue); values
/// outside are clamped, non-finite ones drawn black.
pub fn colourise(values: &[f32], max: f32) -> Vec<u8> {
    let max = if max > 0.0 { max } else { 1.0 };
    values
        .iter()
        .flat_map(|&v| {
            if v.is_finite() {
                turbo((v / max).clamp(0.0, 1.0))
            } else {
                [0, 0, 0]
            }
        })
        .collect()
}

/// Absolute errors in `[0, max]`: black (exact) through red to yellow (`max` or more).
pub fn error_colour(errors: &[f32], max: f32) -> Vec<u8> {
    let max = if max > 0.0 { max } else { 1.0 };
    errors
        .iter()
        .flat_map(|&e| {
            let t = if e.is_finite() { (e / max).clamp(0.0, 1.0) } else { 1.0 };
            let red = (2.0 * t).min(1.0);
            let green = (2.0 * t - 1.0).max(0.0);
            [to_byte(red), to_byte(green), 0]
        })
        .collect()
}

/// Turbo (Mikhailov, Google 2019), the published polynomial fit; `t` in `[0, 1]`.
fn turbo(t: f32) -> [u8; 3] {
    let t = t as f64;
    let (t2, t3, t4, t5) = (t * t, t * t * t, t.powi(4), t.powi(5));
    let r = 0.13572138 + 4.61539260 * t - 42.66032258 * t2 + 132.13108234 * t3 - 152.94239396 * t4 + 59.28637943 * t5;
    let g = 0.09140261 + 2.19418839 * t + 4.84296658 * t2 - 14.18503333 * t3 + 4.27729857 * t4 + 2.82956604 * t5;
    let b = 0.10667330 + 12.64194608 * t - 60.58204836 * t2 + 110.36276771 * t3 - 89.90310912 * t4 + 27.34824973 * t5;
    [to_byte(r as f32), to_byte(g as f32), to_byte(b as f32)]
}

fn to_byte(x: f32) -> u8 {
    (x.clamp(0.0, 1.0) * 255.0).round() as u8
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn turbo_runs_from_dark_blue_to_dark_red() {
        let [r_far, _, b_far] = turbo(0.1);
        let [r_near, _, b_near] = turbo(0.9);
        assert!(
            b_far > 2 * r_far && r_near > 2 * b_near,
            "{:?} {:?}",
            turbo(0.1),
            turbo(0.9)
        );
        let brightness = |t: f32| turbo(t).iter().map(|&c| c as u32).sum::<u32>();
        assert!(brightness(0.0) < brightness(0.5) && brightness(1.0) < brightness(0.5));
        assert_eq!(colourise(&[f32::NAN, 2.0], 1.0).len(), 6);
        assert_eq!(&colourise(&[f32::NAN], 1.0)[..], &[0, 0, 0]);
        assert_eq!(colourise(&[5.0], 1.0), colourise(&[1.0], 1.0));
    }

    #[test]
    fn error_colours_grow_with_the_error() {
        assert_eq!(error_colour(&[0.0], 8.0), vec![0, 0, 0]);
        assert_eq!(error_colour(&[4.0], 8.0), vec![255, 0, 0]);
        assert_eq!(error_colour(&[100.0], 8.0), vec![255, 255, 0]);
    }
}
