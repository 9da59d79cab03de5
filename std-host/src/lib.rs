//! `bino-host`: the host side of BINO edge — image I/O, the EVAL.md resolution profiles,
//! the `PAIRS.tsv` index, the tract-onnx float reference and the array formats the `bino`
//! CLI writes.
#![deny(missing_docs)]

pub mod bench;
pub mod blob_writer;
pub mod budget;
pub mod colour;
pub mod compare;
pub mod demo;
pub mod eval;
pub mod files;
pub mod float_head;
pub mod float_weights;
pub mod head_forward;
pub mod image_io;
pub mod int8;
mod keyed;
pub mod npy;
pub mod npz;
pub mod nuisance;
pub mod occlusion;
pub mod onnx;
pub mod onnx_params;
pub mod ort_bench;
pub mod pairs;
pub mod pathway;
pub mod pfm;
pub mod pipeline_maps;
pub mod profile;
pub mod quantize;
pub mod readout;
pub mod readout_eval;
pub mod reference;
pub mod reference_head;
pub mod refine;
mod rng;
pub mod run;
pub mod sgbm;
pub mod sim;
pub mod synthetic;
pub mod taps;
pub mod train_python;
