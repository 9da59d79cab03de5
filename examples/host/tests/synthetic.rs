//! A synthetic pair with a known disparity: a random texture and the same texture shifted by
//! [`SHIFT`] pixels, written as PNGs, through the program; its PNG must show that disparity.

use std::path::PathBuf;
use std::process::Command;

use image::{DynamicImage, GrayImage};

/// The pair's disparity in pixels (left column x shows what right column x - SHIFT shows).
const SHIFT: u32 = 8;
const WIDTH: u32 = 160;
const HEIGHT: u32 = 48;

/// Left and right views: 2x2-pixel blocks of random grey (a fixed LCG), the right view the left
/// one moved SHIFT pixels to the left (right column x - SHIFT shows left column x).
fn pair() -> (GrayImage, GrayImage) {
    let mut state = 0x2545_f491_u32;
    let blocks: Vec<u8> = (0..(WIDTH + SHIFT) / 2 * HEIGHT / 2)
        .map(|_| {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (state >> 24) as u8
        })
        .collect();
    let texture = |x: u32, y: u32| image::Luma([blocks[(y / 2 * (WIDTH + SHIFT) / 2 + x / 2) as usize]]);
    let left = GrayImage::from_fn(WIDTH, HEIGHT, texture);
    let right = GrayImage::from_fn(WIDTH, HEIGHT, |x, y| texture(x + SHIFT, y));
    (left, right)
}

/// The median of the disparities (px) away from the borders.
fn median_inside(px: impl Fn(u32, u32) -> f32) -> f32 {
    let mut values: Vec<f32> = (8..HEIGHT - 8)
        .flat_map(|y| (24..WIDTH - 8).map(move |x| (x, y)))
        .map(|(x, y)| px(x, y))
        .collect();
    values.sort_by(f32::total_cmp);
    values[values.len() / 2]
}

#[test]
fn the_library_finds_the_shift() {
    let (left, right) = pair();
    let d = bino_example_host::disparity(&DynamicImage::ImageLuma8(left), &DynamicImage::ImageLuma8(right)).unwrap();
    assert_eq!(
        (d.width, d.height, d.q8.len()),
        (WIDTH, HEIGHT, (WIDTH * HEIGHT) as usize)
    );
    let median = median_inside(|x, y| d.px(x, y));
    assert!(
        (median - SHIFT as f32).abs() <= 1.0,
        "median disparity {median} px, expected {SHIFT}"
    );
}

#[test]
fn the_program_writes_the_disparity_png() {
    let dir = std::env::temp_dir().join(format!("bino-example-host-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = |name: &str| -> PathBuf { dir.join(name) };
    let (left, right) = pair();
    left.save(path("left.png")).unwrap();
    right.save(path("right.png")).unwrap();
    let status = Command::new(env!("CARGO_BIN_EXE_bino-example-host"))
        .args([path("left.png"), path("right.png"), path("out.png")])
        .status()
        .unwrap();
    assert!(status.success());
    let out = image::open(path("out.png")).unwrap().to_luma8();
    assert_eq!(out.dimensions(), (WIDTH, HEIGHT));
    // 8 grey levels per pixel of disparity.
    let median = median_inside(|x, y| f32::from(out.get_pixel(x, y).0[0]) / 8.0);
    assert!(
        (median - SHIFT as f32).abs() <= 1.0,
        "median disparity {median} px, expected {SHIFT}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
