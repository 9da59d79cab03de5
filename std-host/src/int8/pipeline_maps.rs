//! The core pipeline (`bino_core::pipeline`) on a host pair, its rows gathered into whole
//! token-grid maps and its refined pixel rows into a map: what `bino run` and `bino eval` read
//! their int8 readouts from ([`PairRuns`]: `bino eval` runs a pair once per refined readout and
//! encodes it once). The census readouts run the core's encoder-free stream
//! ([`run_census_stream`]): no blob, no encoder, their pixels refined in the core. Which readouts
//! the core streams, and with which options every command runs them: [`streamed_input`],
//! [`readout_options`].

use std::time::{Duration, Instant};

use anyhow::{ensure, Result};
use bino_core::band::BandPlan;
use bino_core::config::PATCH_H;
use bino_core::matching::DISPARITY_FRAC_BITS;
use bino_core::model::head::HeadRow;
use bino_core::pipeline::{
    self, CensusRow, HeadChecked, MatchedRow, Options, Pipeline, Refine, RefineInput, Report, Sink, SlicePair, Stage,
};

use bino_core::sgm::Penalties;

use super::pass_cache::{self, PassCache};
use crate::data::profile::View;
use crate::eval::DisparityMap;
use crate::int8::Int8Model;
use crate::readout::pathway::Pathway;
use crate::readout::refine::GrayViews;
use crate::readout::{head_candidates, lr_tolerance_q8, Method, MethodMaps, Readout};

/// Every method of one run as token-grid maps (patch columns), with their left-right masks.
#[derive(Debug, Clone)]
pub struct PipelineMaps {
    /// The methods' maps and masks (the head's when the options asked for it).
    pub methods: MethodMaps,
    /// Wall time inside the pipeline, per stage.
    pub stage_times: Vec<(Stage, Duration)>,
    /// The core's report (arena by part, bands, kept counts).
    pub report: Report,
    /// Arena bytes allocated for the run.
    pub arena_bytes: usize,
    /// The readout's pixels as the core refined them, when the run refined one
    /// ([`run_census_stream`] of a `+ref` readout).
    pub refined: Option<DisparityMap>,
}

/// The core's refinement input for `readout` when the core's pipeline streams it on
/// `pathway`: every readout but the unchecked fusions (`fuse`, `fuse-census`, `fuse-all`) and
/// `fuse-census+lr` on the export pathway (the core fuses the census with the native head only;
/// the export pathway's census fusion is `fuse-all+lr`). The others are host-only analysis:
/// fused and refined on whole maps.
pub fn streamed_input(readout: Readout, pathway: Pathway) -> Option<RefineInput> {
    Some(match (readout.method, readout.lr) {
        (Method::Nolink, false) => RefineInput::Nolink,
        (Method::Nolink, true) => RefineInput::NolinkLr,
        (Method::Sgm, false) => RefineInput::Sgm,
        (Method::Sgm, true) => RefineInput::SgmLr,
        (Method::Head, false) => RefineInput::Head,
        (Method::Head, true) => RefineInput::HeadLr,
        (Method::Fused, true) => RefineInput::FusedLr,
        (Method::CensusFused, true) if pathway == Pathway::Native => RefineInput::FusedCensusLr,
        (Method::FusedAll, true) => RefineInput::FusedAllLr,
        (Method::Census, false) => RefineInput::Census,
        (Method::Census, true) => RefineInput::CensusLr,
        (Method::CensusFused, true) | (Method::Fused | Method::CensusFused | Method::FusedAll, false) => return None,
    })
}

/// The core pipeline's options for a run of `readout` on `width`-pixel views, the same in
/// `bino run`, `bino sim` and `bino eval`: the head (with its own left-right check) only when the
/// readout reads it; the census check's tolerance one patch column
/// ([`crate::readout::census::CENSUS_LR_MAX_DIFF_Q8`]) on every command.
pub fn readout_options(
    readout: Readout,
    pathway: Pathway,
    max_cols: usize,
    penalties: Penalties,
    lr_max_diff: f32,
    width: usize,
) -> Options {
    let head = readout.uses_head();
    Options {
        pathway: pathway.core(),
        max_cols,
        penalties,
        lr_max_diff_q8: match readout.method {
            Method::Census => crate::readout::census::CENSUS_LR_MAX_DIFF_Q8,
            _ => lr_tolerance_q8(lr_max_diff),
        },
        head,
        head_lr: head,
        head_candidates: head_candidates(width),
    }
}

