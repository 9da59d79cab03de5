//! The whole pipeline on the shipped blob: any sizes (small), options, arena sizes, pixels,
//! and sources that lie about their size or fail part-way.
#![no_main]

use bino_core::blob::Blob;
use bino_core::Error;
use bino_fuzz::{run_pipeline, Run, SHIPPED_BLOB};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|run: Run| {
    let Ok(blob) = Blob::parse(SHIPPED_BLOB) else {
        panic!("the shipped blob must parse")
    };
    let result = run_pipeline(blob, &run);
    if run.reported_height.is_some_and(|h| h > bino_core::config::MAX_HEIGHT) {
        assert!(result.is_err(), "a height above the maximum must be refused");
    }
    if let Err(e) = result {
        // Every error has a message (Display must not panic either).
        let _ = format!("{e}");
        let _: Error = e;
    }
});
