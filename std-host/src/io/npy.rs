//! `.npy` arrays of `f32` in C order, through `npyz`: the one array format the CLI writes, so
//! every output opens with `numpy.load`.

use anyhow::{ensure, Context, Result};
use npyz::{NpyFile, Order, WriterBuilder};

/// A dense `f32` array with its shape, in C (row-major) order.
#[derive(Debug, Clone, PartialEq)]
pub struct Array {
    /// Extent of each axis.
    pub shape: Vec<usize>,
    /// `shape.iter().product()` values.
    pub data: Vec<f32>,
}

impl Array {
    /// Wraps `data` as an array of `shape`; fails when the sizes disagree.
    pub fn new(shape: Vec<usize>, data: Vec<f32>) -> Result<Self> {
        let expected: usize = shape.iter().product();
        ensure!(
            expected == data.len(),
            "array of shape {shape:?} needs {expected} values, got {}",
            data.len()
        );
        Ok(Self { shape, data })
    }
}

/// Encodes `array` as the bytes of a `.npy` file (little-endian `f32`, format 1.0).
pub fn encode(array: &Array) -> Vec<u8> {
    let mut out = Vec::new();
    write(&mut out, array).expect("writing to memory cannot fail");
    out
}

/// Writes `array` as a `.npy` file to `out`.
pub fn write<W: std::io::Write>(out: W, array: &Array) -> std::io::Result<()> {
    let shape: Vec<u64> = array.shape.iter().map(|&d| d as u64).collect();
    let mut writer = npyz::WriteOptions::new()
        .default_dtype()
        .shape(&shape)
        .writer(out)
        .begin_nd()?;
    writer.extend(array.data.iter().copied())?;
    writer.finish()
}

/// Decodes a `.npy` file of `f32` values in C order; the payload must be exactly the shape's.
pub fn decode(bytes: &[u8]) -> Result<Array> {
    let file = NpyFile::new(bytes).context("not a .npy file")?;
    ensure!(file.order() == Order::C, "only C-order arrays are supported");
    let shape = (file.shape().iter())
        .map(|&d| usize::try_from(d).context("bad .npy dimension"))
        .collect::<Result<Vec<_>>>()?;
    // npyz reads the elements it needs and ignores the rest: a longer file is not ours.
    let payload = file.clone().into_inner().len() as u64;
    let wanted = file.len().checked_mul(4).context(".npy shape too large")?;
    ensure!(
        payload == wanted,
        ".npy payload holds {payload} bytes, shape {shape:?} needs {wanted}"
    );
    let dtype = file.dtype().descr();
    let data = (file.into_vec::<f32>()).with_context(|| format!("only f32 arrays are supported, found {dtype}"))?;
    Array::new(shape, data)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_and_aligns_data() {
        for shape in [vec![3], vec![2, 3], vec![2, 1, 4]] {
            let n = shape.iter().product();
            let array = Array::new(shape, (0..n).map(|i| i as f32 * 0.5 - 1.0).collect()).unwrap();
            let bytes = encode(&array);
            assert_eq!((bytes.len() - 4 * n) % 16, 0, "data must start 16-byte aligned");
            assert_eq!(decode(&bytes).unwrap(), array);
        }
    }

    #[test]
    fn rejects_truncated_and_foreign_files() {
        let bytes = encode(&Array::new(vec![4], vec![1.0; 4]).unwrap());
        assert!(decode(&bytes[..bytes.len() - 1]).is_err());
        assert!(decode(b"PK\x03\x04 not npy").is_err());
        let f64_file = String::from_utf8_lossy(&bytes).replace("<f4", "<f8").into_bytes();
        assert!(decode(&f64_file).is_err());
        assert!(Array::new(vec![2, 2], vec![0.0; 3]).is_err());
    }
}
