//! Byte layout of the header and of a tensor table entry (docs/blob-format.md), and the header
//! checks that come before the CRC.

use super::error::BlobError;
use super::tensor::TensorId;

/// First 8 bytes of every blob. The CR LF catches a transfer that rewrites line ends.
pub const MAGIC: [u8; 8] = *b"BINOQ8\r\n";
/// The container version this build reads and writes.
pub const FORMAT_VERSION: u16 = 1;
/// Size of the header.
pub const HEADER_BYTES: usize = 32;
/// Size of one tensor table entry.
pub const TABLE_ENTRY_BYTES: usize = 16;
/// Every tensor offset is a multiple of this (from the start of the blob).
pub const TENSOR_ALIGN: usize = 16;
/// Size of the trailing CRC-32.
pub const CRC_BYTES: usize = 4;

// Header field offsets.
const VERSION_AT: usize = 8;
const HEADER_BYTES_AT: usize = 10;
const TENSOR_COUNT_AT: usize = 12;
const ENTRY_BYTES_AT: usize = 14;
const TOTAL_LEN_AT: usize = 16;
const RESERVED_AT: usize = 20;

// Table entry field offsets.
const ID_AT: usize = 0;
const DTYPE_AT: usize = 4;
const ENTRY_RESERVED_AT: usize = 5;
const ELEMENTS_AT: usize = 8;
const OFFSET_AT: usize = 12;

/// The `N` bytes at `at`, or `None` past the end.
fn field<const N: usize>(bytes: &[u8], at: usize) -> Option<[u8; N]> {
    bytes.get(at..)?.first_chunk().copied()
}

pub(super) fn le_u16(bytes: &[u8], at: usize) -> Option<u16> {
    field(bytes, at).map(u16::from_le_bytes)
}

pub(super) fn le_u32(bytes: &[u8], at: usize) -> Option<u32> {
    field(bytes, at).map(u32::from_le_bytes)
}

/// The header fields the rest of the parse needs.
#[derive(Clone, Copy, Debug)]
pub(super) struct Header {
    pub tensor_count: u16,
    /// Whole blob including the CRC; at least header + CRC.
    pub total_len: usize,
}

impl Header {
    /// Parse steps 1 to 4: length, magic, version, then the fixed sizes and reserved bytes.
    /// The version comes before anything else a later version may change, so a blob of another
    /// version always reports [`BlobError::UnsupportedVersion`].
    pub(super) fn parse(bytes: &[u8]) -> Result<Self, BlobError> {
        let header = bytes
            .get(..HEADER_BYTES)
            .ok_or(BlobError::TooShort { len: bytes.len() })?;
        if field::<8>(header, 0) != Some(MAGIC) {
            return Err(BlobError::BadMagic);
        }
        let version = le_u16(header, VERSION_AT).ok_or(BlobError::BadHeader)?;
        if version != FORMAT_VERSION {
            return Err(BlobError::UnsupportedVersion {
                found: version,
                supported: FORMAT_VERSION,
            });
        }
        let sizes_ok = le_u16(header, HEADER_BYTES_AT).map(usize::from) == Some(HEADER_BYTES)
            && le_u16(header, ENTRY_BYTES_AT).map(usize::from) == Some(TABLE_ENTRY_BYTES);
        let reserved_zero = header.get(RESERVED_AT..).is_some_and(|r| r.iter().all(|&b| b == 0));
        let tensor_count = le_u16(header, TENSOR_COUNT_AT);
        let total_len = le_u32(header, TOTAL_LEN_AT).map(|n| usize::try_from(n).unwrap_or(usize::MAX));
        match (sizes_ok && reserved_zero, tensor_count, total_len) {
            // A total length that cannot even hold header and CRC is a header error, not a length one.
            (true, Some(tensor_count), Some(total_len)) if total_len >= HEADER_BYTES + CRC_BYTES => Ok(Self {
                tensor_count,
                total_len,
            }),
            _ => Err(BlobError::BadHeader),
        }
    }

    /// End of the tensor table (start of the payload area).
    pub(super) fn table_end(&self) -> usize {
        entry_start(self.tensor_count)
    }

    /// End of the payload area (start of the CRC).
    pub(super) fn payload_end(&self) -> usize {
        self.total_len.saturating_sub(CRC_BYTES)
    }
}

/// A table entry as stored, not yet validated.
#[derive(Clone, Copy, Debug)]
pub(super) struct RawEntry {
    pub id: TensorId,
    pub dtype_code: u8,
    pub reserved_zero: bool,
    pub elements: u32,
    pub offset: u32,
}

impl RawEntry {
    /// Entry `index` of the table that starts right after the header, or `None` past `bytes`.
    pub(super) fn read(bytes: &[u8], index: u16) -> Option<Self> {
        let entry = bytes.get(entry_start(index)..)?.first_chunk::<TABLE_ENTRY_BYTES>()?;
        Some(Self {
            id: TensorId(le_u32(entry, ID_AT)?),
            dtype_code: *entry.get(DTYPE_AT)?,
            reserved_zero: entry.get(ENTRY_RESERVED_AT..ELEMENTS_AT)?.iter().all(|&b| b == 0),
            elements: le_u32(entry, ELEMENTS_AT)?,
            offset: le_u32(entry, OFFSET_AT)?,
        })
    }
}

/// Where table entry `index` starts (the index of one past the last entry gives the table end).
fn entry_start(index: u16) -> usize {
    HEADER_BYTES.saturating_add(usize::from(index).saturating_mul(TABLE_ENTRY_BYTES))
}
