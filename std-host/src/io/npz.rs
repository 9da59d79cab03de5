//! `.npz` archives: a ZIP of `.npy` members, stored uncompressed, as `numpy.savez` writes them.
//! `npyz`'s own `npz` feature would pull `zip` 0.6 with every compression codec (C builds of
//! bzip2 and zstd); stored members need only `zip` without its default features.

use std::io::{Cursor, Read, Write};

use anyhow::{ensure, Context, Result};
use npyz::npz::{array_name_from_file_name, file_name_from_array_name};
use zip::write::SimpleFileOptions;
use zip::{CompressionMethod, ZipArchive, ZipWriter};

use crate::io::npy::{self, Array};

/// Writes `arrays` as members `NAME.npy` of a stored (uncompressed) ZIP archive.
pub fn write<W: Write>(mut out: W, arrays: &[(&str, &Array)]) -> Result<()> {
    // The ZIP writer seeks back to fill in sizes: build the archive in memory.
    let mut zip = ZipWriter::new(Cursor::new(Vec::new()));
    let options = SimpleFileOptions::default()
        .compression_method(CompressionMethod::Stored)
        .large_file(false);
    for (name, array) in arrays {
        zip.start_file(file_name_from_array_name(name), options)?;
        npy::write(&mut zip, array).with_context(|| format!("array {name}"))?;
    }
    out.write_all(&zip.finish()?.into_inner())?;
    Ok(())
}

/// Reads every member of a `.npz` archive in archive order, checking each member's checksum.
pub fn read(bytes: &[u8]) -> Result<Vec<(String, Array)>> {
    let mut zip = ZipArchive::new(Cursor::new(bytes)).context("not a .npz archive")?;
    let mut arrays = Vec::with_capacity(zip.len());
    for i in 0..zip.len() {
        let mut member = zip.by_index(i).context("corrupt .npz archive")?;
        let name = member.name().context("bad .npz member name")?.to_string();
        let name = array_name_from_file_name(&name).unwrap_or(&name).to_string();
        let mut data = Vec::new();
        member
            .read_to_end(&mut data)
            .with_context(|| format!("member {name}"))?;
        let array = npy::decode(&data).with_context(|| format!("member {name}"))?;
        arrays.push((name, array));
    }
    ensure!(!arrays.is_empty(), "empty .npz archive");
    Ok(arrays)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips_named_arrays() {
        let a = Array::new(vec![2, 2], vec![1.0, 2.0, 3.0, 4.0]).unwrap();
        let b = Array::new(vec![3], vec![-1.0, 0.0, 1.0]).unwrap();
        let mut bytes = Vec::new();
        write(&mut bytes, &[("a", &a), ("b", &b)]).unwrap();
        let back = read(&bytes).unwrap();
        assert_eq!(back, vec![("a".to_string(), a), ("b".to_string(), b)]);
    }

    #[test]
    fn detects_corruption_and_truncation() {
        let a = Array::new(vec![8], vec![0.25; 8]).unwrap();
        let mut bytes = Vec::new();
        write(&mut bytes, &[("a", &a)]).unwrap();
        // The member's last value byte sits just before the central directory.
        let central = bytes.windows(4).position(|w| w == b"PK\x01\x02").unwrap();
        let mut corrupt = bytes.clone();
        corrupt[central - 1] ^= 0xff;
        let err = format!("{:#}", read(&corrupt).unwrap_err());
        assert!(err.contains("checksum"), "{err}");
        assert!(read(&bytes[..60]).is_err());
    }
}
