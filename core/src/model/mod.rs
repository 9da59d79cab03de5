//! The BINO model in int8: tensor inventory, weight views, the encoder.

pub mod encoder;
pub mod head;
pub mod ids;
pub mod probe;
pub mod weights;
