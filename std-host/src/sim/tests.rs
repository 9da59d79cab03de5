use embedded_graphics::pixelcolor::{Rgb565, RgbColor};

use super::*;

#[test]
fn the_default_pair_fills_the_width_of_a_qvga_display_twice_stacked() {
    let layout = Layout::new(DisplaySize::QVGA, 320, 96).unwrap();
    // 240 - 23 status rows = 217; two 96-row pictures at scale 1 fit above each other,
    // each centred in its 107-row half.
    assert_eq!(layout.status_y, 217);
    assert_eq!(
        (
            layout.camera.x,
            layout.camera.y,
            layout.camera.width,
            layout.camera.height
        ),
        (0, 5, 320, 96)
    );
    assert_eq!(layout.disparity.width, 320);
    assert_eq!(layout.disparity.height, 96);
    assert_eq!(layout.disparity.y, 107 + 2 + 5);
    assert!(layout.disparity.y + 96 <= layout.status_y);
}

#[test]
fn tall_images_go_side_by_side_and_tiny_displays_are_refused() {
    let layout = Layout::new(DisplaySize::QVGA, 320, 320).unwrap();
    assert_eq!(layout.camera.y, layout.disparity.y, "{layout:?}");
    assert!(layout.disparity.x >= layout.camera.x + layout.camera.width);
    assert!(layout.disparity.x + layout.disparity.width <= 320);
    let tiny = DisplaySize { width: 32, height: 24 };
    assert!(Layout::new(tiny, 320, 96).is_err());
}

#[test]
fn a_row_is_drawn_into_its_cells_and_rejected_cells_are_dark() {
    let size = DisplaySize { width: 64, height: 48 };
    let mut fb = Framebuffer::new(size);
    // A 16x8 image (4 patch columns, 2 token rows) at scale 2 from (10, 4).
    let panel = Panel::fit(10, 4, 32, 16, 16, 8);
    assert_eq!((panel.x, panel.y, panel.width, panel.height), (10, 4, 32, 16));
    let mut sink = DisplaySink::new(&mut fb, panel, Readout::SGM, 4);
    sink.draw_row(1, &[0, 256, 512, 768], &[1, 1, 0, 1]);
    assert_eq!(sink.rows_drawn, 1);
    // Token row 1 is image rows 4..8, display rows 4 + 8..4 + 16; each cell 8 px wide.
    for (c, expected_dark) in [false, false, true, false].into_iter().enumerate() {
        let x = 10 + 8 * c;
        let colour = fb.pixel(x + 3, 12 + 5).unwrap();
        assert_eq!(colour == REJECTED, expected_dark, "cell {c}: {colour:?}");
        assert_eq!(fb.pixel(x, 12), fb.pixel(x + 7, 19), "cell {c} is one colour");
    }
    assert_ne!(fb.pixel(10, 12), fb.pixel(18, 12), "disparity 0 and 1 differ in colour");
    // Nothing outside the row's cells.
    let lit = fb.raw().iter().filter(|&&w| w != 0).count();
    assert_eq!(lit, 4 * 8 * 8);
    assert_eq!(fb.pixel(10, 11), Some(Rgb565::BLACK));
    assert_eq!(fb.pixel(42, 12), Some(Rgb565::BLACK));
}