/// Runs the int8 pipeline on two views of the same size; `on_band(i, n)` as band `i` of `n`
/// starts encoding.
pub fn run_pipeline(
    model: &Int8Model,
    left: &View,
    right: &View,
    opts: &Options,
    on_band: &mut dyn FnMut(usize, usize),
) -> Result<PipelineMaps> {
    run_pipeline_refined(model, left, right, opts, None, on_band)
}

/// [`run_pipeline`], with the core's refinement of `refine.input`'s grid streamed beside the
/// readouts ([`PipelineMaps::refined`]): what `bino run` writes for a `+ref` readout the core
/// streams, equal to the whole-map refinement of the same grid ([`MethodMaps::pixels`]).
pub fn run_pipeline_refined(
    model: &Int8Model,
    left: &View,
    right: &View,
    opts: &Options,
    refine: Option<&Refine>,
    on_band: &mut dyn FnMut(usize, usize),
) -> Result<PipelineMaps> {
    PairRuns::new(model, left, right)?.run(opts, refine, on_band)
}

/// One pair through the core's pipeline as often as its readouts need (`bino eval`: one run
/// for every readout's grid, one per refined readout), each band encoded once: later runs
/// replay the first run's encoder passes ([`PassCache`]).
pub struct PairRuns<'m> {
    pipeline: Pipeline<'m>,
    passes: PassCache<'m>,
    views: GrayViews,
}

impl<'m> PairRuns<'m> {
    /// The pair of two views of the same size, for the pipeline of `model`.
    pub fn new(model: &'m Int8Model, left: &View, right: &View) -> Result<Self> {
        ensure!(
            (left.width, left.height) == (right.width, right.height),
            "the views differ in size: {}x{} and {}x{}",
            left.width,
            left.height,
            right.width,
            right.height
        );
        let blob = model.blob()?;
        Ok(Self {
            pipeline: Pipeline::new(blob).map_err(anyhow::Error::msg)?,
            passes: PassCache::new(model.encoder()?),
            views: GrayViews::from_views(left, right)?,
        })
    }

    /// Encoder passes run and replayed so far.
    pub fn passes(&self) -> (usize, usize) {
        (self.passes.encoded, self.passes.replayed)
    }

    /// One run of the pipeline with `opts`, refining `refine.input`'s grid when given
    /// ([`run_pipeline_refined`]).
    pub fn run(
        &mut self,
        opts: &Options,
        refine: Option<&Refine>,
        on_band: &mut dyn FnMut(usize, usize),
    ) -> Result<PipelineMaps> {
        let views = &self.views;
        let (w, h) = (views.width, views.height);
        let mut source = SlicePair::new(&views.left, &views.right, w, h).map_err(anyhow::Error::msg)?;
        // The blob's own size: what a board running this blob sizes its arena by.
        let arena_bytes = self.pipeline.arena_bytes(h, w, opts, refine);
        let mut arena = vec![0u8; arena_bytes];
        let bands = BandPlan::new(h / PATCH_H).map_err(anyhow::Error::msg)?.len();
        let mut sink = Collect {
            bands,
            bands_started: 0,
            on_band,
            maps: Default::default(),
            times: StageTimes::new(),
        };
        // On several cores the run's encoder passes are computed ahead, a band a thread, and
        // the pipeline replays them: the same outputs as one thread's.
        let threads = pass_cache::threads();
        if threads > 1 {
            let ahead = Instant::now();
            self.passes
                .prefill(opts.pathway, &views.left, &views.right, w, h, threads)?;
            let stage = match opts.pathway {
                bino_core::pipeline::Pathway::Export => Stage::EncodeLeft,
                bino_core::pipeline::Pathway::Native => Stage::EncodePair,
            };
            sink.times.times.push((stage, ahead.elapsed()));
        }
        let report = (self.pipeline)
            .run_encoded(&mut source, opts, refine, &mut self.passes, &mut arena, &mut sink)
            .map_err(anyhow::Error::msg)?;
        ensure!(
            sink.maps.refined.len() == if refine.is_some() { w * h } else { 0 },
            "the pipeline refined {} of {} pixels",
            sink.maps.refined.len(),
            w * h
        );
        sink.times.stage_done();
        let (rows, cols) = (report.rows, report.cols);
        let m = sink.maps;
        let cells = rows * cols;
        // The native pathway has no matching readouts.
        let matched = opts.pathway == bino_core::pipeline::Pathway::Export;
        let expected_matched = if matched { cells } else { 0 };
        ensure!(
            m.wta.len() == expected_matched
                && m.sgm.len() == expected_matched
                && (m.head.is_empty() || m.head.len() == cells)
                && (m.head_mask.is_empty() || m.head_mask.len() == cells),
            "the pipeline emitted {} WTA, {} SGM, {} head and {} head check cells for {rows}x{cols}",
            m.wta.len(),
            m.sgm.len(),
            m.head.len(),
            m.head_mask.len()
        );
        let map = |values: Vec<f32>| DisparityMap {
            width: cols,
            height: rows,
            values,
        };
        let head_ran = !m.head.is_empty();
        let check_ran = head_ran && opts.head_lr;
        Ok(PipelineMaps {
            methods: MethodMaps {
                nolink: matched.then(|| map(m.wta)),
                sgm: matched.then(|| map(m.sgm)),
                head: head_ran.then(|| map(m.head)),
                nolink_consistent: m.wta_mask,
                sgm_consistent: m.sgm_mask,
                head_consistent: check_ran.then_some(m.head_mask),
                head_confidence: head_ran.then_some(m.head_confidence),
                views: views.clone(),
                census: Default::default(),
            },
            stage_times: sink.times.times,
            report,
            arena_bytes,
            refined: refine.map(|_| DisparityMap {
                width: w,
                height: h,
                values: q8(&m.refined).collect(),
            }),
        })
    }
}

