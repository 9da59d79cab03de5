//! The whole stereo pipeline in one caller-provided arena: image rows in, disparity rows out.
//!
//! Rows arrive top to bottom, as a sensor delivers them ([`RowSource`]), into a buffer of one
//! band (at most 48 rows) per view. Each band is encoded twice, on (L, L) and on (R, R) — the
//! descriptor pathway — and each token row it keeps (see [`crate::band`]) goes at once to
//! - the no-linkage readout: cosine WTA + parabola ([`crate::matching`]),
//! - streaming 4-path SGM on the same cosine costs ([`crate::sgm`]),
//! - the left-right check of both, from the reindexed cost row ([`crate::lr`]),
//! - the shared head, when asked for ([`crate::model::head`]);
//!
//! and, with [`Pipeline::run_refined`], one readout's token rows go on to the pixel
//! refinement ([`crate::refine`]), which emits pixel rows ([`Sink::refined`]). The encoder
//! passes are the blob's encoder's, or with [`Pipeline::run_encoded`] a [`BandEncoder`] that
//! answers with the same bytes (a host refining several readouts of one pair replays the first
//! run's passes).
//!
//! Memory depends on the band and the width, never on the image height. Arena layout, in
//! order: the two views' pixel band, the left descriptors of the band, then
//! - one band (images up to 48 rows): the encoder's scratch, reused after both passes for the
//!   right descriptors (written in place), the readout streams and the refinement's state and
//!   row scratch;
//! - several bands: the readout streams and the refinement's state (they carry state from band
//!   to band), then the encoder's scratch, which between passes holds the right descriptors and
//!   the refinement's row scratch.
//!
//! With weights whose token rows are independent (the shipped ones) the encoder runs
//! [`TOKEN_ROWS_PER_PASS`] token rows a pass ([`Passes`]), each pass's outputs after the last,
//! so its scratch holds one pass's work beside the band's outputs instead of the whole band's;
//! [`Pipeline::arena_bytes`] is a blob's own size, the free `const fn`s here size for any weights.
//!
//! # The refinement
//! [`Refine`] names the readout whose token grid is refined ([`RefineInput`]; the rule of
//! [`Refine::for_options`]: head+lr when the run checks the head, else sgm+lr), the
//! parameters and whether the views' sharpness is equalised first (on in every preset). A `+lr`
//! input is the readout's row filled by its own left-right check ([`RefineInput::fill`], as
//! the host fills), so the pixel rows equal
//! [`crate::refine::sharpness::refine_map_equalised`] (or, without equalisation,
//! [`crate::refine::refine_map`]) on the filled token map. The stage reads the view rows from the
//! band buffer; only the head's rows, which trail the band by six token rows, need a small
//! ring of view rows with several bands (see `refine_stage.rs`). For a 48x160 band pair the
//! arena does not grow: the refinement fits beside the streams in the encoder's scratch.
//!
//! # Files
//! Layered bottom up, each importing only the layers below it (a test in
//! `tests/tests/pipeline_layering.rs` keeps it so): `layout.rs`, the leaf (saturating sizes, the
//! band buffer's rows, the head's lag, the refinement's reach); `api.rs`, the public types;
//! `refine_stage.rs`, the pixel refinement as a stage; `census_stage.rs`, the census SGM as a
//! stage, and `feeding.rs`, the band buffer; `head_check.rs`, the head's rows, its left-right
//! check and the fusions fed from them; `sizing.rs`, the arena sizes, each stage's own summed;
//! `context.rs`, what a run's stages share; `streams.rs` (the export pathway's readouts),
//! `native.rs` (the native pathway) and `census_run.rs` (the encoder-free census readout,
//! [`run_census`]); `export.rs`, the export pathway's band loop; `driver.rs`, [`Pipeline`].
//! Every band loop is one loop for one band and several (`feeding::BandRows::advance` loads a
//! band after the refinement kept the rows it still needs; `refine_stage::Refinement` is the
//! refinement every loop carries).

mod api;
mod census_run;
mod census_stage;
mod context;
mod driver;
mod export;
mod feeding;
mod head_check;
mod layout;
mod native;
mod refine_stage;
mod row_buffers;
mod row_passes;
mod sizing;
mod streams;

/// A head row as [`Sink::head`] receives it.
pub use crate::model::head::HeadRow;
pub use api::{
    BandEncoder, CensusRow, FusedRow, HeadChecked, MatchedRow, Options, Passes, Pathway, Refine, RefineInput, Report,
    RowSource, Sink, SlicePair, Stage, TOKEN_ROWS_PER_PASS,
};
pub use census_run::run_census;
pub use driver::Pipeline;
pub use layout::band_pixel_rows;
pub use sizing::{
    arena_bytes, arena_bytes_for, arena_bytes_head_lr, arena_bytes_refined, arena_bytes_with, census_arena_bytes,
    refine_bytes,
};
