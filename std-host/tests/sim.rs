//! `bino sim` end to end: the built-in pair goes through the sensor, the pipeline and the
//! display into a PNG of the display's size with a real disparity picture in it; a bad pair is
//! a clear error and a non-zero exit.

use std::collections::HashSet;
use std::path::PathBuf;

use bino_host::sim::display::DisplaySize;
use bino_host::sim::{Layout, DEFAULT_SCENE, REJECTED};
use embedded_graphics::pixelcolor::{Rgb565, Rgb888, RgbColor};

mod common;
use common::{bino, s, scratch_dir};

fn scratch(name: &str) -> PathBuf {
    let dir = scratch_dir(&format!("sim-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn sim_on_the_default_pair_draws_a_disparity_map_on_the_display() {
    let dir = scratch("default");
    let run = bino(&["sim", "--out", s(&dir)]);
    let (stdout, stderr) = (
        String::from_utf8_lossy(&run.stdout),
        String::from_utf8_lossy(&run.stderr),
    );
    assert!(run.status.success(), "{stderr}");
    let (w, h) = DEFAULT_SCENE;
    assert!(
        stdout.contains(&format!("sensor rows read {h}/{h} (each once)")),
        "{stdout}"
    );
    assert!(stdout.contains("host ") && stdout.contains(" fps"), "{stdout}");
    assert!(stdout.contains("arena "), "{stdout}");

    let png = image::open(dir.join("display.png")).unwrap().to_rgb8();
    assert_eq!(png.dimensions(), (320, 240), "the default display is 320x240");
    assert!(!dir.join("display.png.partial").exists());

    // The disparity panel holds many colours (the scene's three depths, parabola steps) and
    // mostly left-right consistent cells, not one flat fill.
    let layout = Layout::new(DisplaySize::QVGA, w, h).unwrap();
    let p = layout.disparity;
    let mut colours = HashSet::new();
    let mut rejected = 0;
    for y in p.y..p.y + p.height {
        for x in p.x..p.x + p.width {
            let c = png.get_pixel(x as u32, y as u32).0;
            rejected += usize::from(c == rgb888(REJECTED));
            colours.insert(c);
        }
    }
    assert!(colours.len() >= 8, "{} colours in the disparity panel", colours.len());
    assert!(rejected < p.width * p.height / 2, "{rejected} rejected pixels");
    // The near box (disparity 16 px, left of centre) and the background (4 px) differ.
    let at = |fx: f64, fy: f64| {
        let (x, y) = (
            p.x + (fx * p.width as f64) as usize,
            p.y + (fy * p.height as f64) as usize,
        );
        png.get_pixel(x as u32, y as u32).0
    };
    assert_ne!(at(0.25, 0.5), at(0.45, 0.05), "near box and background look alike");

    // The status bar has text in it.
    let lit = (layout.status_y..240)
        .flat_map(|y| (0..320).map(move |x| (x, y)))
        .filter(|&(x, y)| png.get_pixel(x, y as u32).0 == [255, 255, 255])
        .count();
    assert!(lit > 200, "{lit} white pixels in the status bar");
}

fn rgb888(c: Rgb565) -> [u8; 3] {
    let c = Rgb888::from(c);
    [c.r(), c.g(), c.b()]
}

#[test]
fn views_of_different_sizes_are_a_clear_error() {
    let dir = scratch("mismatch");
    let texture =
        |w: u32, h: u32| image::GrayImage::from_fn(w, h, |x, y| image::Luma([((x * 7 + y * 13) % 256) as u8]));
    texture(64, 48).save(dir.join("l.png")).unwrap();
    texture(64, 40).save(dir.join("r.png")).unwrap();
    let run = bino(&[
        "sim",
        "--left",
        s(&dir.join("l.png")),
        "--right",
        s(&dir.join("r.png")),
        "--out",
        s(&dir),
    ]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(!run.status.success(), "expected failure: {stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    for needle in ["differ in size", "l.png is 64x48", "r.png is 64x40"] {
        assert!(stderr.contains(needle), "stderr lacks {needle:?}: {stderr}");
    }
    assert!(!dir.join("display.png").exists());
}

#[test]
fn a_bad_display_size_or_a_lone_view_is_refused() {
    let run = bino(&["sim", "--display", "320by240"]);
    assert!(!run.status.success());
    assert!(String::from_utf8_lossy(&run.stderr).contains("WIDTHxHEIGHT"));
    let run = bino(&["sim", "--left", "a.png"]);
    assert!(!run.status.success());
    assert!(String::from_utf8_lossy(&run.stderr).contains("--right"));
}

/// One readout, one number: the refined pixels sim draws as the pipeline streams them are the
/// pixels `bino run` writes for the same readout (its `disparity.pfm`), colour for colour. Both
/// default to the census SGM with its check, refined (census+lr+ref), which the pipeline streams
/// without the encoder across the scene's two bands.
#[test]
fn sim_draws_the_refined_pixels_run_writes() {
    sim_matches_run("refined", &[], "census+lr+ref");
}

/// The same for the export pathway's learned readout (fuse-all+lr, refined: the head, the census
/// SGM and the descriptor SGM), its default when the pathway is named.
#[test]
fn sim_draws_the_export_pathways_pixels_run_writes() {
    sim_matches_run("export", &["--pathway", "export"], "fuse-all+lr+ref");
}

/// The same for the head and SGM fused without the census.
#[test]
fn sim_draws_the_fused_pixels_run_writes() {
    sim_matches_run("fused-sgm", &["--readout", "fuse+lr+ref"], "fuse+lr+ref");
}

/// The same for the native pathway's fusion with the census SGM, which the pipeline streams
/// beside the native head across the scene's two bands.
#[test]
fn sim_draws_the_fused_census_pixels_run_writes() {
    let native = ["--pathway", "native", "--readout", "fuse-census+lr+ref"];
    sim_matches_run("census", &native, "fuse-census+lr+ref");
}

/// Runs `bino run` and `bino sim` with `extra` on the default scene and checks sim's display
/// shows run's `disparity.pfm` pixel for pixel, sim naming `readout`.
fn sim_matches_run(name: &str, extra: &[&str], readout: &str) {
    let dir = scratch(name);
    let (w, h) = DEFAULT_SCENE;
    let scene = bino_host::data::synthetic::default_scene(w, h);
    for (name, view) in [("l.png", &scene.left), ("r.png", &scene.right)] {
        image::GrayImage::from_raw(w as u32, h as u32, view.pixels.clone())
            .unwrap()
            .save(dir.join(name))
            .unwrap();
    }
    let (left, right) = (dir.join("l.png"), dir.join("r.png"));
    let pair = ["--left", s(&left), "--right", s(&right), "--profile", "native"];
    let run_dir = dir.join("run");
    let run = bino(&[&["run", "--out", s(&run_dir)][..], &pair, extra].concat());
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let sim = bino(&[&["sim", "--out", s(&dir)][..], &pair, extra].concat());
    let stdout = String::from_utf8_lossy(&sim.stdout);
    assert!(sim.status.success(), "{}", String::from_utf8_lossy(&sim.stderr));
    assert!(stdout.contains(readout), "sim's readout: {stdout}");
    assert!(
        stdout.contains(&format!("{h} rows drawn")),
        "one drawn row per pixel row: {stdout}"
    );

    let written = bino_host::io::pfm::load(&run_dir.join("disparity.pfm"), "run's disparity").unwrap();
    assert_eq!((written.width, written.height), (w, h));
    let max_px = (bino_core::config::HEAD_MAX_DISP - 1) as f32 * bino_host::eval::PIXELS_PER_PATCH_COLUMN as f32;
    let expected = bino_host::io::colour::colourise(&written.values, max_px);
    let layout = Layout::new(DisplaySize::QVGA, w, h).unwrap();
    let p = layout.disparity;
    assert_eq!((p.width, p.height), (w, h), "the scene is drawn at scale 1");
    let png = image::open(dir.join("display.png")).unwrap().to_rgb8();
    let mut differ = 0;
    for y in 0..h {
        for x in 0..w {
            let rgb = &expected[3 * (y * w + x)..3 * (y * w + x) + 3];
            let want = rgb888(Rgb565::from(Rgb888::new(rgb[0], rgb[1], rgb[2])));
            differ += usize::from(png.get_pixel((p.x + x) as u32, (p.y + y) as u32).0 != want);
        }
    }
    assert_eq!(
        differ,
        0,
        "{differ} of {} display pixels differ from run's disparity.pfm",
        w * h
    );
}

#[test]
fn sim_streams_the_checked_fusion_and_refuses_the_unchecked_one() {
    let dir = scratch("fused");
    let (_, h) = DEFAULT_SCENE;
    for readout in [
        &["--readout", "fuse+lr"][..],
        &["--readout", "fuse-all+lr"],
        &["--pathway", "native", "--readout", "fuse-census+lr"],
        &["--readout", "census+lr"],
    ] {
        let run = bino(&[&["sim", "--out", s(&dir)][..], readout].concat());
        let stdout = String::from_utf8_lossy(&run.stdout);
        assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
        assert!(
            stdout.contains(&format!("{} rows drawn", h / 4)),
            "{readout:?}: one drawn row per token row: {stdout}"
        );
    }
    for readout in ["fuse", "fuse+ref"] {
        let run = bino(&["sim", "--readout", readout, "--out", s(&dir)]);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(!run.status.success(), "{stderr}");
        assert!(
            stderr.contains(&format!("--readout {readout}:"))
                && stderr.contains("fuses the head and SGM by their checks"),
            "{stderr}"
        );
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
    // The readouts the pipeline does not stream are refused by name.
    for readout in ["fuse-all", "fuse-all+ref", "fuse-census+ref"] {
        let run = bino(&["sim", "--readout", readout, "--out", s(&dir)]);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert!(!run.status.success(), "{stderr}");
        assert!(
            stderr.contains(&format!("--readout {readout}:")) && stderr.contains("bino run and bino eval only"),
            "{stderr}"
        );
    }
}
