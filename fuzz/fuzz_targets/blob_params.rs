//! The shipped blob with the values of chosen tensors corrupted (shifts, multipliers, zero
//! points, epsilons, tables, weights), CRC recomputed: the model checks must refuse what they
//! cannot run, and whatever they accept must run without a panic.
#![no_main]

use arbitrary::Arbitrary;
use bino_core::blob::{Blob, TensorInfo};
use bino_fuzz::{reseal, run_pipeline, Run, SHIPPED_BLOB};
use libfuzzer_sys::fuzz_target;

#[derive(Debug, Arbitrary)]
struct Input {
    /// (tensor index, element index, value): the element's bytes become the value's.
    edits: Vec<(u16, u32, i64)>,
    run: Run,
}

fuzz_target!(|input: Input| {
    let Ok(shipped) = Blob::parse(SHIPPED_BLOB) else {
        panic!("the shipped blob must parse")
    };
    let tensors: Vec<TensorInfo> = shipped.tensors().collect();
    let mut bytes = SHIPPED_BLOB.to_vec();
    for &(tensor, element, value) in input.edits.iter().take(8) {
        let info = tensors[usize::from(tensor) % tensors.len()];
        let size = info.dtype.size_bytes();
        if info.elements == 0 {
            continue;
        }
        let at = info.offset + (element as usize % info.elements) * size;
        bytes[at..at + size].copy_from_slice(&value.to_le_bytes()[..size]);
    }
    reseal(&mut bytes);
    let Ok(blob) = Blob::parse(&bytes) else {
        panic!("value edits keep the container valid")
    };
    let _ = run_pipeline(blob, &input.run);
});
