//! What the BINO board apps share (`boards/stm32h7`, `boards/alif-e7`): the readout options of
//! the QEMU firmware, a [`RowSource`](bino_core::pipeline::RowSource) over a side-by-side
//! stereo frame (what a camera interface captures), one over camera lines that an interrupt
//! queues ([`line_queue`], fed by a double-buffered DMA: [`double_buffer`]), and the per-sector
//! summary of the refined disparity that the boards print.
//!
//! `no_std`, no `alloc`, like `bino-core`; the host tests run it on the shipped blob and the
//! firmware's test frame.
#![no_std]
#![deny(missing_docs)]

pub mod cycles;
pub mod double_buffer;
pub mod line_queue;
pub mod options;
pub mod run;
pub mod side_by_side;
pub mod summary;

#[cfg(feature = "host")]
pub mod bake;
#[cfg(all(feature = "defmt", feature = "cortex-m"))]
pub mod check;
#[cfg(feature = "cortex-m")]
pub mod clock;
#[cfg(feature = "defmt")]
pub mod log;
