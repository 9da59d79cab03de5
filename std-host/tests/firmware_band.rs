//! The firmware's embedded test bands (`firmware-sim/assets/band_<H>x<W>_{left,right}.gray`, raw
//! row-major gray bytes) are the built-in procedural scene (`bino_host::data::synthetic::default_scene`,
//! the scene `bino demo --width W --height H` shows), not arbitrary blobs.
//! Regenerate them with `cargo test -p bino-host --test firmware_band -- --ignored`.

use std::path::{Path, PathBuf};

use bino_host::data::synthetic::default_scene;

/// The band sizes the firmware embeds (height, width): 48x160 (the budget and CI run), 48x32
/// (`scripts/firmware.sh --band small`, a quick check).
const BANDS: [(usize, usize); 2] = [(48, 160), (48, 32)];

fn assets() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../firmware-sim/assets")
}

fn path(height: usize, width: usize, view: &str) -> PathBuf {
    assets().join(format!("band_{height}x{width}_{view}.gray"))
}

#[test]
fn committed_bands_are_the_demo_scene() {
    for (height, width) in BANDS {
        let scene = default_scene(width, height);
        for (view, image) in [("left", &scene.left), ("right", &scene.right)] {
            let file = path(height, width, view);
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
    for (height, width) in BANDS {
        let scene = default_scene(width, height);
        std::fs::write(path(height, width, "left"), &scene.left.pixels).unwrap();
        std::fs::write(path(height, width, "right"), &scene.right.pixels).unwrap();
    }
}
