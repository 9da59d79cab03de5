//! Arbitrary bytes as a weight blob: parsing, every lookup, and building the models.
#![no_main]

use bino_core::blob::{Blob, Dtype};
use bino_core::pipeline::Pipeline;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(blob) = Blob::parse(data) else { return };
    for info in blob.tensors() {
        let _ = blob.raw(info.id);
        let n = info.elements;
        let _ = match info.dtype {
            Dtype::I8 => blob.i8s(info.id, n).map(|_| ()),
            Dtype::U8 => blob.u8s(info.id, n).map(|_| ()),
            Dtype::I16 => blob.i16s(info.id, n).map(|v| v.iter().for_each(drop)),
            Dtype::U16 => blob.u16s(info.id, n).map(|v| v.iter().for_each(drop)),
            Dtype::I32 => blob.i32s(info.id, n).map(|v| v.iter().for_each(drop)),
            Dtype::U32 => blob.u32s(info.id, n).map(|v| v.iter().for_each(drop)),
            Dtype::I64 => blob.i64s(info.id, n).map(|v| v.iter().for_each(drop)),
            Dtype::F32 => blob.f32s(info.id, n).map(|v| v.iter().for_each(drop)),
        };
        // Wrong lengths and types are errors, not panics.
        let _ = blob.i32s(info.id, n.wrapping_add(1));
        let _ = blob.i8s(info.id, usize::MAX);
    }
    let _ = Pipeline::new(blob);
});
