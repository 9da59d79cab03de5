//! A small blob built by hand, byte by byte, independently of the host writer.

use super::*;
use crate::crc32::crc32;

const I8_ID: TensorId = TensorId::new(10, 0);
const I32_ID: TensorId = TensorId::new(11, 7);
const U16_ID: TensorId = TensorId::new(1, 0);

/// Header, three table entries (ending at 80), tensors at 80, 96 and 112, CRC at 114.
const LEN: usize = 118;
const CRC_AT: usize = LEN - 4;

fn put(buf: &mut [u8], at: usize, bytes: &[u8]) {
    buf[at..at + bytes.len()].copy_from_slice(bytes);
}

fn entry(buf: &mut [u8], index: usize, id: TensorId, dtype: u8, elements: u32, offset: u32) {
    let at = 32 + 16 * index;
    put(buf, at, &id.0.to_le_bytes());
    put(buf, at + 4, &[dtype, 0, 0, 0]);
    put(buf, at + 8, &elements.to_le_bytes());
    put(buf, at + 12, &offset.to_le_bytes());
}

fn seal(buf: &mut [u8; LEN]) {
    let crc = crc32(&buf[..CRC_AT]);
    put(buf, CRC_AT, &crc.to_le_bytes());
}

fn blob_bytes() -> [u8; LEN] {
    let mut buf = [0u8; LEN];
    put(&mut buf, 0, b"BINOQ8\r\n");
    put(&mut buf, 8, &1u16.to_le_bytes());
    put(&mut buf, 10, &32u16.to_le_bytes());
    put(&mut buf, 12, &3u16.to_le_bytes());
    put(&mut buf, 14, &16u16.to_le_bytes());
    put(&mut buf, 16, &(LEN as u32).to_le_bytes());
    entry(&mut buf, 0, I8_ID, 1, 3, 80);
    entry(&mut buf, 1, I32_ID, 5, 2, 96);
    entry(&mut buf, 2, U16_ID, 4, 1, 112);
    put(&mut buf, 80, &[1, 0xFE, 3]);
    put(&mut buf, 96, &(-5i32).to_le_bytes());
    put(&mut buf, 100, &0x0102_0304i32.to_le_bytes());
    put(&mut buf, 112, &7u16.to_le_bytes());
    seal(&mut buf);
    buf
}

fn parse_modified(change: impl FnOnce(&mut [u8; LEN])) -> Result<(), BlobError> {
    let mut buf = blob_bytes();
    change(&mut buf);
    seal(&mut buf);
    Blob::parse(&buf).map(|_| ())
}

#[test]
fn parses_and_reads_every_tensor() -> Result<(), BlobError> {
    let bytes = blob_bytes();
    let blob = Blob::parse(&bytes)?;
    assert_eq!((blob.version(), blob.total_len(), blob.tensor_count()), (1, LEN, 3));
    let mut tensors = blob.tensors();
    assert_eq!(
        tensors.next(),
        Some(TensorInfo {
            id: I8_ID,
            dtype: Dtype::I8,
            elements: 3,
            offset: 80
        })
    );
    assert_eq!(
        tensors.next(),
        Some(TensorInfo {
            id: I32_ID,
            dtype: Dtype::I32,
            elements: 2,
            offset: 96
        })
    );
    assert_eq!(
        tensors.next(),
        Some(TensorInfo {
            id: U16_ID,
            dtype: Dtype::U16,
            elements: 1,
            offset: 112
        })
    );
    assert_eq!(tensors.next(), None);

    assert_eq!(blob.i8s(I8_ID, 3)?, &[1, -2, 3]);
    let words = blob.i32s(I32_ID, 2)?;
    assert_eq!(
        (words.len(), words.get(0), words.get(1), words.get(2)),
        (2, Some(-5), Some(0x0102_0304), None)
    );
    assert_eq!((words.at(1), words.at(2), words.at(usize::MAX)), (0x0102_0304, 0, 0));
    let mut values = words.iter();
    assert_eq!(
        (values.next(), values.next(), values.next()),
        (Some(-5), Some(0x0102_0304), None)
    );
    assert_eq!(blob.u16s(U16_ID, 1)?.get(0), Some(7));
    assert_eq!(blob.raw(I32_ID)?, (Dtype::I32, &bytes[96..104]));
    Ok(())
}

