//! Where the `bino` verbs' default files are: the checkout `bino` was built from.
//!
//! One rule for every verb: a default input (the shipped weights, the data folder, the
//! firmware runs) is a file of the checkout, located from the build-time manifest directory,
//! so an installed `bino` (`cargo install --path std-host`) finds them from any working
//! directory. A path given on the command line is used as given: a relative one is relative
//! to the current directory. Output folders (`out/...`) stay relative to the current directory.

use std::path::{Component, Path, PathBuf};

/// The shipped int8 weight blob.
pub const BLOB: &str = "weights/bino_int8.bin";
/// The board's learned preset's blob: the shipped blob's encoder and native head only
/// (`bino quantize --only native`).
pub const NATIVE_BLOB: &str = "weights/bino_int8_native.bin";
/// The shipped float encoder (ONNX).
pub const ENCODER_ONNX: &str = "weights/bino_encoder.onnx";
/// The shipped float shared head (ONNX).
pub const HEAD_ONNX: &str = "weights/bino_head.onnx";
/// The shipped float native-pathway head (ONNX).
pub const NATIVE_HEAD_ONNX: &str = "weights/bino_native_head.onnx";
/// The data folder with `PAIRS.tsv`, beside the checkout.
pub const DATA: &str = "../shared/data";
/// The committed firmware runs (`m55.json`, `m7.json`).
pub const FIRMWARE_RUNS: &str = "firmware-sim/measured";

/// The checkout's root: the folder holding `std-host/` when `bino` was built.
pub fn root() -> PathBuf {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    manifest.parent().unwrap_or(manifest).to_path_buf()
}

/// `relative` (`/`-separated, from the checkout's root; `..` climbs out of it) as an absolute
/// path without `.` or `..` components: the default of every flag that names a checkout file.
pub fn path(relative: &str) -> PathBuf {
    let mut path = root();
    for component in Path::new(relative).components() {
        match component {
            Component::ParentDir => {
                path.pop();
            }
            Component::CurDir => {}
            other => path.push(other),
        }
    }
    path
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_absolute_files_of_the_checkout() {
        for name in [BLOB, ENCODER_ONNX, HEAD_ONNX, NATIVE_HEAD_ONNX, FIRMWARE_RUNS] {
            let p = path(name);
            assert!(p.is_absolute(), "{}", p.display());
            assert!(p.starts_with(root()) && p.ends_with(name), "{}", p.display());
            assert!(p.exists(), "{} is missing from the checkout", p.display());
        }
        // `..` leaves the checkout without a literal `..` in the path shown by --help.
        let data = path(DATA);
        assert_eq!(data, root().parent().unwrap().join("shared/data"));
        assert!(!data.components().any(|c| c == Component::ParentDir));
    }

    #[test]
    fn the_library_constant_is_the_same_blob() {
        let constant = std::fs::canonicalize(crate::demo::DEFAULT_BLOB).unwrap();
        assert_eq!(constant, std::fs::canonicalize(path(BLOB)).unwrap());
    }
}
