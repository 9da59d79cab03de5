//! Why a blob was rejected or a tensor lookup failed.

use core::fmt;

use super::tensor::{Dtype, TensorId};

/// A blob that does not parse (the variants up to [`BlobError::DuplicateTensor`], in the order
/// [`super::Blob::parse`] checks them) or a lookup that does not match the blob.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum BlobError {
    /// Fewer bytes than the 32-byte header.
    TooShort {
        /// Bytes given.
        len: usize,
    },
    /// The first 8 bytes are not `BINOQ8\r\n`: not a weight blob (or mangled line ends).
    BadMagic,
    /// A format version this build cannot read.
    UnsupportedVersion {
        /// The blob's version.
        found: u16,
        /// The version this build reads.
        supported: u16,
    },
    /// A header size field is wrong or a reserved header byte is not zero.
    BadHeader,
    /// Fewer bytes than the header's total length.
    Truncated {
        /// Length in the header.
        expected: usize,
        /// Bytes given.
        actual: usize,
    },
    /// More bytes than the header's total length.
    TrailingBytes {
        /// Length in the header.
        expected: usize,
        /// Bytes given.
        actual: usize,
    },
    /// The CRC-32 does not match: the blob is corrupt.
    ChecksumMismatch {
        /// CRC in the blob's last 4 bytes.
        stored: u32,
        /// CRC of the bytes before it.
        computed: u32,
    },
    /// The tensor table runs past the end of the payload.
    TableTooLarge {
        /// Entries the header announces.
        tensor_count: u16,
    },
    /// A table entry has nonzero reserved bytes or an offset that is not a multiple of 16.
    BadTable {
        /// Index of the entry.
        entry: u16,
    },
    /// A table entry has a dtype code this version does not know.
    UnknownDtype {
        /// Index of the entry.
        entry: u16,
        /// The code.
        code: u8,
    },
    /// A tensor's bytes do not lie inside the payload.
    TensorOutOfBounds {
        /// The tensor.
        id: TensorId,
    },
    /// Two table entries have the same id.
    DuplicateTensor {
        /// The repeated id.
        id: TensorId,
    },
    /// The blob has no tensor with this id.
    MissingTensor {
        /// The id looked up.
        id: TensorId,
    },
    /// The tensor has another element type than asked for.
    WrongDtype {
        /// The tensor.
        id: TensorId,
        /// Type asked for.
        expected: Dtype,
        /// Type in the blob.
        found: Dtype,
    },
    /// The tensor has another number of elements than asked for.
    WrongLength {
        /// The tensor.
        id: TensorId,
        /// Elements asked for.
        expected: usize,
        /// Elements in the blob.
        found: usize,
    },
}

impl fmt::Display for BlobError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::TooShort { len } => write!(f, "weight blob of {len} bytes is shorter than its 32-byte header"),
            Self::BadMagic => write!(f, "not a BINO weight blob (wrong magic bytes)"),
            Self::UnsupportedVersion { found, supported } => {
                write!(
                    f,
                    "weight blob has format version {found}, this build reads only version {supported}"
                )
            }
            Self::BadHeader => write!(f, "weight blob header is malformed (size fields or reserved bytes)"),
            Self::Truncated { expected, actual } => {
                write!(
                    f,
                    "weight blob is truncated: {actual} bytes, its header says {expected}"
                )
            }
            Self::TrailingBytes { expected, actual } => {
                write!(
                    f,
                    "weight blob has trailing bytes: {actual} bytes, its header says {expected}"
                )
            }
            Self::ChecksumMismatch { stored, computed } => {
                write!(
                    f,
                    "weight blob is corrupt: CRC-32 is {computed:#010x}, stored {stored:#010x}"
                )
            }
            Self::TableTooLarge { tensor_count } => {
                write!(
                    f,
                    "weight blob tensor table of {tensor_count} entries runs past the payload"
                )
            }
            Self::BadTable { entry } => {
                write!(
                    f,
                    "weight blob tensor table entry {entry} has nonzero reserved bytes or a misaligned offset"
                )
            }
            Self::UnknownDtype { entry, code } => {
                write!(
                    f,
                    "weight blob tensor table entry {entry} has unknown dtype code {code}"
                )
            }
            Self::TensorOutOfBounds { id } => write!(f, "weight blob tensor {id} lies outside the payload"),
            Self::DuplicateTensor { id } => write!(f, "weight blob holds tensor {id} twice"),
            Self::MissingTensor { id } => write!(f, "weight blob has no tensor {id}"),
            Self::WrongDtype { id, expected, found } => {
                write!(f, "weight blob tensor {id} is {found}, expected {expected}")
            }
            Self::WrongLength { id, expected, found } => {
                write!(f, "weight blob tensor {id} has {found} elements, expected {expected}")
            }
        }
    }
}

impl core::error::Error for BlobError {}
