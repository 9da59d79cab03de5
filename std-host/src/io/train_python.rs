//! The project's Python environment (`scripts/setup.sh`) and its `train/` package, which the
//! CLI runs for what lives on the Python side: StereoSGBM (OpenCV) for `bino eval`, and
//! onnxruntime's timings for `bino bench`.

use std::path::PathBuf;

use anyhow::{ensure, Context, Result};

/// An interpreter and the folder holding the `bino_train` package.
#[derive(Debug, Clone)]
pub struct TrainPython {
    /// The interpreter.
    pub python: PathBuf,
    /// The `train/` folder (working directory of every `python -m bino_train.*`).
    pub train_dir: PathBuf,
}

impl TrainPython {
    /// The interpreter of `$BINO_PYTHON`, else `$BINO_VENV/bin/python`, else the environment
    /// `scripts/setup.sh` makes (`~/.cache/bino-edge/venv`); the `train/` folder of this
    /// checkout (or `$BINO_TRAIN_DIR`). `purpose` and `opt_out` complete the error when the
    /// interpreter is missing ("StereoSGBM runs ...", "--no-sgbm").
    pub fn locate(purpose: &str, opt_out: &str) -> Result<Self> {
        let python = match (std::env::var_os("BINO_PYTHON"), std::env::var_os("BINO_VENV")) {
            (Some(p), _) => PathBuf::from(p),
            (None, Some(venv)) => PathBuf::from(venv).join("bin/python"),
            (None, None) => {
                let home = std::env::var_os("HOME").context("HOME is not set")?;
                PathBuf::from(home).join(".cache/bino-edge/venv/bin/python")
            }
        };
        let train_dir = std::env::var_os("BINO_TRAIN_DIR")
            .map(PathBuf::from)
            .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../train")));
        ensure!(
            python.is_file(),
            "{purpose} runs in the project's Python environment, and {} does not exist: run \
             scripts/setup.sh, set BINO_PYTHON, or pass {opt_out}",
            python.display()
        );
        ensure!(
            train_dir.join("bino_train").is_dir(),
            "no bino_train package in {} (set BINO_TRAIN_DIR)",
            train_dir.display()
        );
        Ok(Self { python, train_dir })
    }
}

/// A fresh folder under the system's temporary directory, named for `what` and this process.
pub fn tempdir(what: &str) -> Result<PathBuf> {
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    let dir = std::env::temp_dir().join(format!("bino-{what}-{}-{stamp}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    Ok(dir)
}

/// Binary 8-bit PGM.
pub fn pgm(pixels: &[u8], width: usize, height: usize) -> Vec<u8> {
    let mut bytes = format!("P5\n{width} {height}\n255\n").into_bytes();
    bytes.extend_from_slice(pixels);
    bytes
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pgm_header_and_pixels() {
        assert_eq!(
            pgm(&[1, 2, 3, 4, 5, 6], 3, 2),
            b"P5\n3 2\n255\n\x01\x02\x03\x04\x05\x06"
        );
    }
}
