//! `bino-host`: the host side of BINO edge — image I/O, the EVAL.md resolution profiles,
//! the `PAIRS.tsv` index, the tract-onnx float reference and the array formats the `bino`
//! CLI writes.
//!
//! Modules by concern: [`io`] (files and formats), [`data`] (pairs, profiles, the synthetic
//! scene, degradations), [`float`] (the float reference), [`int8`] (the int8 engine on the
//! host), [`readout`] (the readouts every command shares), and one module per `bino` verb
//! that has more than arguments, named as its file in the CLI's `cli/`: [`bench`](mod@bench), [`budget`],
//! [`compare`], [`demo`], [`eval`], [`quantize`], [`run`], [`sim`] (`bino pairs` lists
//! [`data::pairs`], `bino reference` runs [`float::reference`]).
#![deny(missing_docs)]

pub mod band_maps;
pub mod data;
pub mod float;
pub mod int8;
pub mod io;
pub mod readout;

pub mod bench;
pub mod budget;
pub mod compare;
pub mod demo;
pub mod eval;
pub mod quantize;
pub mod run;
pub mod sim;
#[cfg(test)]
mod test_inputs;
