//! The writer against the `bino-core` reader: round trips, the exact layout, and every way a
//! damaged blob must be rejected (never a panic).

use super::*;
use bino_core::blob::{Blob, BlobError};

const ID_I8: TensorId = TensorId::new(10, 0);
const ID_U8: TensorId = TensorId::new(13, 0);
const ID_EMPTY: TensorId = TensorId::new(13, 1);
const ID_I16: TensorId = TensorId::new(33, 0);
const ID_U16: TensorId = TensorId::new(1, 0);
const ID_I32: TensorId = TensorId::new(11, 2);
const ID_U32: TensorId = TensorId::new(2, 5);
const ID_I64: TensorId = TensorId::new(30, 1);
const ID_F32: TensorId = TensorId::new(60, 0);

const I8S: [i8; 5] = [i8::MIN, -1, 0, 1, i8::MAX];
const U8S: [u8; 4] = [0, 1, 254, 255];
const I16S: [i16; 5] = [i16::MIN, -2, 0, 0x1234, i16::MAX];
const U16S: [u16; 3] = [0, 0xBEEF, u16::MAX];
const U32S: [u32; 2] = [0xDEAD_BEEF, u32::MAX];
const I64S: [i64; 3] = [i64::MIN, -0x0102_0304_0506_0708, i64::MAX];
const F32S: [f32; 4] = [0.0, -1.5, f32::MAX, f32::MIN_POSITIVE];

fn i32s() -> Vec<i32> {
    (0..37)
        .map(|i: i32| i.wrapping_mul(-0x0101_0101).wrapping_add(i32::MIN / 3))
        .collect()
}

/// One tensor of every dtype plus an empty one, inserted out of id order.
fn full_blob() -> Result<Vec<u8>> {
    let mut w = BlobWriter::new();
    w.add_i8(ID_I8, &I8S)?.add_u8(ID_U8, &U8S)?.add_u8(ID_EMPTY, &[])?;
    w.add_i16(ID_I16, &I16S)?
        .add_u16(ID_U16, &U16S)?
        .add_i32(ID_I32, &i32s())?;
    w.add_u32(ID_U32, &U32S)?
        .add_i64(ID_I64, &I64S)?
        .add_f32(ID_F32, &F32S)?;
    Ok(w.finish())
}

/// Header, 3 table entries (to 80), i8[3] at 80, i32[2] at 96, u16[1] at 112, CRC at 114.
fn small_blob() -> Result<Vec<u8>> {
    let mut w = BlobWriter::new();
    w.add_i8(ID_I8, &[1, -2, 3])?
        .add_i32(ID_I32, &[-5, 0x0102_0304])?
        .add_u16(ID_U16, &[7])?;
    Ok(w.finish())
}

/// Recomputes the CRC after a deliberate change, so the parse reaches the later checks.
fn reseal(blob: &mut [u8]) {
    let crc_at = blob.len() - 4;
    let crc = crc32fast::hash(&blob[..crc_at]);
    blob[crc_at..].copy_from_slice(&crc.to_le_bytes());
}

fn u32_at(bytes: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"))
}

