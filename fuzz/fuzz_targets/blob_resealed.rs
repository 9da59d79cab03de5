//! The shipped blob with fuzzer-chosen byte edits anywhere (header, table, payload), the CRC
//! recomputed so the edits reach the table and model checks; a blob that still builds a
//! pipeline is run on a small pair.
#![no_main]

use arbitrary::Arbitrary;
use bino_core::blob::Blob;
use bino_fuzz::{reseal, run_pipeline, Run, SHIPPED_BLOB};
use libfuzzer_sys::fuzz_target;

#[derive(Debug, Arbitrary)]
struct Input {
    /// (position, new byte); positions below 4 KiB (header and table) are chosen as often as
    /// the rest, since that is where the structure lives.
    edits: Vec<(bool, u32, u8)>,
    /// Cut the blob to this length first (then reseal), if set.
    truncate: Option<u32>,
    run: Run,
}

fuzz_target!(|input: Input| {
    let mut bytes = SHIPPED_BLOB.to_vec();
    for &(in_table, at, value) in input.edits.iter().take(16) {
        let span = if in_table { 4096 } else { bytes.len() };
        let at = at as usize % span.min(bytes.len());
        bytes[at] = value;
    }
    if let Some(len) = input.truncate {
        bytes.truncate(len as usize % (bytes.len() + 1));
    }
    reseal(&mut bytes);
    let Ok(blob) = Blob::parse(&bytes) else { return };
    let _ = run_pipeline(blob, &input.run);
});