#[test]
fn lookups_check_id_type_and_length() -> Result<(), BlobError> {
    let bytes = blob_bytes();
    let blob = Blob::parse(&bytes)?;
    let missing = TensorId::new(10, 1);
    assert_eq!(blob.i8s(missing, 3), Err(BlobError::MissingTensor { id: missing }));
    let wrong_type = BlobError::WrongDtype {
        id: I32_ID,
        expected: Dtype::U32,
        found: Dtype::I32,
    };
    assert_eq!(blob.u32s(I32_ID, 2).err(), Some(wrong_type));
    let wrong_len = BlobError::WrongLength {
        id: I8_ID,
        expected: 4,
        found: 3,
    };
    assert_eq!(blob.i8s(I8_ID, 4), Err(wrong_len));
    Ok(())
}

#[test]
fn parses_at_any_offset() -> Result<(), BlobError> {
    let mut buf = [0u8; LEN + 3];
    put(&mut buf, 3, &blob_bytes());
    let blob = Blob::parse(&buf[3..])?;
    assert_eq!(blob.i32s(I32_ID, 2)?.get(1), Some(0x0102_0304));
    Ok(())
}

#[test]
fn rejects_bad_lengths_and_corruption() {
    let bytes = blob_bytes();
    assert_eq!(Blob::parse(&bytes[..31]).err(), Some(BlobError::TooShort { len: 31 }));
    assert_eq!(
        Blob::parse(&bytes[..LEN - 1]).err(),
        Some(BlobError::Truncated {
            expected: LEN,
            actual: LEN - 1
        })
    );
    let mut longer = [0u8; LEN + 1];
    put(&mut longer, 0, &bytes);
    assert_eq!(
        Blob::parse(&longer).err(),
        Some(BlobError::TrailingBytes {
            expected: LEN,
            actual: LEN + 1
        })
    );
    let mut corrupt = bytes;
    corrupt[81] ^= 0x10;
    assert!(matches!(Blob::parse(&corrupt), Err(BlobError::ChecksumMismatch { .. })));
}

#[test]
fn rejects_bad_headers_even_with_a_valid_crc() {
    assert_eq!(parse_modified(|b| b[0] = b'X'), Err(BlobError::BadMagic));
    let newer = BlobError::UnsupportedVersion {
        found: 2,
        supported: FORMAT_VERSION,
    };
    assert_eq!(parse_modified(|b| b[8] = 2), Err(newer));
    assert_eq!(parse_modified(|b| b[10] = 48), Err(BlobError::BadHeader));
    assert_eq!(parse_modified(|b| b[14] = 8), Err(BlobError::BadHeader));
    assert_eq!(parse_modified(|b| b[31] = 1), Err(BlobError::BadHeader));
}

#[test]
fn rejects_bad_table_entries_even_with_a_valid_crc() {
    assert_eq!(
        parse_modified(|b| b[12] = 6),
        Err(BlobError::TableTooLarge { tensor_count: 6 })
    );
    assert_eq!(
        parse_modified(|b| b[36] = 9),
        Err(BlobError::UnknownDtype { entry: 0, code: 9 })
    );
    assert_eq!(parse_modified(|b| b[53] = 1), Err(BlobError::BadTable { entry: 1 }));
    assert_eq!(
        parse_modified(|b| entry(b, 1, I32_ID, 5, 2, 97)),
        Err(BlobError::BadTable { entry: 1 })
    );
    // Starts inside the table.
    let inside_table = parse_modified(|b| entry(b, 1, I32_ID, 5, 2, 64));
    assert_eq!(inside_table, Err(BlobError::TensorOutOfBounds { id: I32_ID }));
    // Overlaps the CRC.
    assert_eq!(
        parse_modified(|b| entry(b, 2, U16_ID, 4, 2, 112)),
        Err(BlobError::TensorOutOfBounds { id: U16_ID })
    );
    // `elements x 8` overflows 32 bits.
    let huge = parse_modified(|b| entry(b, 1, I32_ID, 7, u32::MAX, 96));
    assert_eq!(huge, Err(BlobError::TensorOutOfBounds { id: I32_ID }));
    assert_eq!(
        parse_modified(|b| entry(b, 2, I8_ID, 4, 1, 112)),
        Err(BlobError::DuplicateTensor { id: I8_ID })
    );
}

#[test]
fn converts_into_the_crate_error() {
    let error: crate::Error = BlobError::BadMagic.into();
    assert_eq!(error, crate::Error::Blob(BlobError::BadMagic));
}
