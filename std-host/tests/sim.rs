//! `bino sim` end to end: the built-in pair goes through the sensor, the pipeline and the
//! display into a PNG of the display's size with a real disparity picture in it; a bad pair is
//! a clear error and a non-zero exit.

use std::collections::HashSet;
use std::path::PathBuf;

use bino_host::sim::display::DisplaySize;
use bino_host::sim::{Layout, DEFAULT_SCENE, REJECTED};

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

fn rgb888(c: embedded_graphics::pixelcolor::Rgb565) -> [u8; 3] {
    use embedded_graphics::pixelcolor::{Rgb888, RgbColor};
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
    // The board draws token rows as they stream; the refinement is not a pipeline stage yet.
    let run = bino(&["sim", "--readout", "head+lr+ref", "--out", s(&scratch("refined"))]);
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert_eq!(run.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("use --readout head+lr"), "{stderr}");
}