#[test]
fn blob_round_trip_of_every_dtype() -> Result<()> {
    let bytes = full_blob()?;
    let blob = Blob::parse(&bytes)?;
    assert_eq!(blob.tensor_count(), 9);
    assert_eq!(blob.i8s(ID_I8, I8S.len())?, &I8S);
    assert_eq!(blob.u8s(ID_U8, U8S.len())?, &U8S);
    assert_eq!(blob.u8s(ID_EMPTY, 0)?, &[] as &[u8]);
    assert_eq!(blob.i16s(ID_I16, I16S.len())?.iter().collect::<Vec<_>>(), I16S);
    assert_eq!(blob.u16s(ID_U16, U16S.len())?.iter().collect::<Vec<_>>(), U16S);
    assert_eq!(blob.i32s(ID_I32, 37)?.iter().collect::<Vec<_>>(), i32s());
    assert_eq!(blob.u32s(ID_U32, U32S.len())?.iter().collect::<Vec<_>>(), U32S);
    assert_eq!(blob.i64s(ID_I64, I64S.len())?.iter().collect::<Vec<_>>(), I64S);
    let floats = blob
        .f32s(ID_F32, F32S.len())?
        .iter()
        .map(f32::to_bits)
        .collect::<Vec<_>>();
    assert_eq!(floats, F32S.map(f32::to_bits));
    assert_eq!(format!("{:?}", blob.u16s(ID_U16, 3)?), "[0, 48879, 65535]");
    assert_eq!(
        format!("{blob:?}"),
        format!("Blob {{ total_len: {}, tensor_count: 9, .. }}", bytes.len())
    );
    let (dtype, raw) = blob.raw(ID_I64)?;
    assert_eq!((dtype, raw.len()), (Dtype::I64, 24));
    assert_eq!(raw[..8], i64::MIN.to_le_bytes());
    Ok(())
}

#[test]
fn blob_layout_follows_the_spec() -> Result<()> {
    let bytes = full_blob()?;
    assert_eq!(&bytes[..8], b"BINOQ8\r\n");
    assert_eq!(bytes[8..16], [1, 0, 32, 0, 9, 0, 16, 0]);
    assert_eq!(u32_at(&bytes, 16) as usize, bytes.len());
    assert!(bytes[20..32].iter().all(|&b| b == 0));
    let crc_at = bytes.len() - 4;
    assert_eq!(u32_at(&bytes, crc_at), crc32fast::hash(&bytes[..crc_at]));

    // Table in insertion order, offsets 16-aligned, tightly packed, zero padding in between.
    let blob = Blob::parse(&bytes)?;
    let ids: Vec<TensorId> = blob.tensors().map(|t| t.id).collect();
    assert_eq!(
        ids,
        [ID_I8, ID_U8, ID_EMPTY, ID_I16, ID_U16, ID_I32, ID_U32, ID_I64, ID_F32]
    );
    let table_end: usize = 32 + 9 * 16;
    let mut end = table_end;
    for t in blob.tensors() {
        assert_eq!(t.offset, end.next_multiple_of(16), "tensor {}", t.id);
        assert!(
            bytes[end..t.offset].iter().all(|&b| b == 0),
            "padding before tensor {}",
            t.id
        );
        end = t.offset + t.byte_len();
    }
    assert_eq!(end, crc_at);

    let empty = BlobWriter::new().finish();
    assert_eq!(empty.len(), 36);
    assert_eq!(Blob::parse(&empty)?.tensor_count(), 0);
    Ok(())
}

#[test]
fn blob_reads_from_a_misaligned_buffer() -> Result<()> {
    let bytes = full_blob()?;
    let mut buffer = vec![0u8; bytes.len() + 2];
    let start = if (buffer.as_ptr() as usize).is_multiple_of(2) {
        1
    } else {
        2
    };
    buffer[start..start + bytes.len()].copy_from_slice(&bytes);
    let shifted = &buffer[start..start + bytes.len()];
    assert_eq!(shifted.as_ptr() as usize % 2, 1);
    let blob = Blob::parse(shifted)?;
    let values = blob.i32s(ID_I32, 37)?;
    assert_eq!(values.iter().collect::<Vec<_>>(), i32s());
    assert_eq!(
        (values.get(36), values.at(5), values.get(37)),
        (i32s().get(36).copied(), i32s()[5], None)
    );
    assert_eq!(blob.i64s(ID_I64, 3)?.get(2), Some(i64::MAX));
    Ok(())
}

