//! One readout, one number, on the board's whole frame: the fast preset's frame that the firmware
//! runs under QEMU (`firmware-sim/assets/frame_120x160_*.gray`, four bands of the census readout,
//! rows from the camera) refines to the pixels `bino run` writes for the same pair with its
//! default readout (`census+lr+ref`): the CRC-32 of run's `disparity.pfm` (back in Q8 pixels,
//! exactly: every value is a multiple of 1/256) is the `refined` digest both firmwares recorded
//! (`firmware-sim/measured/{m55,m7}.json`, pathway `census`). `bino sim` draws what `bino run`
//! writes (`tests/sim.rs`), so the three agree.

mod common;
use common::{bino, q8_crc, repo, s, scratch_dir};

const FRAME: (usize, usize) = (160, 120);

/// The `refined` digest a firmware run recorded for its census frame.
fn firmware_refined(core: &str) -> u32 {
    let path = repo().join(format!("firmware-sim/measured/{core}.json"));
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let run: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(run["passed"], true, "{}", path.display());
    let (w, h) = FRAME;
    assert_eq!(run["census"]["frame"]["width"], w, "{}", path.display());
    assert_eq!(run["census"]["frame"]["height"], h, "{}", path.display());
    let digest = run["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .find(|o| o["pathway"] == "census" && o["name"] == "refined")
        .unwrap_or_else(|| panic!("{}: no census refined digest", path.display()));
    assert_eq!(
        digest["match"],
        true,
        "{}: the firmware against its host",
        path.display()
    );
    u32::from_str_radix(digest["digest"].as_str().unwrap(), 16).unwrap()
}

#[test]
fn run_writes_the_pixels_the_firmware_refines_on_its_frame() {
    let (w, h) = FRAME;
    let dir = scratch_dir("census-frame");
    let assets = repo().join("firmware-sim/assets");
    for (view, png) in [("left", "l.png"), ("right", "r.png")] {
        let pixels = std::fs::read(assets.join(format!("frame_{h}x{w}_{view}.gray"))).unwrap();
        image::GrayImage::from_raw(w as u32, h as u32, pixels)
            .unwrap()
            .save(dir.join(png))
            .unwrap();
    }
    let out = dir.join("run");
    let run = bino(&[
        "run",
        "--left",
        s(&dir.join("l.png")),
        "--right",
        s(&dir.join("r.png")),
        "--profile",
        "native",
        "--out",
        s(&out),
    ]);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    assert!(stdout.contains("census"), "run's default readout: {stdout}");
    let written = q8_crc(&out.join("disparity.pfm"), FRAME);
    for core in ["m55", "m7"] {
        let firmware = firmware_refined(core);
        assert_eq!(
            written, firmware,
            "{core}: bino run {written:08x}, firmware {firmware:08x} (re-measure with scripts/firmware.sh --profile --kernels --frame320 --out firmware-sim/measured after changing the engine)"
        );
    }
}