/// The core's encoder-free census run (`bino_core::pipeline::run_census`) on two views of the
/// same size, for a census readout (`census`, `census+lr`, each optionally `+ref`): the census
/// grid and its check's mask as [`MethodMaps::census`] (no other method), and for `+ref` the
/// pixels the core refined (Q8 px / 256), which equal [`MethodMaps::pixels`] of that grid.
/// Of `opts` the census reads `head_candidates` (its check's tolerance is
/// [`crate::readout::census::CENSUS_LR_MAX_DIFF_Q8`], as everywhere on the host).
pub fn run_census_stream(left: &View, right: &View, opts: &Options, readout: Readout) -> Result<PipelineMaps> {
    ensure!(
        readout.method == Method::Census,
        "{readout} is not a census readout: it needs the encoder"
    );
    ensure!(
        (left.width, left.height) == (right.width, right.height),
        "the views differ in size: {}x{} and {}x{}",
        left.width,
        left.height,
        right.width,
        right.height
    );
    let (w, h) = (left.width, left.height);
    let views = GrayViews::from_views(left, right)?;
    let input = if readout.lr {
        RefineInput::CensusLr
    } else {
        RefineInput::Census
    };
    let refine = readout.refine.then(|| Refine::for_width(input, w));
    // The census check's tolerance is one column on every command (`bino eval`'s census grid).
    let opts = &Options {
        lr_max_diff_q8: crate::readout::census::CENSUS_LR_MAX_DIFF_Q8,
        ..*opts
    };
    let mut source = SlicePair::new(&views.left, &views.right, w, h).map_err(anyhow::Error::msg)?;
    let arena_bytes = pipeline::census_arena_bytes(h, w, opts, refine.as_ref());
    let mut arena = vec![0u8; arena_bytes];
    let mut sink = CensusCollect {
        width: w,
        times: StageTimes::new(),
        grid: Vec::new(),
        mask: Vec::new(),
        refined: Vec::new(),
    };
    let report =
        pipeline::run_census(&mut source, opts, refine.as_ref(), &mut arena, &mut sink).map_err(anyhow::Error::msg)?;
    sink.times.stage_done();
    let (rows, cols) = (report.rows, report.cols);
    ensure!(
        sink.grid.len() == rows * cols && sink.mask.len() == rows * cols,
        "the census run emitted {} cells for {rows}x{cols}",
        sink.grid.len()
    );
    ensure!(
        sink.refined.len() == if refine.is_some() { w * h } else { 0 },
        "the census run refined {} of {} pixels",
        sink.refined.len(),
        w * h
    );
    let grid = DisparityMap {
        width: cols,
        height: rows,
        values: q8(&sink.grid).collect(),
    };
    let census = std::cell::OnceCell::new();
    let _ = census.set((grid, sink.mask.iter().map(|&k| k != 0).collect()));
    let refined = refine.map(|_| DisparityMap {
        width: w,
        height: h,
        values: q8(&sink.refined).collect(),
    });
    Ok(PipelineMaps {
        methods: MethodMaps {
            nolink: None,
            sgm: None,
            head: None,
            nolink_consistent: Vec::new(),
            sgm_consistent: Vec::new(),
            head_consistent: None,
            head_confidence: None,
            views,
            census,
        },
        stage_times: sink.times.times,
        report,
        arena_bytes,
        refined,
    })
}

