//! The bottom layer of the kernels: the parameter types, constants and tables that the
//! reference kernels, every instruction set's kernels and the dispatch share. Nothing here
//! computes a layer; nothing here imports another kernel module.

pub mod attention;
pub mod code;
pub mod exp;
pub mod layernorm;
pub mod params;
pub mod prepared;
pub mod requant;
pub mod rope;
