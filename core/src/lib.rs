//! `bino-core`: the `no_std`, allocation-free engine of BINO edge.
//!
//! BINO is a 1.34M-parameter binocular ViT encoder that fuses a rectified stereo pair by
//! pixel interleaving. This crate holds what every target shares: the model configuration
//! ([`config`]) and the band plan that lets a fixed-size encoder cover images of any height
//! ([`band`]); after the readouts, [`refine`] turns a token-grid disparity into pixels. It never
//! allocates and never panics on input: bad input is an [`Error`].
//!
//! ```
//! use bino_core::band::BandPlan;
//! // A 96-row image (24 token rows) goes as three overlapping 12-row bands.
//! let plan = BandPlan::new(24)?;
//! assert_eq!(plan.len(), 3);
//! # Ok::<(), bino_core::Error>(())
//! ```
#![no_std]
#![deny(missing_docs)]
// Audited exceptions: the x86 intrinsic kernels of host builds (kernels/arch/x86/, chosen at run
// time from cpuid) and the Cortex-M assembly kernels
// (kernels/arch/), each behind a safe, length-checked wrapper.
#![deny(unsafe_code)]

pub mod arena;
pub mod band;
pub mod blob;
pub mod config;
pub mod crc32;
#[cfg(feature = "depth")]
pub mod depth;
pub mod error;
pub mod fixed;
pub mod kernels;
pub mod lr;
pub mod matching;
pub mod model;
pub mod pipeline;
pub mod preset;
pub mod refine;
pub mod sgm;
#[cfg(test)]
mod testutil;

pub use error::Error;
