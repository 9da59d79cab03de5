//! `bino-host`: the host side of BINO edge — image I/O, the EVAL.md resolution profiles,
//! the `PAIRS.tsv` index, the tract-onnx float reference and the array formats the `bino`
//! CLI writes.
#![deny(missing_docs)]

pub mod image_io;
pub mod npy;
pub mod npz;
pub mod onnx;
pub mod pairs;
pub mod profile;
pub mod reference;
pub mod reference_head;
pub mod synthetic;