#[test]
fn blob_lookups_report_distinct_errors() -> Result<()> {
    let bytes = full_blob()?;
    let blob = Blob::parse(&bytes)?;
    let missing = TensorId::new(10, 1);
    assert_eq!(blob.i8s(missing, 5), Err(BlobError::MissingTensor { id: missing }));
    assert_eq!(blob.raw(missing), Err(BlobError::MissingTensor { id: missing }));
    let wrong_type = BlobError::WrongDtype {
        id: ID_I32,
        expected: Dtype::U32,
        found: Dtype::I32,
    };
    assert_eq!(blob.u32s(ID_I32, 37).err(), Some(wrong_type));
    let wrong_type = BlobError::WrongDtype {
        id: ID_U8,
        expected: Dtype::I8,
        found: Dtype::U8,
    };
    assert_eq!(blob.i8s(ID_U8, 4), Err(wrong_type));
    let wrong_len = BlobError::WrongLength {
        id: ID_I32,
        expected: 36,
        found: 37,
    };
    assert_eq!(blob.i32s(ID_I32, 36).err(), Some(wrong_len));
    Ok(())
}

#[test]
fn blob_writer_rejects_duplicate_ids() -> Result<()> {
    let mut w = BlobWriter::new();
    w.add_i8(ID_I8, &[1])?;
    assert!(w.add_i32(ID_I8, &[2]).is_err());
    assert_eq!(w.tensor_count(), 1);
    Ok(())
}

#[test]
fn blob_every_strict_prefix_is_rejected() -> Result<()> {
    let bytes = small_blob()?;
    for len in 0..bytes.len() {
        let expected = if len < 32 {
            BlobError::TooShort { len }
        } else {
            BlobError::Truncated {
                expected: bytes.len(),
                actual: len,
            }
        };
        assert_eq!(
            Blob::parse(&bytes[..len]).err(),
            Some(expected),
            "prefix of {len} bytes"
        );
    }
    Ok(())
}

/// The error a blob must give after a bit flip in its byte `at` (`flipped` is the damaged blob).
fn error_after_flip(flipped: &[u8], at: usize) -> BlobError {
    let len = flipped.len();
    match at {
        0..8 => BlobError::BadMagic,
        8..10 => {
            let found = u16::from_le_bytes([flipped[8], flipped[9]]);
            BlobError::UnsupportedVersion {
                found,
                supported: FORMAT_VERSION,
            }
        }
        10..12 | 14..16 | 20..32 => BlobError::BadHeader,
        16..20 => match u32_at(flipped, 16) as usize {
            total if total < 36 => BlobError::BadHeader,
            total if total > len => BlobError::Truncated {
                expected: total,
                actual: len,
            },
            total => BlobError::TrailingBytes {
                expected: total,
                actual: len,
            },
        },
        // Tensor count, table, payload and the CRC itself: caught by the CRC.
        _ => {
            let computed = crc32fast::hash(&flipped[..len - 4]);
            BlobError::ChecksumMismatch {
                stored: u32_at(flipped, len - 4),
                computed,
            }
        }
    }
}

#[test]
fn blob_every_single_bit_flip_is_rejected() -> Result<()> {
    let bytes = small_blob()?;
    assert_eq!(bytes.len(), 118);
    for at in 0..bytes.len() {
        for bit in 0..8 {
            let mut flipped = bytes.clone();
            flipped[at] ^= 1 << bit;
            let expected = error_after_flip(&flipped, at);
            assert_eq!(Blob::parse(&flipped).err(), Some(expected), "bit {bit} of byte {at}");
        }
    }
    // A few positions spelled out, so the classification above cannot drift unnoticed.
    let flip = |at: usize, mask: u8| {
        let mut b = bytes.clone();
        b[at] ^= mask;
        Blob::parse(&b).err()
    };
    assert_eq!(flip(3, 0x01), Some(BlobError::BadMagic));
    assert_eq!(
        flip(8, 0x02),
        Some(BlobError::UnsupportedVersion { found: 3, supported: 1 })
    );
    assert_eq!(flip(10, 0x01), Some(BlobError::BadHeader));
    assert_eq!(
        flip(16, 0x01),
        Some(BlobError::Truncated {
            expected: 119,
            actual: 118
        })
    );
    assert_eq!(
        flip(16, 0x02),
        Some(BlobError::TrailingBytes {
            expected: 116,
            actual: 118
        })
    );
    assert_eq!(
        flip(19, 0x80),
        Some(BlobError::Truncated {
            expected: 0x8000_0076,
            actual: 118
        })
    );
    assert!(matches!(flip(12, 0x01), Some(BlobError::ChecksumMismatch { .. })));
    assert!(matches!(flip(100, 0x80), Some(BlobError::ChecksumMismatch { .. })));
    Ok(())
}

