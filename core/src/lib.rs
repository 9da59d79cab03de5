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
// Audited exceptions: the x86 intrinsic kernels of host builds (kernels/matmul_avx2.rs, and
// kernels/x86_vnni.rs with its cpuid/xgetbv check) and the Cortex-M assembly kernels
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
// Test code, not an API: the one test PRNG, for this crate's tests and (feature `testutil`)
// the integration and firmware kernel tests.
#[cfg(any(test, feature = "testutil"))]
#[doc(hidden)]
pub mod testutil;

pub use error::Error;
