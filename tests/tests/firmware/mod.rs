//! The QEMU firmware's workload (`firmware-sim/src/workload.rs`, word for word) for the tests
//! that run it on the host, with hooks that do nothing (no stage markers, no stack scans).

#[path = "../../../firmware-sim/src/workload.rs"]
#[allow(dead_code)]
pub mod workload;

use workload::{Hooks, Stage};

/// Hooks for a host run: it needs none.
pub struct Quiet;

impl Hooks for Quiet {
    fn enter(&mut self, _: Stage) {}
    fn pause(&mut self) {}
    fn resume(&mut self, _: Stage) {}
    fn finish(&mut self) {}
}
