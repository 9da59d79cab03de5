//! Every core on the host: a run's encoder passes computed ahead on several threads
//! (`bino_host::int8::pass_cache::PassCache::prefill`) and handed to the core's pipeline
//! (`Pipeline::run_encoded`) give the rows a one-thread run gives, bit for bit, on both
//! pathways, for one band and several; every pass the pipeline asks for was computed ahead
//! (none encoded during the run), and passes computed for other pixels are never replayed
//! (the run encodes its own and its rows stay the same).

use std::path::Path;

use bino_core::band::Band;
use bino_core::blob::Blob;
use bino_core::model::head::HeadRow;
use bino_core::pipeline::{
    arena_bytes_refined, FusedRow, HeadChecked, MatchedRow, Options, Pathway, Pipeline, Refine, Sink, SlicePair,
};
use bino_core::preset;
use bino_host::int8::pass_cache::PassCache;
use bino_tests::scene;

/// Every row the pipeline emits, in order, as bytes.
#[derive(Default, PartialEq, Eq)]
struct Rows(Vec<u8>);

impl Rows {
    fn put(&mut self, tag: u8, row: usize, values: &[u16]) {
        self.0.push(tag);
        self.0.extend_from_slice(&(row as u32).to_le_bytes());
        self.0.extend(values.iter().flat_map(|v| v.to_le_bytes()));
    }
}

impl Sink for Rows {
    fn band(&mut self, _: Band, left: &[i8], right: &[i8]) {
        self.0.extend(left.iter().chain(right).map(|&c| c as u8));
    }
    fn pair_band(&mut self, _: Band, tokens: &[i8]) {
        self.0.extend(tokens.iter().map(|&c| c as u8));
    }
    fn matched(&mut self, row: &MatchedRow<'_>) {
        self.put(1, row.row, row.wta_q8);
        self.put(2, row.row, row.sgm_q8);
    }
    fn head(&mut self, row: HeadRow<'_>) {
        self.put(3, row.row, row.disparity_q8);
    }
    fn head_checked(&mut self, row: &HeadChecked<'_>) {
        self.0.extend_from_slice(row.consistent);
    }
    fn fused(&mut self, row: &FusedRow<'_>) {
        self.0.extend_from_slice(&(row.row as u32).to_le_bytes());
    }
    fn refined(&mut self, row: usize, disparity_q8: &[u16]) {
        self.put(4, row, disparity_q8);
    }
}

fn preset(pathway: Pathway) -> (Options, Refine) {
    match pathway {
        Pathway::Export => (preset::EXPORT_OPTIONS, preset::EXPORT_REFINE),
        Pathway::Native => (preset::OPTIONS, preset::REFINE),
    }
}

/// The rows of one run, with the passes `passes` (none: the blob's encoder, one thread).
fn rows(pipeline: &Pipeline<'_>, pathway: Pathway, s: &bino_tests::Scene, passes: Option<&mut PassCache<'_>>) -> Rows {
    let (opts, refine) = preset(pathway);
    let mut arena = vec![0u8; arena_bytes_refined(s.height, s.width, &opts, &refine)];
    let mut source = SlicePair::new(&s.left, &s.right, s.width, s.height).unwrap();
    let mut out = Rows::default();
    match passes {
        Some(p) => pipeline.run_encoded(&mut source, &opts, Some(&refine), p, &mut arena, &mut out),
        None => pipeline.run_refined(&mut source, &opts, &refine, &mut arena, &mut out),
    }
    .unwrap();
    out
}

#[test]
fn passes_computed_ahead_give_the_one_thread_rows() {
    let bytes = std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join("../weights/bino_int8.bin")).unwrap();
    let blob = Blob::parse(&bytes).unwrap();
    let pipeline = Pipeline::new(blob).unwrap();
    let encoder = bino_core::model::encoder::Encoder::new(blob).unwrap();
    for pathway in [Pathway::Export, Pathway::Native] {
        for (width, height) in [(160, 48), (160, 120), (96, 100)] {
            let s = scene(width, height);
            let want = rows(&pipeline, pathway, &s, None);
            let mut cache = PassCache::new(encoder);
            cache.prefill(pathway, &s.left, &s.right, width, height, 3).unwrap();
            let ahead = cache.encoded;
            assert!(ahead > 0);
            let got = rows(&pipeline, pathway, &s, Some(&mut cache));
            assert!(
                got == want,
                "{pathway:?} {width}x{height}: rows differ from one thread's"
            );
            assert_eq!(
                cache.encoded, ahead,
                "{pathway:?} {width}x{height}: passes encoded in the run"
            );
            assert!(
                cache.replayed >= ahead,
                "{pathway:?} {width}x{height}: passes not replayed"
            );

            // Passes of other pixels (the views in negative) are never replayed: the run encodes
            // its own, and its rows stay the same.
            let negative = |v: &[u8]| v.iter().map(|p| 255 - p).collect::<Vec<u8>>();
            let (left, right) = (negative(&s.left), negative(&s.right));
            let mut other = PassCache::new(encoder);
            other.prefill(pathway, &left, &right, width, height, 2).unwrap();
            let got = rows(&pipeline, pathway, &s, Some(&mut other));
            assert!(got == want, "{pathway:?} {width}x{height}: rows from foreign passes");
            assert_eq!(
                other.replayed, 0,
                "{pathway:?} {width}x{height}: foreign passes replayed"
            );
        }
    }
}