#[test]
fn blob_of_another_version_is_unsupported_even_with_a_valid_crc() -> Result<()> {
    let mut bytes = small_blob()?;
    bytes[8] = 2;
    reseal(&mut bytes);
    let unsupported = Some(BlobError::UnsupportedVersion { found: 2, supported: 1 });
    assert_eq!(Blob::parse(&bytes).err(), unsupported);
    // A later version may change every size; the version still decides the error.
    bytes[10] = 64;
    bytes[14] = 24;
    bytes[16..20].copy_from_slice(&1_000_000u32.to_le_bytes());
    bytes[25] = 7;
    assert_eq!(Blob::parse(&bytes).err(), unsupported);
    assert_eq!(Blob::parse(&bytes[..40]).err(), unsupported);
    Ok(())
}

#[test]
fn blob_with_an_appended_byte_has_trailing_bytes() -> Result<()> {
    let mut bytes = small_blob()?;
    bytes.push(0);
    assert_eq!(
        Blob::parse(&bytes).err(),
        Some(BlobError::TrailingBytes {
            expected: 118,
            actual: 119
        })
    );
    Ok(())
}

#[test]
fn blob_table_errors_behind_a_valid_crc() -> Result<()> {
    let original = small_blob()?;
    let parse_changed = |change: &dyn Fn(&mut Vec<u8>)| {
        let mut bytes = original.clone();
        change(&mut bytes);
        reseal(&mut bytes);
        Blob::parse(&bytes).err()
    };
    // Entry 1 (the i32 tensor) starts at byte 48: id, dtype + 3 reserved, elements, offset.
    let set_u32 = |at: usize, value: u32| move |b: &mut Vec<u8>| b[at..at + 4].copy_from_slice(&value.to_le_bytes());
    // A total length that cannot hold header and CRC is a header error.
    assert_eq!(parse_changed(&set_u32(16, 35)), Some(BlobError::BadHeader));
    assert_eq!(
        parse_changed(&|b| b[12] = 6),
        Some(BlobError::TableTooLarge { tensor_count: 6 })
    );
    assert_eq!(
        parse_changed(&|b| b[52] = 0),
        Some(BlobError::UnknownDtype { entry: 1, code: 0 })
    );
    assert_eq!(
        parse_changed(&|b| b[52] = 9),
        Some(BlobError::UnknownDtype { entry: 1, code: 9 })
    );
    assert_eq!(parse_changed(&|b| b[55] = 1), Some(BlobError::BadTable { entry: 1 }));
    assert_eq!(parse_changed(&set_u32(60, 104)), Some(BlobError::BadTable { entry: 1 }));
    let out_of_bounds = Some(BlobError::TensorOutOfBounds { id: ID_I32 });
    assert_eq!(parse_changed(&set_u32(60, 64)), out_of_bounds);
    assert_eq!(parse_changed(&set_u32(60, 112)), out_of_bounds);
    assert_eq!(parse_changed(&set_u32(56, 5)), out_of_bounds);
    assert_eq!(parse_changed(&set_u32(56, u32::MAX)), out_of_bounds);
    assert_eq!(
        parse_changed(&set_u32(48, ID_I8.0)),
        Some(BlobError::DuplicateTensor { id: ID_I8 })
    );
    // The unchanged blob passes the same path.
    assert_eq!(parse_changed(&|_| ()), None);
    Ok(())
}