/// Wall time per pipeline stage, charged at each stage change.
struct StageTimes {
    times: Vec<(Stage, Duration)>,
    current: Option<(Stage, Instant)>,
}

impl StageTimes {
    fn new() -> Self {
        Self {
            times: Stage::ALL.iter().map(|&s| (s, Duration::ZERO)).collect(),
            current: None,
        }
    }

    /// Charges the time since the last stage change to that stage.
    fn stage_done(&mut self) {
        if let Some((stage, since)) = self.current.take() {
            if let Some(entry) = self.times.iter_mut().find(|(s, _)| *s == stage) {
                entry.1 += since.elapsed();
            }
        }
    }

    fn enter(&mut self, stage: Stage) {
        self.stage_done();
        self.current = Some((stage, Instant::now()));
    }
}

/// The census run's rows, gathered.
struct CensusCollect {
    width: usize,
    times: StageTimes,
    grid: Vec<u16>,
    mask: Vec<u8>,
    refined: Vec<u16>,
}

impl Sink for CensusCollect {
    fn stage(&mut self, stage: Stage) {
        self.times.enter(stage);
    }

    fn census(&mut self, row: &CensusRow<'_>) {
        self.grid.extend_from_slice(row.disparity_q8);
        self.mask.extend_from_slice(row.consistent);
    }

    fn refined(&mut self, row: usize, disparity_q8: &[u16]) {
        // Rows arrive once each, top to bottom (the core's contract).
        debug_assert_eq!(self.refined.len(), row * self.width);
        self.refined.extend_from_slice(disparity_q8);
    }
}

#[derive(Default)]
struct Rows {
    wta: Vec<f32>,
    sgm: Vec<f32>,
    head: Vec<f32>,
    head_confidence: Vec<u16>,
    wta_mask: Vec<bool>,
    sgm_mask: Vec<bool>,
    head_mask: Vec<bool>,
    /// Refined pixel rows, Q8 px, in order.
    refined: Vec<u16>,
}

struct Collect<'p> {
    bands: usize,
    bands_started: usize,
    on_band: &'p mut dyn FnMut(usize, usize),
    maps: Rows,
    times: StageTimes,
}

fn q8(values: &[u16]) -> impl Iterator<Item = f32> + '_ {
    let unit = (1u32 << DISPARITY_FRAC_BITS) as f32;
    values.iter().map(move |&d| d as f32 / unit)
}

impl Sink for Collect<'_> {
    fn stage(&mut self, stage: Stage) {
        if stage == Stage::EncodeLeft || stage == Stage::EncodePair {
            self.bands_started += 1;
            (self.on_band)(self.bands_started, self.bands);
        }
        self.times.enter(stage);
    }

    fn matched(&mut self, row: &MatchedRow<'_>) {
        self.maps.wta.extend(q8(row.wta_q8));
        self.maps.sgm.extend(q8(row.sgm_q8));
        self.maps.wta_mask.extend(row.wta_consistent.iter().map(|&m| m != 0));
        self.maps.sgm_mask.extend(row.sgm_consistent.iter().map(|&m| m != 0));
    }

    fn head(&mut self, row: HeadRow<'_>) {
        self.maps.head.extend(q8(row.disparity_q8));
        self.maps.head_confidence.extend(row.confidence_q8);
    }

    fn head_checked(&mut self, row: &HeadChecked<'_>) {
        self.maps.head_mask.extend(row.consistent.iter().map(|&m| m != 0));
    }

    fn refined(&mut self, _row: usize, disparity_q8: &[u16]) {
        // Rows arrive once each, top to bottom (the core's contract, checked by its tests).
        self.maps.refined.extend_from_slice(disparity_q8);
    }
}
