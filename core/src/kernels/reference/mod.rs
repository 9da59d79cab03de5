//! The reference kernels: plain Rust, the specification that every instruction set's kernel is
//! tested against bit for bit. They import the shared types only.

pub mod attention;
pub mod gemm;
pub mod layernorm;
pub mod matmul;
pub mod residual;
pub mod softmax;
