//! `.npy` arrays (format version 1.0, little-endian `f32`, C order): the one array format
//! the CLI writes, so every output opens with `numpy.load`.

use anyhow::{bail, ensure, Context, Result};

const MAGIC: &[u8] = b"\x93NUMPY";

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

/// Encodes `array` as the bytes of a `.npy` file.
pub fn encode(array: &Array) -> Vec<u8> {
    let dims: Vec<String> = array.shape.iter().map(|d| d.to_string()).collect();
    let shape = match dims.len() {
        1 => format!("({},)", dims[0]),
        _ => format!("({})", dims.join(", ")),
    };
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape}, }}");
    // The data must start on a 64-byte boundary: pad with spaces, end with a newline.
    let unpadded = MAGIC.len() + 4 + header.len() + 1;
    header.push_str(&" ".repeat((64 - unpadded % 64) % 64));
    header.push('\n');
    let mut out = Vec::with_capacity(MAGIC.len() + 4 + header.len() + 4 * array.data.len());
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for value in &array.data {
        out.extend_from_slice(&value.to_le_bytes());
    }
    out
}

/// Decodes a `.npy` file holding little-endian `f32` values in C order.
pub fn decode(bytes: &[u8]) -> Result<Array> {
    ensure!(
        bytes.len() >= 10 && bytes.starts_with(MAGIC),
        "not a .npy file (bad magic)"
    );
    let (header_len, header_start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            ensure!(bytes.len() >= 12, "truncated .npy header");
            let len = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize;
            (len, 12)
        }
        v => bail!("unsupported .npy format version {v}"),
    };
    let header = bytes
        .get(header_start..header_start + header_len)
        .context("truncated .npy header")?;
    let header = std::str::from_utf8(header).context(".npy header is not text")?;
    ensure!(
        header.contains("'descr': '<f4'"),
        "only little-endian f32 arrays are supported: {header}"
    );
    ensure!(
        header.contains("'fortran_order': False"),
        "only C-order arrays are supported"
    );
    let shape = parse_shape(header)?;
    let count: usize = shape.iter().product();
    let payload = &bytes[header_start + header_len..];
    ensure!(
        payload.len() == 4 * count,
        ".npy payload holds {} bytes, shape {shape:?} needs {}",
        payload.len(),
        4 * count
    );
    let data = payload
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    Array::new(shape, data)
}

fn parse_shape(header: &str) -> Result<Vec<usize>> {
    let start = header.find("'shape': (").context(".npy header has no shape")? + "'shape': (".len();
    let end = start + header[start..].find(')').context(".npy shape is not closed")?;
    header[start..end]
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse::<usize>().with_context(|| format!("bad .npy dimension {s:?}")))
        .collect()
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
            assert_eq!((bytes.len() - 4 * n) % 64, 0, "data must start 64-byte aligned");
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
