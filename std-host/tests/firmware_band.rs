//! The firmware's and the boards' embedded test bands and frames (`firmware-sim/assets/{band,frame}_<H>x<W>_{left,right}.gray`,
//! raw row-major gray bytes) are the built-in procedural scene (`bino_host::data::synthetic::default_scene`,
//! the scene `bino demo --width W --height H` shows), not arbitrary blobs.
//! Regenerate them with `cargo test -p bino-host --test firmware_band -- --ignored`.

use std::path::{Path, PathBuf};

use bino_host::data::synthetic::default_scene;

/// The pairs the firmware and the boards embed (kind, height, width): the 48x160 band (the budget
/// and CI run), the 48x32 band (`scripts/firmware.sh --band small`, a quick check), the 160x120
/// frame of both presets' whole-frame runs and the 320x240 frame the Alif E7 board runs.
const BANDS: [(&str, usize, usize); 4] = [
    ("band", 48, 160),
    ("band", 48, 32),
    ("frame", 120, 160),
    ("frame", 240, 320),
];

fn assets() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../firmware-sim/assets")
}

fn path(kind: &str, height: usize, width: usize, view: &str) -> PathBuf {
    assets().join(format!("{kind}_{height}x{width}_{view}.gray"))
}

#[test]
fn committed_bands_are_the_demo_scene() {
    for (kind, height, width) in BANDS {
        let scene = default_scene(width, height);
        for (view, image) in [("left", &scene.left), ("right", &scene.right)] {
            let file = path(kind, height, width, view);
            let bytes = std::fs::read(&file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
            assert_eq!(bytes.len(), width * height, "{}", file.display());
            let first_diff = bytes.iter().zip(&image.pixels).position(|(a, b)| a != b);
            assert_eq!(
                first_diff,
                None,
                "{} differs from default_scene({width}, {height})",
                file.display()
            );
        }
        // A real scene, not a flat band: the two views differ (disparity) and have texture.
        assert_ne!(scene.left.pixels, scene.right.pixels);
        let (min, max) = scene
            .left
            .pixels
            .iter()
            .fold((255, 0), |(lo, hi), &p| (p.min(lo), p.max(hi)));
        assert!(max - min > 64, "{height}x{width}: texture range {min}..{max}");
    }
}

#[test]
#[ignore = "writes firmware-sim/assets; run on purpose to regenerate the bands"]
fn write_firmware_bands() {
    for (kind, height, width) in BANDS {
        let scene = default_scene(width, height);
        std::fs::write(path(kind, height, width, "left"), &scene.left.pixels).unwrap();
        std::fs::write(path(kind, height, width, "right"), &scene.right.pixels).unwrap();
    }
}
