//! The one error type of `bino-core`.

use core::fmt;

/// Everything that can go wrong in `bino-core`. Every bad input is one of these, never a panic.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
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
    /// The image is taller than [`crate::config::MAX_HEIGHT`].
    TooTall {
        /// Height in pixels.
        height: usize,
        /// The most the engine takes.
        max: usize,
    },
    /// The left and right views have different sizes.
    PairMismatch,
    /// A band is taller than the encoder's band.
    BandTooTall {
        /// Rows given.
        rows: usize,
        /// The most the encoder takes.
        max: usize,
    },
    /// A buffer has the wrong length.
    BufferSize {
        /// Which buffer.
        what: &'static str,
        /// Length it must have.
        expected: usize,
        /// Length it has.
        found: usize,
    },
    /// The arena cannot hold what the run needs.
    ArenaTooSmall {
        /// Bytes the run needs.
        needed: usize,
        /// Bytes the arena has.
        available: usize,
    },
    /// The weight blob was made for another model configuration.
    ConfigMismatch {
        /// The configuration field that differs.
        field: &'static str,
        /// This build's value.
        expected: usize,
        /// The blob's value.
        found: usize,
    },
    /// A quantisation parameter in the blob is out of range (a shift of 0 or above 62, a
    /// negative epsilon, a table of the wrong size).
    BadParameter {
        /// The tensor holding it.
        id: crate::blob::TensorId,
    },
    /// Rows were pushed into a stream after it was finished.
    StreamFinished,
    /// More disparity candidates were asked of row matching than it supports (or none).
    Candidates {
        /// Candidates asked for.
        requested: usize,
        /// The most supported.
        max: usize,
    },
    /// A parameter or index is outside the range the operation takes.
    OutOfRange {
        /// Which parameter.
        what: &'static str,
        /// Its value.
        value: usize,
        /// The least allowed.
        min: usize,
        /// The most allowed.
        max: usize,
    },
    /// A stage asked for a readout the run does not produce (the refinement of a head readout
    /// without the head, or of head+lr without the head's left-right check).
    MissingReadout {
        /// The readout, as the host names it (`head+lr`, ...).
        readout: &'static str,
    },
    /// A row source lost rows before handing over `row` (a camera whose row queue overflowed:
    /// the sensor ran further ahead than its line buffers hold).
    RowsLost {
        /// The row the pipeline asked for.
        row: usize,
        /// Rows lost so far.
        lost: usize,
    },
    /// A row source waited for `row` longer than its timeout and got nothing (a camera that
    /// stopped sending mid-frame, or never started): an error, never an endless wait.
    RowsStalled {
        /// The row the pipeline asked for.
        row: usize,
        /// Milliseconds it waited.
        waited_ms: u32,
    },
    /// A row source was asked for a row past its last one: the frame ended before the image's
    /// height (a camera that stopped, a pair in memory shorter than its stated height).
    EndOfRows {
        /// The row asked for (0-based).
        row: usize,
        /// The rows the source holds.
        height: usize,
    },
    /// A head stream was given the other pathway's input (descriptor rows to the native
    /// head, or pair-token rows to the export head).
    PathwayMismatch {
        /// The head's pathway (`export` or `native`).
        head: &'static str,
        /// The pathway whose input it was given.
        input: &'static str,
    },
    /// The weight blob is malformed or lacks a tensor the model needs.
    Blob(crate::blob::BlobError),
}

impl Error {
    /// `Ok` when a buffer's length `found` is the `expected` one, else [`Error::BufferSize`]
    /// naming the buffer (`what`) and both lengths: the one check every length-taking function
    /// makes.
    ///
    /// ```
    /// use bino_core::Error;
    /// assert_eq!(Error::check_len("row", 4, 4), Ok(()));
    /// assert_eq!(
    ///     Error::check_len("row", 4, 3),
    ///     Err(Error::BufferSize { what: "row", expected: 4, found: 3 })
    /// );
    /// ```
    #[inline]
    pub const fn check_len(what: &'static str, expected: usize, found: usize) -> Result<(), Error> {
        if found == expected {
            Ok(())
        } else {
            Err(Error::BufferSize { what, expected, found })
        }
    }
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
            Error::TooTall { height, max } => {
                write!(f, "image height {height} exceeds the maximum {max}")
            }
            Error::PairMismatch => write!(f, "left and right views differ in size"),
            Error::BandTooTall { rows, max } => write!(f, "band of {rows} rows is taller than the encoder's {max}"),
            Error::BufferSize { what, expected, found } => {
                write!(f, "{what} holds {found} values, expected {expected}")
            }
            Error::ArenaTooSmall { needed, available } => {
                write!(f, "arena of {available} bytes is too small: the run needs {needed}")
            }
            Error::ConfigMismatch { field, expected, found } => {
                write!(f, "weight blob has {field} = {found}, this build expects {expected}")
            }
            Error::BadParameter { id } => {
                write!(f, "weight blob tensor {:#010x} holds an out-of-range parameter", id.0)
            }
            Error::StreamFinished => write!(f, "row pushed after the stream was finished"),
            Error::PathwayMismatch { head, input } => {
                write!(
                    f,
                    "the {head} pathway's head was given the {input} pathway's input rows"
                )
            }
            Error::Candidates { requested, max } => {
                write!(
                    f,
                    "{requested} disparity candidates requested; row matching supports 1 to {max}"
                )
            }
            Error::OutOfRange { what, value, min, max } => {
                write!(f, "{what} {value} is outside {min}..={max}")
            }
            Error::MissingReadout { readout } => {
                write!(f, "the {readout} readout is not produced by this run")
            }
            Error::EndOfRows { row, height } => {
                write!(f, "row {row} asked of a row source that ended after {height} rows")
            }
            Error::RowsLost { row, lost } => {
                write!(f, "row source lost {lost} rows by row {row} (its row queue overflowed)")
            }
            Error::RowsStalled { row, waited_ms } => {
                write!(
                    f,
                    "row source delivered no row {row} within {waited_ms} ms (its camera stalled)"
                )
            }
            Error::Blob(e) => write!(f, "{e}"),
        }
    }
}

impl From<crate::blob::BlobError> for Error {
    fn from(e: crate::blob::BlobError) -> Self {
        Error::Blob(e)
    }
}

impl core::error::Error for Error {}
