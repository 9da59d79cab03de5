//! The versioned weight-blob container: a header, a table of named tensors, their bytes and a
//! CRC-32 (byte layout in `docs/blob-format.md`). It knows nothing about the model: which
//! tensors a model needs is the model's business.
//!
//! [`Blob::parse`] validates everything once; lookups then borrow the tensors straight from the
//! input bytes (flash, a file read into memory, any alignment). `i8`/`u8` tensors come back as
//! plain slices, wider types as [`Le`] views that assemble each little-endian value from bytes.
//!
//! ```
//! use bino_core::blob::{Blob, BlobError};
//! assert_eq!(Blob::parse(b"BINOQ8").err(), Some(BlobError::TooShort { len: 6 }));
//! ```

mod error;
mod layout;
mod le;
mod tensor;
#[cfg(test)]
mod tests;

pub use error::BlobError;
pub use layout::{CRC_BYTES, FORMAT_VERSION, HEADER_BYTES, MAGIC, TABLE_ENTRY_BYTES, TENSOR_ALIGN};
pub use le::{Le, LeScalar};
pub use tensor::{Dtype, TensorId, TensorInfo};

use crate::crc32::crc32;
use layout::{le_u32, Header, RawEntry};

/// A validated weight blob borrowing its bytes.
#[derive(Clone, Copy)]
pub struct Blob<'a> {
    /// The whole blob, CRC included (exactly the header's total length).
    bytes: &'a [u8],
    tensor_count: u16,
}

impl<'a> Blob<'a> {
    /// Checks `bytes` in the order of [`BlobError`]'s variants: header, length, CRC, then every
    /// table entry (type, alignment, bounds, unique ids).
    pub fn parse(bytes: &'a [u8]) -> Result<Self, BlobError> {
        let header = Header::parse(bytes)?;
        let (expected, actual) = (header.total_len, bytes.len());
        if actual < expected {
            return Err(BlobError::Truncated { expected, actual });
        }
        if actual > expected {
            return Err(BlobError::TrailingBytes { expected, actual });
        }
        let checked = bytes.get(..header.payload_end()).ok_or(BlobError::BadHeader)?;
        let stored = le_u32(bytes, header.payload_end()).ok_or(BlobError::BadHeader)?;
        let computed = crc32(checked);
        if stored != computed {
            return Err(BlobError::ChecksumMismatch { stored, computed });
        }
        validate_table(bytes, &header)?;
        Ok(Self {
            bytes,
            tensor_count: header.tensor_count,
        })
    }

    /// The container format version (always [`FORMAT_VERSION`] once parsed).
    pub fn version(&self) -> u16 {
        FORMAT_VERSION
    }

    /// Length of the whole blob in bytes, CRC included.
    pub fn total_len(&self) -> usize {
        self.bytes.len()
    }

