//! The core pipeline (`bino_core::pipeline`) on a host pair, its rows gathered into whole
//! token-grid maps: what `bino run` and `bino eval` read their int8 readouts from.

use std::time::{Duration, Instant};

use anyhow::{ensure, Result};
use bino_core::band::BandPlan;
use bino_core::config::PATCH_H;
use bino_core::matching::DISPARITY_FRAC_BITS;
use bino_core::model::head::HeadRow;
use bino_core::pipeline::{self, HeadChecked, MatchedRow, Options, Pipeline, Report, Sink, SlicePair, Stage};

use crate::data::profile::View;
use crate::eval::DisparityMap;
use crate::int8::Int8Model;
use crate::readout::refine::GrayViews;
use crate::readout::MethodMaps;

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
    ensure!(
        (left.width, left.height) == (right.width, right.height),
        "the views differ in size: {}x{} and {}x{}",
        left.width,
        left.height,
        right.width,
        right.height
    );
    let pipeline = Pipeline::new(model.blob()?).map_err(anyhow::Error::msg)?;
    let (w, h) = (left.width, left.height);
    let views = GrayViews::from_views(left, right)?;
    let mut source = SlicePair::new(&views.left, &views.right, w, h).map_err(anyhow::Error::msg)?;
    let arena_bytes = pipeline::arena_bytes_for(h, w, opts);
    let mut arena = vec![0u8; arena_bytes];
    let bands = BandPlan::new(h / PATCH_H).map_err(anyhow::Error::msg)?.len();
    let mut sink = Collect {
        bands,
        bands_started: 0,
        on_band,
        maps: Default::default(),
        stage_times: Stage::ALL.iter().map(|&s| (s, Duration::ZERO)).collect(),
        current: None,
    };
    let report = pipeline
        .run(&mut source, opts, &mut arena, &mut sink)
        .map_err(anyhow::Error::msg)?;
    sink.stage_done();
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
            views,
            census: Default::default(),
        },
        stage_times: sink.stage_times,
        report,
        arena_bytes,
    })
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
}

struct Collect<'p> {
    bands: usize,
    bands_started: usize,
    on_band: &'p mut dyn FnMut(usize, usize),
    maps: Rows,
    stage_times: Vec<(Stage, Duration)>,
    current: Option<(Stage, Instant)>,
}

impl Collect<'_> {
    /// Charges the time since the last stage change to that stage.
    fn stage_done(&mut self) {
        if let Some((stage, since)) = self.current.take() {
            if let Some(entry) = self.stage_times.iter_mut().find(|(s, _)| *s == stage) {
                entry.1 += since.elapsed();
            }
        }
    }
}

fn q8(values: &[u16]) -> impl Iterator<Item = f32> + '_ {
    let unit = (1u32 << DISPARITY_FRAC_BITS) as f32;
    values.iter().map(move |&d| d as f32 / unit)
}

impl Sink for Collect<'_> {
    fn stage(&mut self, stage: Stage) {
        self.stage_done();
        if stage == Stage::EncodeLeft || stage == Stage::EncodePair {
            self.bands_started += 1;
            (self.on_band)(self.bands_started, self.bands);
        }
        self.current = Some((stage, Instant::now()));
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
}
