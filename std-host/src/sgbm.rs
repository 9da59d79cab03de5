//! OpenCV StereoSGBM with EVAL.md's settings, run by the project's Python environment
//! (`python -m bino_train.sgbm_run`), so `bino eval` puts the reference next to BINO's readouts
//! on the very same profile images. Rust writes the pairs as 8-bit PGM, Python writes SGBM's
//! disparity as `.npy` (-1 where SGBM rejected a pixel), and Rust scores it with the same
//! metric code as every other readout.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{bail, ensure, Context, Result};

use crate::eval::DisparityMap;

/// Where the Python side lives and which interpreter runs it.
#[derive(Debug, Clone)]
pub struct SgbmRunner {
    python: PathBuf,
    train_dir: PathBuf,
}

/// One pair at the profile's resolution, 8-bit gray, row-major.
pub struct GrayPair<'a> {
    /// Left view.
    pub left: &'a [u8],
    /// Right view.
    pub right: &'a [u8],
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
}

impl SgbmRunner {
    /// The interpreter of `$BINO_PYTHON`, else `$BINO_VENV/bin/python`, else the environment
    /// `scripts/setup.sh` makes (`~/.cache/bino-edge/venv`); the `train/` folder of this
    /// checkout (or `$BINO_TRAIN_DIR`).
    pub fn locate() -> Result<Self> {
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
            "StereoSGBM runs in the project's Python environment, and {} does not exist: run \
             scripts/setup.sh, set BINO_PYTHON, or pass --no-sgbm",
            python.display()
        );
        ensure!(
            train_dir.join("bino_train").is_dir(),
            "no bino_train package in {} (set BINO_TRAIN_DIR)",
            train_dir.display()
        );
        Ok(Self { python, train_dir })
    }

    /// SGBM's disparity (pixels) and validity for each pair, in order.
    pub fn run(&self, pairs: &[GrayPair<'_>]) -> Result<Vec<(DisparityMap, Vec<bool>)>> {
        let dir = tempdir()?;
        let result = self.run_in(dir.as_path(), pairs);
        let _ = std::fs::remove_dir_all(&dir);
        result
    }

    fn run_in(&self, dir: &Path, pairs: &[GrayPair<'_>]) -> Result<Vec<(DisparityMap, Vec<bool>)>> {
        let mut jobs = String::new();
        for (i, pair) in pairs.iter().enumerate() {
            ensure!(
                pair.left.len() == pair.width * pair.height && pair.right.len() == pair.left.len(),
                "pair {i}: views do not hold {}x{} pixels",
                pair.width,
                pair.height
            );
            let (l, r, out) = (
                dir.join(format!("{i}_l.pgm")),
                dir.join(format!("{i}_r.pgm")),
                dir.join(format!("{i}.npy")),
            );
            std::fs::write(&l, pgm(pair.left, pair.width, pair.height))?;
            std::fs::write(&r, pgm(pair.right, pair.width, pair.height))?;
            jobs.push_str(&format!("{}\t{}\t{}\n", l.display(), r.display(), out.display()));
        }
        let list = dir.join("jobs.tsv");
        std::fs::write(&list, jobs)?;
        let output = Command::new(&self.python)
            .args(["-W", "ignore", "-m", "bino_train.sgbm_run", "--list"])
            .arg(&list)
            .current_dir(&self.train_dir)
            .output()
            .with_context(|| format!("cannot start {}", self.python.display()))?;
        if !output.status.success() {
            bail!(
                "StereoSGBM ({} -m bino_train.sgbm_run) failed: {}",
                self.python.display(),
                String::from_utf8_lossy(&output.stderr).trim()
            );
        }
        pairs
            .iter()
            .enumerate()
            .map(|(i, pair)| {
                let path = dir.join(format!("{i}.npy"));
                let bytes = std::fs::read(&path).with_context(|| format!("SGBM wrote no {}", path.display()))?;
                let array = crate::npy::decode(&bytes)?;
                ensure!(
                    array.shape == [pair.height, pair.width],
                    "SGBM disparity has shape {:?}, expected [{}, {}]",
                    array.shape,
                    pair.height,
                    pair.width
                );
                let valid = array.data.iter().map(|&d| d >= 0.0).collect();
                Ok((
                    DisparityMap {
                        width: pair.width,
                        height: pair.height,
                        values: array.data,
                    },
                    valid,
                ))
            })
            .collect()
    }
}

/// Binary 8-bit PGM.
fn pgm(pixels: &[u8], width: usize, height: usize) -> Vec<u8> {
    let mut bytes = format!("P5\n{width} {height}\n255\n").into_bytes();
    bytes.extend_from_slice(pixels);
    bytes
}

fn tempdir() -> Result<PathBuf> {
    let stamp = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos())
        .unwrap_or(0);
    let dir = std::env::temp_dir().join(format!("bino-sgbm-{}-{stamp}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    Ok(dir)
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

    #[test]
    fn sgbm_finds_a_known_shift_when_python_is_there() {
        let Ok(runner) = SgbmRunner::locate() else {
            eprintln!("skipped: no Python environment (scripts/setup.sh)");
            return;
        };
        // A blurred random texture; left(x) = right(x - 6): right(x) = texture(x + 6).
        let (w, h, shift) = (96usize, 32usize, 6usize);
        let mut state = 12345u32;
        let texture: Vec<u8> = (0..(w + shift) * h)
            .map(|_| {
                state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (state >> 24) as u8
            })
            .collect();
        let blur = |x: usize, y: usize| -> u8 {
            let row = &texture[y * (w + shift)..(y + 1) * (w + shift)];
            ((row[x] as u16 + row[(x + 1).min(w + shift - 1)] as u16) / 2) as u8
        };
        let left: Vec<u8> = (0..w * h).map(|i| blur(i % w, i / w)).collect();
        let right: Vec<u8> = (0..w * h).map(|i| blur(i % w + shift, i / w)).collect();
        let out = runner
            .run(&[GrayPair {
                left: &left,
                right: &right,
                width: w,
                height: h,
            }])
            .unwrap();
        let (disp, valid) = &out[0];
        let good: Vec<f32> = disp
            .values
            .iter()
            .zip(valid)
            .filter(|(_, &v)| v)
            .map(|(&d, _)| d)
            .collect();
        assert!(good.len() > w * h / 3, "{} valid pixels", good.len());
        let near = good.iter().filter(|&&d| (d - shift as f32).abs() <= 1.0).count();
        assert!(
            near * 10 >= good.len() * 9,
            "{near} of {} within 1 px of {shift}",
            good.len()
        );
    }
}
