//! The board program's logic on the host: the test band's digests equal the firmware's, and
//! [`EXPECTED`] equals what the firmware runs recorded (`firmware-sim/measured/`).

use bino_example_board::{run_band, Camera, Digests, ARENA_BYTES, EXPECTED, OUTPUTS, WIDTH};

fn read(rel: &str) -> Vec<u8> {
    let path = format!("{}/../../{rel}", env!("CARGO_MANIFEST_DIR"));
    std::fs::read(&path).unwrap_or_else(|e| panic!("{path}: {e}"))
}

#[test]
fn band_digests_equal_the_firmware() {
    let blob = read("weights/bino_int8.bin");
    let (left, right) = (
        read("firmware-sim/assets/band_48x160_left.gray"),
        read("firmware-sim/assets/band_48x160_right.gray"),
    );
    let mut arena = vec![0u8; ARENA_BYTES];
    let (digests, report) = run_band(&blob, &mut Camera::new(&left, &right), &mut arena).unwrap();
    for ((name, found), expected) in OUTPUTS.iter().zip(digests.0).zip(EXPECTED.0) {
        assert_eq!(found, expected, "{name}: found {found:08x}, expected {expected:08x}");
    }
    assert!(report.arena_used <= ARENA_BYTES);
}

/// `EXPECTED` is what the firmware measured on both cores (native pathway, the preset's).
#[test]
fn expected_digests_are_the_firmwares() {
    for core in ["m55", "m7"] {
        let json: serde_json::Value =
            serde_json::from_slice(&read(&format!("firmware-sim/measured/{core}.json"))).unwrap();
        let outputs = json["outputs"].as_array().expect("outputs");
        let digest = |name: &str| {
            let o = outputs.iter().find(|o| o["pathway"] == "native" && o["name"] == name);
            let hex = o
                .and_then(|o| o["digest"].as_str())
                .unwrap_or_else(|| panic!("{core}.json: no native digest of {name}"));
            u32::from_str_radix(hex, 16).unwrap()
        };
        assert_eq!(
            Digests(OUTPUTS.map(digest)),
            EXPECTED,
            "firmware-sim/measured/{core}.json"
        );
    }
}

#[test]
fn a_short_frame_is_an_error() {
    let blob = read("weights/bino_int8.bin");
    let short = vec![0u8; WIDTH * 10];
    let mut arena = vec![0u8; ARENA_BYTES];
    assert!(run_band(&blob, &mut Camera::new(&short, &short), &mut arena).is_err());
}
