//! OpenCV StereoSGBM with EVAL.md's settings, run by the project's Python environment
//! (`python -m bino_train.sgbm_run`), so `bino eval` puts the reference next to BINO's readouts
//! on the very same profile images. Rust writes the pairs as 8-bit PGM, Python writes SGBM's
//! disparity as `.npy` (-1 where SGBM rejected a pixel), and Rust scores it with the same
//! metric code as every other readout.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{bail, ensure, Context, Result};

use crate::io::train_python::{pgm, tempdir, TrainPython};

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
    /// The project's Python environment ([`TrainPython::locate`]).
    pub fn locate() -> Result<Self> {
        let TrainPython { python, train_dir } = TrainPython::locate("StereoSGBM", "--no-sgbm")?;
        Ok(Self { python, train_dir })
    }

    /// SGBM's disparity (pixels) and validity for each pair, in order.
    pub fn run(&self, pairs: &[GrayPair<'_>]) -> Result<Vec<(DisparityMap, Vec<bool>)>> {
        let dir = tempdir("sgbm")?;
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
                let array = crate::io::npy::decode(&bytes)?;
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sgbm_finds_a_known_shift_when_python_is_there() {
        let Ok(runner) = SgbmRunner::locate() else {
            crate::test_inputs::skip("the Python environment (scripts/setup.sh)");
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
