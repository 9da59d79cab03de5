//! Carving a caller-provided byte arena into the typed buffers of a run.
//!
//! The engine never allocates: firmware declares a `static` arena of the size a `const fn`
//! gives (e.g. [`crate::model::encoder::arena_bytes`]) and passes it in; host code passes a `Vec`.
//! Buffers are cut from the front in a fixed order, so the bytes used are known before the
//! run and the high-water mark is exactly what was cut.

use crate::Error;

/// Bytes of slack one `i32` buffer may need to reach 4-byte alignment.
pub const ALIGN_SLACK: usize = 3;

/// The unused rest of an arena, cut from the front.
pub struct Carver<'a> {
    rest: &'a mut [u8],
    capacity: usize,
    needed: usize,
}

impl<'a> Carver<'a> {
    /// Starts carving `arena`; `needed` is the total the run will take (for the error message).
    pub fn new(arena: &'a mut [u8], needed: usize) -> Result<Self, Error> {
        let capacity = arena.len();
        check_size(arena, needed)?;
        Ok(Self {
            rest: arena,
            capacity,
            needed,
        })
    }

    /// Bytes cut so far (alignment padding included): the high-water mark.
    pub fn used(&self) -> usize {
        self.capacity - self.rest.len()
    }

    fn take_bytes(&mut self, len: usize) -> Result<&'a mut [u8], Error> {
        if self.rest.len() < len {
            return Err(Error::ArenaTooSmall {
                needed: self.needed.max(self.used() + len),
                available: self.capacity,
            });
        }
        let (head, tail) = core::mem::take(&mut self.rest).split_at_mut(len);
        self.rest = tail;
        Ok(head)
    }

    /// `len` zeroed `i8` values.
    pub fn i8s(&mut self, len: usize) -> Result<&'a mut [i8], Error> {
        let bytes = self.take_bytes(len)?;
        bytes.fill(0);
        Ok(bytemuck::cast_slice_mut(bytes))
    }

    /// `len` zeroed `u8` values.
    pub fn u8s(&mut self, len: usize) -> Result<&'a mut [u8], Error> {
        let bytes = self.take_bytes(len)?;
        bytes.fill(0);
        Ok(bytes)
    }

    /// `len` zeroed `u16` values, 2-byte aligned (up to one byte of padding).
    pub fn u16s(&mut self, len: usize) -> Result<&'a mut [u16], Error> {
        let misalign = self.rest.as_ptr() as usize % 2;
        self.take_bytes(misalign)?;
        let bytes = self.take_bytes(len.saturating_mul(2))?;
        bytes.fill(0);
        bytemuck::try_cast_slice_mut(bytes).map_err(|_| Error::ArenaTooSmall {
            needed: self.needed,
            available: 0,
        })
    }

    /// `len` zeroed `u32` values, 4-byte aligned (up to [`ALIGN_SLACK`] bytes of padding).
    pub fn u32s(&mut self, len: usize) -> Result<&'a mut [u32], Error> {
        let words = self.i32s(len)?;
        Ok(bytemuck::cast_slice_mut(words))
    }

    /// `len` zeroed `i32` values, 4-byte aligned (up to [`ALIGN_SLACK`] bytes of padding).
    pub fn i32s(&mut self, len: usize) -> Result<&'a mut [i32], Error> {
        let misalign = self.rest.as_ptr() as usize % 4;
        self.take_bytes((4 - misalign) % 4)?;
        let bytes = self.take_bytes(len.saturating_mul(4))?;
        bytes.fill(0);
        bytemuck::try_cast_slice_mut(bytes).map_err(|_| Error::ArenaTooSmall {
            needed: self.needed,
            available: 0,
        })
    }
}

/// [`Error::ArenaTooSmall`] unless `arena` holds `needed` bytes: a run's check before any work.
pub fn check_size(arena: &[u8], needed: usize) -> Result<(), Error> {
    if arena.len() < needed {
        return Err(Error::ArenaTooSmall {
            needed,
            available: arena.len(),
        });
    }
    Ok(())
}

/// `arena` cut at `at`, or `None` when it is shorter (the pipeline's regions, cut in order).
pub fn split(arena: &mut [u8], at: usize) -> Option<(&mut [u8], &mut [u8])> {
    (at <= arena.len()).then(|| arena.split_at_mut(at))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn carves_aligned_disjoint_buffers() -> Result<(), Error> {
        let mut arena = [0xAAu8; 64];
        for start in 0..4 {
            let slice = &mut arena[start..];
            let mut carver = Carver::new(slice, 40)?;
            let a = carver.i8s(5)?;
            let b = carver.i32s(4)?;
            a.fill(-1);
            b.fill(i32::MAX);
            assert_eq!(b.as_ptr() as usize % 4, 0);
            assert!(carver.used() <= 5 + ALIGN_SLACK + 16);
        }
        Ok(())
    }

    #[test]
    fn too_small_is_an_error() {
        let mut arena = [0u8; 16];
        assert!(matches!(
            Carver::new(&mut arena, 17),
            Err(Error::ArenaTooSmall {
                needed: 17,
                available: 16
            })
        ));
        let Ok(mut carver) = Carver::new(&mut arena, 16) else {
            panic!("16 bytes fit")
        };
        assert!(carver.i32s(3).is_ok());
        assert!(matches!(carver.i8s(100), Err(Error::ArenaTooSmall { .. })));
    }
}
