//! The encoder-free run: the census SGM of the views' pixels ([`crate::census`]) with its own
//! left-right check, token row by token row, optionally refined to pixels. It reads no weights
//! and runs no encoder, so it needs neither a blob nor the encoder's scratch: the fast readout
//! (`census`, `census+lr`, each optionally `+ref`) at a fraction of the learned ones' cost.
//!
//! Rows arrive into the same band buffer the encoder pathways use and bands advance by the same
//! plan ([`BandPlan`]), so every token row is computed once, from the band where it is furthest
//! from a cut (its census window, two view rows beyond its own, lies inside that band), and the
//! refinement reads its view rows from the buffer as on the matching readouts (no ring: the
//! census rows trail nothing). A band's rows are read as its token rows need them, four at a
//! time ([`BandRows::load_until`]), not all at the band's start: a camera feeding the run
//! through a few line buffers keeps up when it delivers rows no faster than they are worked on.
//!
//! Arena layout, in order: the two views' pixel band, the census stage (its SGM stream and one
//! row), the refinement's state, then its row scratch.

use super::api::{CensusRow, Options, Refine, RefineInput, Report, RowSource, Sink, Stage};
use super::census_stage::{self, CensusStage};
use super::feeding::BandRows;
use super::layout::band_pixel_rows;
use super::refine_stage::{RefineIoOf, Refinement, Scratch};
use super::sizing::{census_arena_bytes, refine_parts, CENSUS_RING_ROWS as RING_ROWS};
use crate::arena::split;
use crate::band::BandPlan;
use crate::census::{self, WINDOW_ROWS};
use crate::config::{check_view_size, PATCH_H};
use crate::model::head;
use crate::Error;

/// Runs the census readout over the pair `source` delivers, in `arena` ([`census_arena_bytes`]
/// bytes at least): each token row goes to [`Sink::census`]; with `refine` (whose input must be
/// [`RefineInput::Census`] or [`RefineInput::CensusLr`]) pixel rows go to [`Sink::refined`].
/// Of `opts` only `head_candidates` (the search range, 4 px a candidate) and `lr_max_diff_q8`
/// (the check's tolerance) are read.
///
/// Errors: the view size ([`check_view_size`]), [`Error::Candidates`] for a bad range,
/// [`Error::MissingReadout`] for a refinement of another readout, [`Error::OutOfRange`] for bad
/// refinement parameters, [`Error::ArenaTooSmall`], and whatever `source` returns.
pub fn run_census(
    source: &mut impl RowSource,
    opts: &Options,
    refine: Option<&Refine>,
    arena: &mut [u8],
    sink: &mut impl Sink,
) -> Result<Report, Error> {
    let (width, height) = (source.width(), source.height());
    let (token_rows, cols) = check_view_size(height, width)?;
    head::check_candidates(opts.head_candidates)?;
    if let Some(r) = refine {
        r.params.check()?;
        if !r.input.census_only() {
            return Err(Error::MissingReadout {
                readout: r.input.name(),
            });
        }
    }
    let needed = census_arena_bytes(height, width, opts, refine);
    crate::arena::check_size(arena, needed)?;
    let plan = BandPlan::new(token_rows)?;
    let band_px = band_pixel_rows(height);
    let pixel_len = band_px * width;
    let census_len = census_stage::bytes(width, opts.head_candidates, RING_ROWS);
    let (state_len, _) = match refine {
        Some(r) => refine_parts(height, width, r),
        None => (0, 0),
    };
    let too_small = Error::ArenaTooSmall {
        needed,
        available: arena.len(),
    };
    let (pixels, rest) = split(arena, 2 * pixel_len).ok_or(too_small)?;
    let (left_px, right_px) = pixels.split_at_mut(pixel_len);
    let (census_arena, rest) = split(rest, census_len).ok_or(too_small)?;
    let (state_arena, scratch) = split(rest, state_len).ok_or(too_small)?;
    let (mut census, census_used) = CensusStage::carve(
        census_arena,
        width,
        height,
        (opts.head_candidates, opts.lr_max_diff_q8),
        RING_ROWS,
        true,
    )?;
    let mut refinement = Refinement::new(refine, width, height, plan.len() > 1, state_arena)?;
    // View rows below a token row's pixel rows that the refinement reads (none without it).
    let reach = refine.map_or(0, |r| r.reach());
    // Which cells the refinement fills: `census+lr` by its check, `census` none.
    let fill = matches!(refine, Some(r) if matches!(r.input, RefineInput::CensusLr));
    let mut rows = BandRows::new(source, width);
    let mut report = Report {
        rows: token_rows,
        cols,
        bands: plan.len(),
        pixels: 2 * pixel_len,
        streams: census_used,
        ..Report::default()
    };
    let mut scratch_used = 0;
    for band in plan.iter() {
        rows.keep_for(band, left_px, right_px, Some(&mut refinement), sink)?;
        // The refiner's census rows stay valid for the band (the scratch is not lent out).
        let mut band_scratch = Scratch::of(refine, &mut *scratch, width, height)?;
        for row in band.keep_from..band.keep_to {
            // The view rows this token row's census window and its refined pixel rows read,
            // read only now: a camera's rows arrive while the rows above them are worked on.
            rows.load_until(band, rows_needed(row, reach), left_px, right_px, sink)?;
            let view = rows.view(left_px, right_px);
            sink.stage(Stage::Sgm);
            census.compute(row, &view)?;
            let (disparity_q8, consistent) = census.row(row)?;
            report.census_kept += consistent.iter().filter(|&&k| k != 0).count();
            sink.census(&CensusRow {
                row,
                disparity_q8,
                consistent,
            });
            if let Some((_, stage)) = refinement.0.as_mut() {
                sink.stage(Stage::Refine);
                let mut io = RefineIoOf {
                    view,
                    scratch: band_scratch,
                };
                let pushed = stage.push(row, disparity_q8, fill.then_some(consistent), &mut io, sink);
                band_scratch = io.scratch;
                pushed?;
            }
        }
        scratch_used = scratch_used.max(band_scratch.used());
    }
    if refine.is_some() {
        refinement.done()?;
        report.refine = refinement.used() + scratch_used;
    }
    report.arena_used = report.pixels + census_len + state_len + scratch_used;
    Ok(report)
}

/// Image rows (from the top) that token row `row`'s census window and the pixel rows it
/// completes ([`RefineStage::push`]: down to `4 row + 1`, each reading `reach` rows below) need.
/// The last token row completes the image's last rows too; the band's end caps it there.
const fn rows_needed(row: usize, reach: usize) -> usize {
    let census = census::window_row(row, WINDOW_ROWS - 1, usize::MAX).saturating_add(1);
    let refined = PATCH_H
        .saturating_mul(row)
        .saturating_add(PATCH_H / 2)
        .saturating_add(reach);
    if census > refined {
        census
    } else {
        refined
    }
}
