//! Integer kernels of the int8 path. Each is a plain function over slices that cannot panic:
//! lengths that do not fit just compute fewer outputs (the engine checks shapes up front),
//! and every accumulation is bounded by the model's fixed sizes or done with wrapping /
//! saturating arithmetic.

pub mod arch;
pub mod attention;
pub mod conv;
pub mod dispatch;
pub mod epilogue;
pub mod gemm;
pub mod layernorm;
pub mod lut;
pub mod matmul;
pub mod reference;
pub mod residual;
pub mod rope;

pub mod types;

// The shared types at their long-standing paths.
pub use types::params::I32s;
pub use types::{exp, params};
