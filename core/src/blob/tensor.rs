//! What a blob says about each tensor: its id, its element type, where its bytes are.

use core::fmt;

/// A tensor's name in a blob: `kind << 16 | index`. Which kinds exist is up to the model that
/// reads the blob; the container only requires ids to be unique.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TensorId(pub u32);

impl TensorId {
    /// The id of tensor `index` of kind `kind`.
    pub const fn new(kind: u16, index: u16) -> Self {
        Self(((kind as u32) << 16) | index as u32)
    }

    /// The kind (high 16 bits).
    pub const fn kind(self) -> u16 {
        (self.0 >> 16) as u16
    }

    /// The index within the kind (low 16 bits).
    pub const fn index(self) -> u16 {
        self.0 as u16
    }
}

impl fmt::Display for TensorId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}:{}", self.kind(), self.index())
    }
}

/// Element type of a tensor, with its code in the tensor table.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Dtype {
    /// `i8`.
    I8 = 1,
    /// `u8`.
    U8 = 2,
    /// `i16`, little-endian.
    I16 = 3,
    /// `u16`, little-endian.
    U16 = 4,
    /// `i32`, little-endian.
    I32 = 5,
    /// `u32`, little-endian.
    U32 = 6,
    /// `i64`, little-endian.
    I64 = 7,
    /// `f32`, little-endian: metadata for host tools; the integer engine never reads it.
    F32 = 8,
}

impl Dtype {
    /// The type with table code `code`, or `None` for a code this version does not know.
    pub const fn from_code(code: u8) -> Option<Self> {
        Some(match code {
            1 => Self::I8,
            2 => Self::U8,
            3 => Self::I16,
            4 => Self::U16,
            5 => Self::I32,
            6 => Self::U32,
            7 => Self::I64,
            8 => Self::F32,
            _ => return None,
        })
    }

    /// The code written in the tensor table.
    pub const fn code(self) -> u8 {
        self as u8
    }

    /// Bytes per element.
    pub const fn size_bytes(self) -> usize {
        match self {
            Self::I8 | Self::U8 => 1,
            Self::I16 | Self::U16 => 2,
            Self::I32 | Self::U32 | Self::F32 => 4,
            Self::I64 => 8,
        }
    }

    /// The Rust name of the type (`"i16"`).
    pub const fn name(self) -> &'static str {
        match self {
            Self::I8 => "i8",
            Self::U8 => "u8",
            Self::I16 => "i16",
            Self::U16 => "u16",
            Self::I32 => "i32",
            Self::U32 => "u32",
            Self::I64 => "i64",
            Self::F32 => "f32",
        }
    }
}

impl fmt::Display for Dtype {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// One validated entry of a blob's tensor table.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TensorInfo {
    /// The tensor's id.
    pub id: TensorId,
    /// Its element type.
    pub dtype: Dtype,
    /// Its number of elements.
    pub elements: usize,
    /// Byte offset of its first element from the start of the blob (a multiple of 16).
    pub offset: usize,
}

impl TensorInfo {
    /// Bytes the tensor occupies (`elements x dtype size`; validated not to overflow).
    pub const fn byte_len(&self) -> usize {
        self.elements.saturating_mul(self.dtype.size_bytes())
    }
}
