//! Writes weight blobs in the container format that `bino_core::blob::Blob` reads
//! (`docs/blob-format.md`). Generic: ids and contents are the caller's.

use anyhow::{anyhow, ensure, Result};
use bino_core::blob::{
    Blob, Dtype, TensorId, CRC_BYTES, FORMAT_VERSION, HEADER_BYTES, MAGIC, TABLE_ENTRY_BYTES, TENSOR_ALIGN,
};
use bino_core::crc32::crc32;
use bino_core::model::ids::{self, HeadKind};

#[cfg(test)]
mod tests;

/// One tensor waiting to be written.
struct Tensor {
    id: TensorId,
    dtype: Dtype,
    elements: u32,
    /// Little-endian element bytes.
    bytes: Vec<u8>,
}

/// Collects tensors, then lays them out as one blob: tensors in insertion order, each at a
/// 16-byte aligned offset, zero padding between them.
pub struct BlobWriter {
    tensors: Vec<Tensor>,
    /// An upper bound of the blob's length (as if every tensor needed 16 bytes of padding), kept
    /// to reject a blob whose length the u32 header field cannot hold before it is built.
    len_bound: usize,
}

macro_rules! add_le {
    ($($(#[$doc:meta])* $name:ident: $t:ty => $dtype:ident;)*) => {$(
        $(#[$doc])*
        pub fn $name(&mut self, id: TensorId, values: &[$t]) -> Result<&mut Self> {
            let bytes = values.iter().flat_map(|v| v.to_le_bytes()).collect();
            self.add_raw(id, Dtype::$dtype, values.len(), bytes)
        }
    )*};
}

impl BlobWriter {
    /// An empty blob.
    pub fn new() -> Self {
        Self {
            tensors: Vec::new(),
            len_bound: HEADER_BYTES + CRC_BYTES,
        }
    }

    add_le! {
        /// Adds an `i8` tensor. Fails if `id` is already present or the blob would exceed 4 GiB.
        add_i8: i8 => I8;
        /// Adds a `u8` tensor (see [`BlobWriter::add_i8`] for the errors).
        add_u8: u8 => U8;
        /// Adds an `i16` tensor (see [`BlobWriter::add_i8`] for the errors).
        add_i16: i16 => I16;
        /// Adds a `u16` tensor (see [`BlobWriter::add_i8`] for the errors).
        add_u16: u16 => U16;
        /// Adds an `i32` tensor (see [`BlobWriter::add_i8`] for the errors).
        add_i32: i32 => I32;
        /// Adds a `u32` tensor (see [`BlobWriter::add_i8`] for the errors).
        add_u32: u32 => U32;
        /// Adds an `i64` tensor (see [`BlobWriter::add_i8`] for the errors).
        add_i64: i64 => I64;
        /// Adds an `f32` tensor, metadata for host tools (see [`BlobWriter::add_i8`] for the errors).
        add_f32: f32 => F32;
    }

    /// Adds a tensor of `elements` values of `dtype` as little-endian `bytes` (a tensor copied
    /// from another blob: `Blob::raw`); errors as [`BlobWriter::add_i8`], and when the byte count
    /// is not `elements` values of `dtype`.
    pub fn add_raw(&mut self, id: TensorId, dtype: Dtype, elements: usize, bytes: Vec<u8>) -> Result<&mut Self> {
        ensure!(
            !self.tensors.iter().any(|t| t.id == id),
            "blob already holds tensor {id}"
        );
        ensure!(
            self.tensors.len() < usize::from(u16::MAX),
            "blob cannot hold more than {} tensors",
            u16::MAX
        );
        ensure!(
            elements.checked_mul(dtype.size_bytes()) == Some(bytes.len()),
            "tensor {id}: {} bytes are not {elements} {} values",
            bytes.len(),
            dtype.name()
        );
        let elements = u32::try_from(elements).map_err(|_| anyhow::anyhow!("tensor {id} has too many elements"))?;
        // One more table entry, alignment padding and the tensor's bytes.
        let len_bound = self.len_bound + TABLE_ENTRY_BYTES + TENSOR_ALIGN + bytes.len();
        ensure!(
            u32::try_from(len_bound).is_ok(),
            "blob would exceed the 4 GiB the format allows"
        );
        self.len_bound = len_bound;
        self.tensors.push(Tensor {
            id,
            dtype,
            elements,
            bytes,
        });
        Ok(self)
    }

    /// Number of tensors added so far.
    pub fn tensor_count(&self) -> usize {
        self.tensors.len()
    }

    /// The blob: header, table, tensors, CRC-32.
    pub fn finish(&self) -> Vec<u8> {
        let table_end = HEADER_BYTES + self.tensors.len() * TABLE_ENTRY_BYTES;
        let mut offsets = Vec::with_capacity(self.tensors.len());
        let mut end = table_end;
        for tensor in &self.tensors {
            let offset = end.next_multiple_of(TENSOR_ALIGN);
            offsets.push(offset);
            end = offset + tensor.bytes.len();
        }
        let total_len = end + CRC_BYTES;

        let mut blob = Vec::with_capacity(total_len);
        blob.extend_from_slice(&MAGIC);
        blob.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
        blob.extend_from_slice(&(HEADER_BYTES as u16).to_le_bytes());
        blob.extend_from_slice(&(self.tensors.len() as u16).to_le_bytes());
        blob.extend_from_slice(&(TABLE_ENTRY_BYTES as u16).to_le_bytes());
        blob.extend_from_slice(&(total_len as u32).to_le_bytes());
        blob.resize(HEADER_BYTES, 0);
        for (tensor, &offset) in self.tensors.iter().zip(&offsets) {
            blob.extend_from_slice(&tensor.id.0.to_le_bytes());
            blob.extend_from_slice(&[tensor.dtype.code(), 0, 0, 0]);
            blob.extend_from_slice(&tensor.elements.to_le_bytes());
            blob.extend_from_slice(&(offset as u32).to_le_bytes());
        }
        for (tensor, &offset) in self.tensors.iter().zip(&offsets) {
            blob.resize(offset, 0);
            blob.extend_from_slice(&tensor.bytes);
        }
        let crc = crc32(&blob);
        blob.extend_from_slice(&crc.to_le_bytes());
        blob
    }
}

/// `blob` without `head`'s tensors ([`bino_core::model::ids::head_of`]): every other tensor
/// copied byte for byte, in order. A board that runs one pathway links only its head (the
/// native pathway needs no shared head).
pub fn without_head(blob: &Blob<'_>, head: HeadKind) -> Result<Vec<u8>> {
    let mut out = BlobWriter::new();
    for info in blob.tensors() {
        if ids::head_of(info.id) == Some(head) {
            continue;
        }
        let (dtype, bytes) = blob.raw(info.id).map_err(|e| anyhow!("tensor {}: {e}", info.id))?;
        out.add_raw(info.id, dtype, info.elements, bytes.to_vec())?;
    }
    Ok(out.finish())
}

impl Default for BlobWriter {
    fn default() -> Self {
        Self::new()
    }
}
