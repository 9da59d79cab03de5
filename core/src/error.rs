//! The one error type of `bino-core`.

use core::fmt;

/// Everything that can go wrong in `bino-core`. Every bad input is one of these, never a panic.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[non_exhaustive]
pub enum Error {
    /// An image has no rows or columns.
    EmptyImage,
    /// An image dimension is not a multiple of what the token grid needs.
    NotMultiple {
        /// Which dimension ("height" or "width").
        what: &'static str,
        /// Its value in pixels.
        value: usize,
        /// The multiple it must be.
        multiple: usize,
    },
    /// The image is wider than the configured maximum width.
    TooWide {
        /// Width in pixels.
        width: usize,
        /// Configured maximum.
        max: usize,
    },
    /// The left and right views have different sizes.
    PairMismatch,
}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Error::EmptyImage => write!(f, "image has zero rows or columns"),
            Error::NotMultiple { what, value, multiple } => {
                write!(f, "image {what} {value} is not a multiple of {multiple}")
            }
            Error::TooWide { width, max } => {
                write!(f, "image width {width} exceeds the configured maximum {max}")
            }
            Error::PairMismatch => write!(f, "left and right views differ in size"),
        }
    }
}

impl core::error::Error for Error {}
