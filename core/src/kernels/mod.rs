//! Integer kernels of the int8 path. Each is a plain function over slices that cannot panic:
//! lengths that do not fit just compute fewer outputs (the engine checks shapes up front),
//! and every accumulation is bounded by the model's fixed sizes or done with wrapping /
//! saturating arithmetic.
//!
//! Layers, bottom up (`docs/kernels.md`): [`types`], [`mod@reference`], [`arch`] (one module per
//! instruction set), the portable families ([`layernorm`], [`lut`]) and [`dispatch`], the one
//! place that picks an instruction set and the only kernel module the model calls.

pub mod arch;
pub mod dispatch;
pub mod layernorm;
pub mod lut;
pub mod reference;

pub mod types;

// The shared types at their long-standing paths.
pub use types::params::I32s;
pub use types::{exp, params};
