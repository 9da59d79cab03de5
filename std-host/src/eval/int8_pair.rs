//! `bino eval`'s int8 readouts of one pair through the core's streaming pipeline, as `bino run`
//! computes them: one run for every readout's token grid and left-right mask (what
//! `bino run --refine off` upsamples), and for each `+ref` readout the core streams
//! ([`streamed_input`]) the pixel rows the core refined in a run of that readout with `bino run`'s
//! options ([`readout_options`]). The pair is encoded once: later runs replay its encoder passes
//! ([`PairRuns`]). The readouts the core does not stream (the unchecked fusions, and
//! `fuse-census` on the export pathway) are host-only analysis: fused and refined on whole maps
//! from the first run's rows ([`MethodMaps::pixels`]), marked `host_only` in the report.

use anyhow::Result;
use bino_core::pipeline::{Options, Refine};

use super::{DisparityMap, EvalItem, EvalOptions};
use crate::int8::pipeline_maps::{readout_options, run_census_stream, streamed_input, PairRuns};
use crate::int8::Int8Model;
use crate::readout::{head_candidates, lr_tolerance_q8, Method, MethodMaps, Readout};

/// One pair's int8 readouts.
pub struct Int8Pair {
    /// Every method's token grid and mask, from the core's rows.
    pub maps: MethodMaps,
    /// Per readout of [`EvalOptions::readouts`], in order: its pixels as the core refined them,
    /// for the `+ref` readouts the core streams (`None`: the pixels come from [`Int8Pair::maps`]).
    pub refined: Vec<Option<DisparityMap>>,
}

/// Whether `bino eval` computes `readout`'s int8 pixels on the host only: the core's streaming
/// pipeline does not stream it on this pathway.
pub fn host_only(opts: &EvalOptions, readout: Readout) -> bool {
    streamed_input(readout, opts.pathway).is_none()
}

/// The int8 readouts of `item` (see the module).
pub fn int8_pair(opts: &EvalOptions, model: &Int8Model, item: &EvalItem) -> Result<Int8Pair> {
    let (left, right) = (&item.left, &item.right);
    let width = left.width;
    let run_options = |readout: Readout| {
        readout_options(
            readout,
            opts.pathway,
            opts.max_cols,
            opts.penalties,
            opts.lr_max_diff,
            width,
        )
    };
    if opts.readouts.iter().all(|r| r.method == Method::Census) {
        // Nothing here reads the encoder: the core's encoder-free census run gives the grid and
        // each refined census readout's pixels.
        let grid_options = run_options(Readout::new(Method::Census, false));
        let maps = run_census_stream(left, right, &grid_options, Readout::new(Method::Census, false))?.methods;
        let refined = (opts.readouts.iter())
            .map(|&r| match r.refine {
                true => Ok(run_census_stream(left, right, &run_options(r), r)?.refined),
                false => Ok(None),
            })
            .collect::<Result<_>>()?;
        return Ok(Int8Pair { maps, refined });
    }
    let head = opts.readouts.iter().any(|r| r.uses_head());
    // Every readout's grid; the head's own check for head+lr and for head's LRkeep column.
    let grid_options = Options {
        pathway: opts.pathway.core(),
        max_cols: opts.max_cols,
        penalties: opts.penalties,
        lr_max_diff_q8: lr_tolerance_q8(opts.lr_max_diff),
        head,
        head_lr: head,
        head_candidates: head_candidates(width),
    };
    let mut pair = PairRuns::new(model, left, right)?;
    let mut refined: Vec<Option<DisparityMap>> = vec![None; opts.readouts.len()];
    // The grid run also refines the first streamed readout that runs with the same options.
    let shared = (opts.readouts.iter()).position(|&r| {
        let input = streamed_input(r, opts.pathway);
        r.refine && input.is_some_and(|i| !i.census_only()) && run_options(r) == grid_options
    });
    let shared_refine = shared.and_then(|i| refine_of(opts, opts.readouts[i], width));
    let first = pair.run(&grid_options, shared_refine.as_ref(), &mut |_, _| {})?;
    if let Some(i) = shared {
        refined[i] = first.refined;
    }
    for (i, &readout) in opts.readouts.iter().enumerate() {
        let Some(refine) = refine_of(opts, readout, width).filter(|_| Some(i) != shared) else {
            continue;
        };
        let options = run_options(readout);
        refined[i] = match refine.input.census_only() {
            true => run_census_stream(left, right, &options, readout)?.refined,
            false => pair.run(&options, Some(&refine), &mut |_, _| {})?.refined,
        };
    }
    Ok(Int8Pair {
        maps: first.methods,
        refined,
    })
}

/// The core's refinement of `readout` when it is a `+ref` readout the core streams.
fn refine_of(opts: &EvalOptions, readout: Readout, width: usize) -> Option<Refine> {
    let input = streamed_input(readout, opts.pathway).filter(|_| readout.refine)?;
    Some(Refine::for_width(input, width))
}
