//! `bino-core`: the `no_std`, allocation-free engine of BINO edge.
//!
//! BINO is a 1.34M-parameter binocular ViT encoder that fuses a rectified stereo pair by
//! pixel interleaving. This crate runs its int8 weights on any target, Cortex-M included: rows of
//! a rectified pair in, disparity rows out, in one caller-owned arena whose size is a `const fn`.
//! It never allocates and never panics on input: bad input is an [`Error`].
//!
//! The whole pipeline on the firmware's 48x160 test band, with the boards' readouts (the
//! native pathway: one encoder pass on (L, R), the native head checked from the same pass and
//! fused with a census SGM, then refined to pixels):
//!
//! ```
//! use bino_core::blob::Blob;
//! use bino_core::crc32::Crc32;
//! use bino_core::pipeline::{Pipeline, SlicePair, Sink};
//! use bino_core::preset;
//!
//! const HEIGHT: usize = 48; // one band (a taller image needs more, the same for any height)
//! const WIDTH: usize = 160;
//! const ARENA_BYTES: usize = preset::arena_bytes(HEIGHT, WIDTH); // a const fn: 408,212 B
//!
//! // The weight blob, read in place (in flash on a board), checked once.
//! static BLOB: &[u8] = include_bytes!(concat!(env!("CARGO_MANIFEST_DIR"), "/../weights/bino_int8.bin"));
//! // A rectified 8-bit grey pair; on a board a camera delivers the rows (a `RowSource`).
//! static LEFT: &[u8] = include_bytes!(concat!(env!("CARGO_MANIFEST_DIR"), "/../firmware-sim/assets/band_48x160_left.gray"));
//! static RIGHT: &[u8] = include_bytes!(concat!(env!("CARGO_MANIFEST_DIR"), "/../firmware-sim/assets/band_48x160_right.gray"));
//!
//! /// Digests the refined disparity rows (Q8 pixels) as the firmware does.
//! struct Refined(Crc32);
//!
//! // Every method has a default: a sink implements the outputs it wants.
//! impl Sink for Refined {
//!     fn refined(&mut self, _row: usize, disparity_q8: &[u16]) {
//!         for d in disparity_q8 {
//!             self.0.update(&d.to_le_bytes()); // d / 256 = disparity in pixels
//!         }
//!     }
//! }
//!
//! let pipeline = Pipeline::new(Blob::parse(BLOB)?)?; // once, at boot
//! let mut arena = [0u8; ARENA_BYTES]; // a `static` in firmware
//! let mut rows = SlicePair::new(LEFT, RIGHT, WIDTH, HEIGHT)?;
//! let mut sink = Refined(Crc32::new());
//! let report = pipeline.run_refined(&mut rows, &preset::OPTIONS, &preset::REFINE, &mut arena, &mut sink)?;
//! assert!(report.arena_used <= ARENA_BYTES);
//! // One encoder pass per band: no descriptor band is held (`Report::arena_used`).
//! assert_eq!((report.bands, report.descriptors), (1, 0));
//! // Bit for bit what the firmware computes on both Cortex-M cores.
//! assert_eq!(sink.0.finish(), 0x53cc_34d5);
//! # Ok::<(), bino_core::Error>(())
//! ```
//!
//! The main types: [`blob::Blob`] (the weights, parsed in place), [`pipeline::Pipeline`] with
//! its [`pipeline::RowSource`] (rows in; [`pipeline::SlicePair`] for a pair in memory) and
//! [`pipeline::Sink`] (readouts out), and [`preset`], the readouts the firmware and the boards
//! run with the `const fn` sizing their arena ([`preset::arena_bytes`]; the export pathway's
//! [`preset::EXPORT_OPTIONS`] and [`preset::export_arena_bytes`]; for other
//! [`pipeline::Options`], [`pipeline::arena_bytes_refined`], or for a blob's own encoder passes
//! [`pipeline::Pipeline::arena_bytes`]). Every error is an [`Error`].
//! `examples/board` (a `no_std` program for Cortex-M) and `examples/host` (a PNG pair in, a
//! disparity PNG out) in the repository build on this.
//!
//! Inside, in the order data moves: the model configuration ([`config`]) and the band plan that
//! lets a fixed-size encoder cover images of any height ([`band`]), the int8 [`kernels`] and
//! [`model`], the readouts ([`matching`], [`sgm`], [`lr`]), and [`refine`], which turns a
//! token-grid disparity into pixels.
//!
//! # Features
//!
//! None is on by default.
//! - `depth`: `depth` (Q8 disparity to depth in mm, nearest depth per column sector) and the
//!   example board's `preset::CALIBRATION` and `preset::SECTORS`; pulls in `micromath`.
//! - `defmt`: `defmt::Format` on [`Error`], [`pipeline::Stage`], [`pipeline::Report`] and the
//!   other public report types, for firmware that logs with defmt.
//!
//! The instruction set is never a feature: the Arm kernels are chosen by the target (and
//! `-C target-cpu`), the x86 ones by the CPU.
#![no_std]
#![deny(missing_docs)]
// Audited exceptions: the x86 intrinsic kernels of host builds (kernels/arch/x86/, chosen at run
// time from cpuid) and the Cortex-M assembly kernels
// (kernels/arch/), each behind a safe, length-checked wrapper.
#![deny(unsafe_code)]

pub mod arena;
pub mod band;
pub mod blob;
pub mod census;
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
