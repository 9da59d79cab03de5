//! The stage markers: one `extern "C"` function `bino_mark_<stage>` per stage, whose address the
//! QEMU instruction-count plugin (`qemu-plugin/`) watches; each call starts that stage's count.
//! `bino_mark_end` starts work outside the stages (digests, stack scans, logging).

use core::ptr::addr_of_mut;

use crate::workload::Stage;

/// The stage the firmware is in (written by the markers, which also keeps them distinct).
static mut CURRENT: u32 = u32::MAX;

macro_rules! markers {
    ($($name:ident = $id:expr;)*) => {
        $(
            #[no_mangle]
            #[inline(never)]
            #[doc = "Marker the instruction-count plugin watches."]
            pub extern "C" fn $name() {
                // SAFETY: only the main thread writes CURRENT; the camera's interrupt never
                // touches it.
                unsafe { core::ptr::write_volatile(addr_of_mut!(CURRENT), $id) };
            }
        )*
    };
}

markers! {
    bino_mark_load = 0;
    bino_mark_rows = 1;
    bino_mark_encode_left = 2;
    bino_mark_encode_right = 3;
    bino_mark_match = 4;
    bino_mark_sgm = 5;
    bino_mark_left_right = 6;
    bino_mark_head = 7;
    bino_mark_refine = 8;
    bino_mark_encode_pair = 9;
    bino_mark_native_rows = 101;
    bino_mark_native_encode_left = 102;
    bino_mark_native_encode_right = 103;
    bino_mark_native_match = 104;
    bino_mark_native_sgm = 105;
    bino_mark_native_left_right = 106;
    bino_mark_native_head = 107;
    bino_mark_native_refine = 108;
    bino_mark_native_encode_pair = 109;
    bino_mark_census_rows = 201;
    bino_mark_census_sgm = 205;
    bino_mark_census_refine = 208;
    bino_mark_frame_rows = 301;
    bino_mark_frame_encode_left = 302;
    bino_mark_frame_encode_right = 303;
    bino_mark_frame_match = 304;
    bino_mark_frame_sgm = 305;
    bino_mark_frame_left_right = 306;
    bino_mark_frame_head = 307;
    bino_mark_frame_refine = 308;
    bino_mark_frame_encode_pair = 309;
    bino_mark_census320_rows = 401;
    bino_mark_census320_sgm = 405;
    bino_mark_census320_refine = 408;
    bino_mark_frame320_rows = 501;
    bino_mark_frame320_encode_left = 502;
    bino_mark_frame320_encode_right = 503;
    bino_mark_frame320_match = 504;
    bino_mark_frame320_sgm = 505;
    bino_mark_frame320_left_right = 506;
    bino_mark_frame320_head = 507;
    bino_mark_frame320_refine = 508;
    bino_mark_frame320_encode_pair = 509;
    bino_mark_end = 0xFFFF;
}

/// Starts the count of `stage`.
pub fn mark(stage: Stage) {
    use bino_core::pipeline::Stage as P;
    match stage {
        Stage::Load => bino_mark_load(),
        Stage::Pipeline(P::Rows) => bino_mark_rows(),
        Stage::Pipeline(P::EncodeLeft) => bino_mark_encode_left(),
        Stage::Pipeline(P::EncodeRight) => bino_mark_encode_right(),
        Stage::Pipeline(P::Match) => bino_mark_match(),
        Stage::Pipeline(P::Sgm) => bino_mark_sgm(),
        Stage::Pipeline(P::LeftRight) => bino_mark_left_right(),
        Stage::Pipeline(P::Head) => bino_mark_head(),
        Stage::Pipeline(P::Refine) => bino_mark_refine(),
        Stage::Pipeline(P::EncodePair) => bino_mark_encode_pair(),
        Stage::Native(P::Rows) => bino_mark_native_rows(),
        Stage::Native(P::EncodeLeft) => bino_mark_native_encode_left(),
        Stage::Native(P::EncodeRight) => bino_mark_native_encode_right(),
        Stage::Native(P::Match) => bino_mark_native_match(),
        Stage::Native(P::Sgm) => bino_mark_native_sgm(),
        Stage::Native(P::LeftRight) => bino_mark_native_left_right(),
        Stage::Native(P::Head) => bino_mark_native_head(),
        Stage::Native(P::Refine) => bino_mark_native_refine(),
        Stage::Native(P::EncodePair) => bino_mark_native_encode_pair(),
        Stage::Census(P::Rows) => bino_mark_census_rows(),
        Stage::Census(P::Refine) => bino_mark_census_refine(),
        // run_census enters no other stage; were it to, it would count as the SGM's.
        Stage::Census(_) => bino_mark_census_sgm(),
        Stage::Frame(P::Rows) => bino_mark_frame_rows(),
        Stage::Frame(P::EncodeLeft) => bino_mark_frame_encode_left(),
        Stage::Frame(P::EncodeRight) => bino_mark_frame_encode_right(),
        Stage::Frame(P::Match) => bino_mark_frame_match(),
        Stage::Frame(P::Sgm) => bino_mark_frame_sgm(),
        Stage::Frame(P::LeftRight) => bino_mark_frame_left_right(),
        Stage::Frame(P::Head) => bino_mark_frame_head(),
        Stage::Frame(P::Refine) => bino_mark_frame_refine(),
        Stage::Frame(P::EncodePair) => bino_mark_frame_encode_pair(),
        Stage::Census320(P::Rows) => bino_mark_census320_rows(),
        Stage::Census320(P::Refine) => bino_mark_census320_refine(),
        Stage::Census320(_) => bino_mark_census320_sgm(),
        Stage::Frame320(P::Rows) => bino_mark_frame320_rows(),
        Stage::Frame320(P::EncodeLeft) => bino_mark_frame320_encode_left(),
        Stage::Frame320(P::EncodeRight) => bino_mark_frame320_encode_right(),
        Stage::Frame320(P::Match) => bino_mark_frame320_match(),
        Stage::Frame320(P::Sgm) => bino_mark_frame320_sgm(),
        Stage::Frame320(P::LeftRight) => bino_mark_frame320_left_right(),
        Stage::Frame320(P::Head) => bino_mark_frame320_head(),
        Stage::Frame320(P::Refine) => bino_mark_frame320_refine(),
        Stage::Frame320(P::EncodePair) => bino_mark_frame320_encode_pair(),
    }
}
