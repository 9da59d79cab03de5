//! Per-channel parameters wherever they live: a blob's little-endian bytes or a plain slice.

/// Read-only array of 32-bit parameters indexed by channel.
pub trait I32s {
    /// Element `i`, or 0 past the end (the engine validates lengths before running).
    fn at(&self, i: usize) -> i32;
}

impl I32s for [i32] {
    #[inline(always)]
    fn at(&self, i: usize) -> i32 {
        self.get(i).copied().unwrap_or(0)
    }
}

impl<const N: usize> I32s for [i32; N] {
    #[inline(always)]
    fn at(&self, i: usize) -> i32 {
        self.get(i).copied().unwrap_or(0)
    }
}

/// The same value for every channel (per-tensor parameters).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Uniform(pub i32);

impl I32s for Uniform {
    #[inline(always)]
    fn at(&self, _: usize) -> i32 {
        self.0
    }
}

/// A window of another parameter array starting at `start` (e.g. the key rows of a QKV layer).
#[derive(Clone, Copy)]
pub struct Offset<'p, P: I32s + ?Sized> {
    /// The whole array.
    pub inner: &'p P,
    /// Index of the window's first element.
    pub start: usize,
}

impl<P: I32s + ?Sized> I32s for Offset<'_, P> {
    #[inline(always)]
    fn at(&self, i: usize) -> i32 {
        self.inner.at(self.start.saturating_add(i))
    }
}

impl I32s for crate::blob::Le<'_, i32> {
    #[inline(always)]
    fn at(&self, i: usize) -> i32 {
        self.get(i).unwrap_or(0)
    }
}