    /// The blob's bytes.
    pub fn as_bytes(&self) -> &'a [u8] {
        self.bytes
    }

    /// Number of tensors.
    pub fn tensor_count(&self) -> usize {
        usize::from(self.tensor_count)
    }

    /// Every tensor, in table order.
    pub fn tensors(&self) -> impl Iterator<Item = TensorInfo> + 'a {
        let bytes = self.bytes;
        (0..self.tensor_count).filter_map(move |i| RawEntry::read(bytes, i).and_then(|e| tensor_info(&e)))
    }

    /// The tensor `id`: its table entry.
    pub fn info(&self, id: TensorId) -> Result<TensorInfo, BlobError> {
        self.tensors()
            .find(|t| t.id == id)
            .ok_or(BlobError::MissingTensor { id })
    }

    /// The tensor `id`: its type and raw little-endian bytes, whatever the type.
    pub fn raw(&self, id: TensorId) -> Result<(Dtype, &'a [u8]), BlobError> {
        let info = self.info(id)?;
        Ok((info.dtype, self.payload(&info)?))
    }

    /// The `i8` tensor `id`, which must have exactly `len` elements.
    pub fn i8s(&self, id: TensorId, len: usize) -> Result<&'a [i8], BlobError> {
        Ok(bytemuck::must_cast_slice(self.typed(id, Dtype::I8, len)?))
    }

    /// The `u8` tensor `id`, which must have exactly `len` elements.
    pub fn u8s(&self, id: TensorId, len: usize) -> Result<&'a [u8], BlobError> {
        self.typed(id, Dtype::U8, len)
    }

    /// The `i16` tensor `id`, which must have exactly `len` elements.
    pub fn i16s(&self, id: TensorId, len: usize) -> Result<Le<'a, i16>, BlobError> {
        self.le(id, len)
    }

    /// The `u16` tensor `id`, which must have exactly `len` elements.
    pub fn u16s(&self, id: TensorId, len: usize) -> Result<Le<'a, u16>, BlobError> {
        self.le(id, len)
    }

    /// The `i32` tensor `id`, which must have exactly `len` elements.
    pub fn i32s(&self, id: TensorId, len: usize) -> Result<Le<'a, i32>, BlobError> {
        self.le(id, len)
    }

    /// The `u32` tensor `id`, which must have exactly `len` elements.
    pub fn u32s(&self, id: TensorId, len: usize) -> Result<Le<'a, u32>, BlobError> {
        self.le(id, len)
    }

    /// The `i64` tensor `id`, which must have exactly `len` elements.
    pub fn i64s(&self, id: TensorId, len: usize) -> Result<Le<'a, i64>, BlobError> {
        self.le(id, len)
    }

    /// The `f32` tensor `id` (host-side metadata), which must have exactly `len` elements.
    pub fn f32s(&self, id: TensorId, len: usize) -> Result<Le<'a, f32>, BlobError> {
        self.le(id, len)
    }

    fn le<T: LeScalar>(&self, id: TensorId, len: usize) -> Result<Le<'a, T>, BlobError> {
        let bytes = self.typed(id, T::DTYPE, len)?;
        Le::new(bytes).ok_or(BlobError::TensorOutOfBounds { id })
    }

    /// The bytes of tensor `id` after checking its type and element count.
    fn typed(&self, id: TensorId, expected: Dtype, len: usize) -> Result<&'a [u8], BlobError> {
        let info = self.info(id)?;
        if info.dtype != expected {
            return Err(BlobError::WrongDtype {
                id,
                expected,
                found: info.dtype,
            });
        }
        if info.elements != len {
            return Err(BlobError::WrongLength {
                id,
                expected: len,
                found: info.elements,
            });
        }
        self.payload(&info)
    }

    fn payload(&self, info: &TensorInfo) -> Result<&'a [u8], BlobError> {
        let end = info.offset.checked_add(info.byte_len());
        end.and_then(|end| self.bytes.get(info.offset..end))
            .ok_or(BlobError::TensorOutOfBounds { id: info.id })
    }
}

/// Parse step 7: every entry well formed and inside the payload, and no id twice.
fn validate_table(bytes: &[u8], header: &Header) -> Result<(), BlobError> {
    let (table_end, payload_end) = (header.table_end(), header.payload_end());
    let tensor_count = header.tensor_count;
    if table_end > payload_end {
        return Err(BlobError::TableTooLarge { tensor_count });
    }
    for entry in 0..tensor_count {
        let raw = RawEntry::read(bytes, entry).ok_or(BlobError::TableTooLarge { tensor_count })?;
        let info = validate_entry(&raw, entry, table_end, payload_end)?;
        // Quadratic, but a model has a few hundred tensors and parsing happens once.
        let mut earlier = (0..entry).filter_map(|e| RawEntry::read(bytes, e));
        if earlier.any(|e| e.id == info.id) {
            return Err(BlobError::DuplicateTensor { id: info.id });
        }
    }
    Ok(())
}

fn validate_entry(raw: &RawEntry, entry: u16, table_end: usize, payload_end: usize) -> Result<TensorInfo, BlobError> {
    if !raw.reserved_zero {
        return Err(BlobError::BadTable { entry });
    }
    let info = tensor_info(raw).ok_or(BlobError::UnknownDtype {
        entry,
        code: raw.dtype_code,
    })?;
    if !info.offset.is_multiple_of(TENSOR_ALIGN) {
        return Err(BlobError::BadTable { entry });
    }
    let end = info
        .elements
        .checked_mul(info.dtype.size_bytes())
        .and_then(|n| n.checked_add(info.offset));
    match end {
        Some(end) if info.offset >= table_end && end <= payload_end => Ok(info),
        _ => Err(BlobError::TensorOutOfBounds { id: info.id }),
    }
}

/// The entry's typed view (no bounds checks), or `None` for an unknown dtype.
fn tensor_info(raw: &RawEntry) -> Option<TensorInfo> {
    Some(TensorInfo {
        id: raw.id,
        dtype: Dtype::from_code(raw.dtype_code)?,
        // A u32 that does not fit usize (16-bit targets) can never be in bounds either.
        elements: usize::try_from(raw.elements).unwrap_or(usize::MAX),
        offset: usize::try_from(raw.offset).unwrap_or(usize::MAX),
    })
}

// Summarised: the derived form would print every byte of a megabyte blob.
impl core::fmt::Debug for Blob<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Blob")
            .field("total_len", &self.total_len())
            .field("tensor_count", &self.tensor_count)
            .finish_non_exhaustive()
    }
}
