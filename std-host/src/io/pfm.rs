//! Reading grayscale PFM (portable float map): the ground-truth format of Middlebury 2014 and
//! ETH3D, and what `bino run` writes.
//!
//! No well-kept crate reads PFM (`pxm` has one release, 0.1.0), and the format is three header
//! tokens and raw float32s, so it is read here, small and strict:
//!
//! - `Pf` (one channel); `PF` (RGB) is refused, not reduced to a channel: a colour map is not a
//!   disparity map, and guessing a channel would hide a wrong file;
//! - width and height in ASCII decimal, at most [`MAX_IMAGE_SIDE`] each, checked before
//!   anything is allocated;
//! - a scale whose sign gives the byte order (negative: little-endian, positive: big-endian);
//!   its magnitude is not applied (Middlebury and ETH3D write 1), `gt_scale` is the divisor;
//! - one whitespace byte, then exactly `width * height` float32s, rows from the bottom of the
//!   image up. Values are returned as stored, `inf` and NaN included.
//!
//! Errors say what is wrong and never panic; [`load`] adds the file's name.

use std::path::Path;

use anyhow::{bail, ensure, Context, Result};

use crate::io::image_io::MAX_IMAGE_SIDE;

/// A one-channel float image, row-major, top row first.
#[derive(Debug, Clone, PartialEq)]
pub struct FloatImage {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// `width * height` values as stored, top row first.
    pub values: Vec<f32>,
}

/// Reads the PFM file `path` (the command's `what`, e.g. "ground truth"); every error names it.
pub fn load(path: &Path, what: &str) -> Result<FloatImage> {
    let bytes = crate::io::files::read(path, what)?;
    decode(&bytes).with_context(|| format!("cannot decode {what} {} (PFM)", path.display()))
}

/// Decodes the bytes of a grayscale PFM file.
pub fn decode(bytes: &[u8]) -> Result<FloatImage> {
    let mut header = Header { bytes, pos: 0 };
    match header.token() {
        Some(b"Pf") => {}
        Some(b"PF") => bail!("colour PFM (PF): a disparity map has one channel (Pf)"),
        _ => bail!("not a PFM file (it must start with Pf)"),
    }
    let width = header.number::<u32>("width")?;
    let height = header.number::<u32>("height")?;
    ensure!(width > 0 && height > 0, "empty image ({width}x{height})");
    ensure!(
        width <= MAX_IMAGE_SIDE && height <= MAX_IMAGE_SIDE,
        "declares {width}x{height} pixels, more than the {MAX_IMAGE_SIDE}x{MAX_IMAGE_SIDE} limit"
    );
    let scale = header.number::<f32>("scale")?;
    ensure!(
        scale.is_finite() && scale != 0.0,
        "scale {scale} gives no byte order (it must be a non-zero number)"
    );
    let little_endian = scale < 0.0;
    // The scale ends with exactly one whitespace byte; the pixels follow.
    match bytes.get(header.pos) {
        Some(b) if b.is_ascii_whitespace() => header.pos += 1,
        _ => bail!("truncated header (no line end after the scale)"),
    }
    let (width, height) = (width as usize, height as usize);
    let need = width * height * 4;
    let data = &bytes[header.pos..];
    ensure!(
        data.len() >= need,
        "truncated: {} bytes of pixels, {width}x{height} needs {need}",
        data.len()
    );
    ensure!(
        data.len() == need,
        "{} bytes after the {width}x{height} pixels (wrong size in the header?)",
        data.len() - need
    );
    let float = |c: &[u8]| {
        let b = [c[0], c[1], c[2], c[3]];
        if little_endian {
            f32::from_le_bytes(b)
        } else {
            f32::from_be_bytes(b)
        }
    };
    // Stored bottom row first: reversing the rows gives top-first.
    let values = data
        .chunks_exact(width * 4)
        .rev()
        .flat_map(|row| row.chunks_exact(4).map(float))
        .collect();
    Ok(FloatImage { width, height, values })
}

