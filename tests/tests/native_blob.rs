//! The board's learned-preset blob, `weights/bino_int8_native.bin`: the shipped blob's encoder
//! and native head byte for byte (`bino quantize --only native`), within the 1.5 MiB weights
//! target. The learned preset's whole frame (the QEMU firmware's `frame` run) gives the same
//! digests with it as with the whole blob, and a run that needs the shared head is refused.

mod firmware;

use bino_core::blob::Blob;
use bino_core::model::ids::{head_of, HeadKind};
use bino_core::pipeline::SlicePair;
use bino_host::int8::blob_writer::without_head;
use bino_tests::repo;
use firmware::workload::{self, Run};
use firmware::Quiet;

fn read(relative: &str) -> Vec<u8> {
    let path = repo().join(relative);
    std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn the_native_blob_is_the_shipped_blobs_encoder_and_native_head() {
    let (full, native) = (read("weights/bino_int8.bin"), read("weights/bino_int8_native.bin"));
    let full_blob = Blob::parse(&full).unwrap();
    assert!(
        without_head(&full_blob, HeadKind::Export).unwrap() == native,
        "weights/bino_int8_native.bin is not the shipped blob without its shared head: \
         bino quantize --only native --from weights/bino_int8.bin --out weights/bino_int8_native.bin --force"
    );
    assert!(native.len() <= 3 * 512 * 1024, "{} bytes", native.len());
    let native_blob = Blob::parse(&native).unwrap();
    // Every tensor but the shared head's, byte for byte; the shared head's, none.
    let mut kept = 0;
    for info in full_blob.tensors() {
        match head_of(info.id) {
            Some(HeadKind::Export) => assert!(native_blob.raw(info.id).is_err(), "{}", info.id),
            _ => {
                assert_eq!(native_blob.raw(info.id).unwrap(), full_blob.raw(info.id).unwrap());
                kept += 1;
            }
        }
    }
    assert_eq!(kept, native_blob.tensor_count());
    assert!(kept < full_blob.tensor_count());
}

#[test]
fn the_learned_frame_is_the_same_with_either_blob_and_the_export_pathway_needs_the_whole_one() {
    let (full, native) = (read("weights/bino_int8.bin"), read("weights/bino_int8_native.bin"));
    let (left, right) = (
        read("firmware-sim/assets/frame_120x160_left.gray"),
        read("firmware-sim/assets/frame_120x160_right.gray"),
    );
    let run = |blob: &[u8], run: Run| {
        let mut arena = vec![0u8; workload::arena_bytes(120, 160).max(workload::frame_arena_bytes(120, 160))];
        let mut source = SlicePair::new(&left, &right, 160, 120).unwrap();
        workload::run(blob, run, &mut source, &mut arena, &mut Quiet)
    };
    let with_full = run(&full, Run::Frame).unwrap();
    let with_native = run(&native, Run::Frame).unwrap();
    assert_eq!(with_full.digests, with_native.digests);
    assert_eq!(with_full.report.arena_used, with_native.report.arena_used);
    // The core names the first tensor it misses (the shared head's LayerNorm); the host's
    // verbs say which head and how to add it.
    let err = run(&native, Run::Export).map(|_| ()).unwrap_err().to_string();
    assert!(err.contains("no tensor 30:100"), "{err}");
    let model = bino_host::int8::Int8Model::from_bytes(native, "native.bin").unwrap();
    let err = model.require_head(HeadKind::Export).unwrap_err();
    assert!(format!("{err:#}").contains("no usable export pathway head"), "{err:#}");
    model.require_head(HeadKind::Native).unwrap();
}
