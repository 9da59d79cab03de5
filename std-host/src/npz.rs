//! `.npz` archives: a ZIP of `.npy` members, stored uncompressed, as `numpy.savez` writes them.
//! Only what the CLI needs: writing named arrays and reading them back.

use std::io::Write;

use anyhow::{ensure, Context, Result};

use crate::npy::{self, Array};

const LOCAL_HEADER: u32 = 0x0403_4b50;
const CENTRAL_HEADER: u32 = 0x0201_4b50;
const END_OF_CENTRAL: u32 = 0x0605_4b50;

/// Writes `arrays` as members `NAME.npy` of a stored (uncompressed) ZIP archive.
pub fn write<W: Write>(mut out: W, arrays: &[(&str, &Array)]) -> Result<()> {
    let mut central = Vec::new();
    let mut offset = 0usize;
    for (name, array) in arrays {
        let member = format!("{name}.npy");
        let data = npy::encode(array);
        ensure!(
            data.len() < u32::MAX as usize && offset < u32::MAX as usize,
            "array {name} is too large for a ZIP32 archive"
        );
        let crc = crc32fast::hash(&data);
        let mut local = Vec::new();
        local.extend_from_slice(&LOCAL_HEADER.to_le_bytes());
        push_common(&mut local, crc, data.len() as u32, member.len() as u16);
        local.extend_from_slice(member.as_bytes());
        out.write_all(&local)?;
        out.write_all(&data)?;

        central.extend_from_slice(&CENTRAL_HEADER.to_le_bytes());
        central.extend_from_slice(&20u16.to_le_bytes()); // made by: version 2.0
        push_common(&mut central, crc, data.len() as u32, member.len() as u16);
        central.extend_from_slice(&[0; 6]); // comment length, disk, internal attributes
        central.extend_from_slice(&0u32.to_le_bytes()); // external attributes
        central.extend_from_slice(&(offset as u32).to_le_bytes());
        central.extend_from_slice(member.as_bytes());
        offset += local.len() + data.len();
    }
    let mut end = Vec::new();
    end.extend_from_slice(&END_OF_CENTRAL.to_le_bytes());
    end.extend_from_slice(&[0; 4]); // disk numbers
    end.extend_from_slice(&(arrays.len() as u16).to_le_bytes());
    end.extend_from_slice(&(arrays.len() as u16).to_le_bytes());
    end.extend_from_slice(&(central.len() as u32).to_le_bytes());
    end.extend_from_slice(&(offset as u32).to_le_bytes());
    end.extend_from_slice(&0u16.to_le_bytes());
    out.write_all(&central)?;
    out.write_all(&end)?;
    Ok(())
}

// The fields local and central headers share, from "version needed" to "extra length".
fn push_common(buf: &mut Vec<u8>, crc: u32, size: u32, name_len: u16) {
    buf.extend_from_slice(&20u16.to_le_bytes()); // version needed
    buf.extend_from_slice(&0u16.to_le_bytes()); // flags
    buf.extend_from_slice(&0u16.to_le_bytes()); // method: stored
    buf.extend_from_slice(&[0, 0, 0x21, 0]); // time 00:00, date 1980-01-01
    buf.extend_from_slice(&crc.to_le_bytes());
    buf.extend_from_slice(&size.to_le_bytes());
    buf.extend_from_slice(&size.to_le_bytes());
    buf.extend_from_slice(&name_len.to_le_bytes());
    buf.extend_from_slice(&0u16.to_le_bytes()); // extra length
}

/// Reads every member of a stored `.npz` archive, in archive order, through its central
/// directory (as `numpy.load` does), checking each member's checksum.
pub fn read(bytes: &[u8]) -> Result<Vec<(String, Array)>> {
    ensure!(bytes.len() >= 22, "not a .npz archive (too short)");
    let end = bytes.len() - 22;
    ensure!(
        u32_at(bytes, end)? == END_OF_CENTRAL,
        "not a .npz archive (no end-of-directory record; comments unsupported)"
    );
    let count = u16_at(bytes, end + 10)? as usize;
    let mut pos = u32_at(bytes, end + 16)? as usize;
    let mut arrays = Vec::with_capacity(count);
    for _ in 0..count {
        ensure!(
            u32_at(bytes, pos)? == CENTRAL_HEADER,
            "corrupt .npz central directory at byte {pos}"
        );
        let name_len = u16_at(bytes, pos + 28)? as usize;
        let skip = name_len + u16_at(bytes, pos + 30)? as usize + u16_at(bytes, pos + 32)? as usize;
        let local = u32_at(bytes, pos + 42)? as usize;
        arrays.push(read_member(bytes, local)?);
        pos += 46 + skip;
    }
    ensure!(!arrays.is_empty(), "empty .npz archive");
    Ok(arrays)
}

fn read_member(bytes: &[u8], pos: usize) -> Result<(String, Array)> {
    ensure!(
        u32_at(bytes, pos)? == LOCAL_HEADER,
        "corrupt .npz member header at byte {pos}"
    );
    let method = u16_at(bytes, pos + 8)?;
    let crc = u32_at(bytes, pos + 14)?;
    let size = u32_at(bytes, pos + 18)? as usize;
    let name_len = u16_at(bytes, pos + 26)? as usize;
    let extra_len = u16_at(bytes, pos + 28)? as usize;
    ensure!(
        method == 0,
        "member at byte {pos} is compressed; only stored .npz archives are supported"
    );
    let name_start = pos + 30;
    let data_start = name_start + name_len + extra_len;
    let name = bytes
        .get(name_start..name_start + name_len)
        .context("truncated .npz member name")?;
    let data = bytes
        .get(data_start..data_start + size)
        .context("truncated .npz member")?;
    ensure!(
        crc32fast::hash(data) == crc,
        "checksum mismatch in .npz member at byte {pos}"
    );
    let name = String::from_utf8_lossy(name);
    let name = name.strip_suffix(".npy").unwrap_or(&name).to_string();
    let array = npy::decode(data).with_context(|| format!("member {name}"))?;
    Ok((name, array))
}

fn u16_at(bytes: &[u8], at: usize) -> Result<u16> {
    let b = bytes.get(at..at + 2).context("truncated .npz archive")?;
    Ok(u16::from_le_bytes([b[0], b[1]]))
}

fn u32_at(bytes: &[u8], at: usize) -> Result<u32> {
    let b = bytes.get(at..at + 4).context("truncated .npz archive")?;
    Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
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
        let mut corrupt = bytes.clone();
        let last_data = corrupt.len() - 200;
        corrupt[last_data] ^= 0xff;
        assert!(read(&corrupt).is_err());
        assert!(read(&bytes[..60]).is_err());
    }
}