/// The header's whitespace-separated tokens, read from the front.
struct Header<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Header<'a> {
    /// The next token, or `None` at the end of the file. The whitespace after it is not consumed.
    fn token(&mut self) -> Option<&'a [u8]> {
        let rest = &self.bytes[self.pos..];
        let start = rest.iter().position(|b| !b.is_ascii_whitespace())?;
        let len = rest[start..]
            .iter()
            .position(|b| b.is_ascii_whitespace())
            .unwrap_or(rest.len() - start);
        self.pos += start + len;
        Some(&rest[start..start + len])
    }

    /// The next token as a number; `what` names it in errors.
    fn number<T: std::str::FromStr>(&mut self, what: &str) -> Result<T> {
        let token = self.token().with_context(|| format!("truncated header (no {what})"))?;
        let text = std::str::from_utf8(token).ok();
        match text.and_then(|t| t.parse().ok()) {
            Some(value) => Ok(value),
            None => bail!("bad {what} {:?} in the header", String::from_utf8_lossy(token)),
        }
    }
}

/// A PFM of `rows` (top row first) in the given byte order, for tests.
#[cfg(test)]
pub(crate) fn encode(rows: &[&[f32]], little_endian: bool) -> Vec<u8> {
    let scale = if little_endian { "-1.0" } else { "1.0" };
    let mut bytes = format!("Pf\n{} {}\n{scale}\n", rows[0].len(), rows.len()).into_bytes();
    for row in rows.iter().rev() {
        for v in *row {
            bytes.extend(if little_endian {
                v.to_le_bytes()
            } else {
                v.to_be_bytes()
            });
        }
    }
    bytes
}

#[cfg(test)]
mod tests {
    use super::*;

    fn err(bytes: &[u8]) -> String {
        format!("{:#}", decode(bytes).unwrap_err())
    }

    #[test]
    fn both_byte_orders_give_rows_top_first() {
        // Asymmetric in both axes, so a flip or a transpose would show.
        let rows: [&[f32]; 2] = [&[1.0, 2.5, f32::INFINITY], &[-0.5, 7.0, 1e6]];
        for little_endian in [true, false] {
            let image = decode(&encode(&rows, little_endian)).unwrap();
            assert_eq!((image.width, image.height), (3, 2));
            assert_eq!(image.values, rows.concat(), "little-endian {little_endian}");
        }
    }

    #[test]
    fn reads_what_bino_run_writes() {
        let map = crate::eval::DisparityMap {
            width: 2,
            height: 3,
            values: vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0],
        };
        let image = decode(&crate::run::pfm_bytes(&map)).unwrap();
        assert_eq!((image.width, image.height, image.values), (2, 3, map.values));
    }

    #[test]
    fn header_spacing_may_vary() {
        let mut bytes = b"Pf 1  2\r\n-1 ".to_vec();
        bytes.extend(3f32.to_le_bytes());
        bytes.extend(4f32.to_le_bytes());
        assert_eq!(decode(&bytes).unwrap().values, vec![4.0, 3.0]);
    }

    #[test]
    fn malformed_files_are_refused_with_the_problem() {
        let good = encode(&[&[1.0, 2.0], &[3.0, 4.0]], true);
        let cases: [(&[u8], &str); 11] = [
            (b"P5\n2 2\n255\n", "not a PFM file"),
            (b"PF\n1 1\n-1\n\0\0\0\0\0\0\0\0\0\0\0\0", "colour PFM"),
            (b"Pf\n", "no width"),
            (b"Pf\n2", "no height"),
            (b"Pf\n2 x\n-1\n", "bad height \"x\""),
            (b"Pf\n-2 2\n-1\n", "bad width \"-2\""),
            (b"Pf\n0 2\n-1\n", "empty image (0x2)"),
            (b"Pf\n100000 100000\n-1\n\0\0\0\0", "declares 100000x100000 pixels"),
            (b"Pf\n2 2\n0\n", "gives no byte order"),
            (b"Pf\n2 2\n-1", "no line end after the scale"),
            (&good[..good.len() - 3], "truncated: 13 bytes of pixels, 2x2 needs 16"),
        ];
        for (bytes, needle) in cases {
            let e = err(bytes);
            assert!(e.contains(needle), "{needle}: {e}");
        }
        let mut long = good.clone();
        long.push(0);
        assert!(err(&long).contains("1 bytes after the 2x2 pixels"));
        assert!(err(b"Pf\n99999999999 1\n-1\n").contains("bad width"));
    }
}
