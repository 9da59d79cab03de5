//! The float reference: the exported ONNX models run by tract ([`onnx`], the encoder in
//! [`reference`](mod@reference), the shared head in [`reference_head`], intermediate tensors in [`taps`]),
//! their parameters read from the ONNX files ([`onnx_params`], [`weights`], [`head`]) and the
//! float heads run in Rust for any number of candidates ([`head_forward`]).

pub mod head;
pub mod head_forward;
pub mod onnx;
pub mod onnx_params;
pub mod reference;
pub mod reference_head;
pub mod taps;
pub mod weights;
