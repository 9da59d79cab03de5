//! The 8-bit operand types of the dot products.

/// An 8-bit operand of the dot products: int8 codes, or the unsigned softmax weights.
pub trait Code: bytemuck::Pod {
    /// Whether the byte is signed (decides sign- or zero-extension).
    const SIGNED: bool;
    /// Zero of the type.
    const ZERO: Self;
    /// The value in 32 bits.
    fn wide(self) -> i32;
}

impl Code for i8 {
    const SIGNED: bool = true;
    const ZERO: Self = 0;
    #[inline(always)]
    fn wide(self) -> i32 {
        self as i32
    }
}

impl Code for u8 {
    const SIGNED: bool = false;
    const ZERO: Self = 0;
    #[inline(always)]
    fn wide(self) -> i32 {
        self as i32
    }
}
