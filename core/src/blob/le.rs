//! Zero-copy views of little-endian arrays at any address: values are assembled from bytes, so
//! a blob in flash or at an odd offset needs no alignment and no copy.

use core::marker::PhantomData;

use super::tensor::Dtype;

mod sealed {
    pub trait Sealed {}
}

/// A scalar a [`Le`] view can decode (`i16`, `u16`, `i32`, `u32`, `i64`, `f32`). Sealed.
pub trait LeScalar: sealed::Sealed + Copy + Default + 'static {
    /// Bytes per value.
    const SIZE: usize;
    /// The blob element type holding this scalar.
    const DTYPE: Dtype;
    /// Decodes the first `SIZE` bytes of `bytes`, or `None` if there are fewer.
    fn from_le(bytes: &[u8]) -> Option<Self>;
}

macro_rules! le_scalar {
    ($($t:ty => $dtype:ident),* $(,)?) => {$(
        impl sealed::Sealed for $t {}
        impl LeScalar for $t {
            const SIZE: usize = core::mem::size_of::<$t>();
            const DTYPE: Dtype = Dtype::$dtype;
            #[inline(always)]
            fn from_le(bytes: &[u8]) -> Option<Self> {
                bytes.first_chunk().map(|b| <$t>::from_le_bytes(*b))
            }
        }
    )*};
}

le_scalar!(i16 => I16, u16 => U16, i32 => I32, u32 => U32, i64 => I64, f32 => F32);

/// A read-only array of little-endian `T` borrowed from bytes.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Le<'a, T> {
    /// Exactly `len() * T::SIZE` bytes.
    bytes: &'a [u8],
    values: PhantomData<T>,
}

impl<'a, T: LeScalar> Le<'a, T> {
    /// A view of `bytes`, or `None` if its length is not a whole number of values.
    pub fn new(bytes: &'a [u8]) -> Option<Self> {
        bytes.len().is_multiple_of(T::SIZE).then_some(Self {
            bytes,
            values: PhantomData,
        })
    }

    /// Number of values.
    pub fn len(&self) -> usize {
        self.bytes.len() / T::SIZE
    }

    /// Whether the view holds no values.
    pub fn is_empty(&self) -> bool {
        self.bytes.is_empty()
    }

    /// Value `i`, or `None` past the end.
    #[inline(always)]
    pub fn get(&self, i: usize) -> Option<T> {
        let start = i.checked_mul(T::SIZE)?;
        T::from_le(self.bytes.get(start..)?)
    }

    /// Value `i`, or zero past the end: for hot loops whose indices were checked up front.
    #[inline(always)]
    pub fn at(&self, i: usize) -> T {
        self.get(i).unwrap_or_default()
    }

    /// The values in order.
    pub fn iter(&self) -> impl Iterator<Item = T> + 'a {
        self.bytes.chunks_exact(T::SIZE).filter_map(T::from_le)
    }

    /// The underlying little-endian bytes.
    pub fn as_bytes(&self) -> &'a [u8] {
        self.bytes
    }
}

// Shows the values, not the bytes.
impl<T: LeScalar + core::fmt::Debug> core::fmt::Debug for Le<'_, T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}
