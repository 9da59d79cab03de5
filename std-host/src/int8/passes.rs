//! A run's encoder passes computed ahead on every core ([`PassCache`]), handed to the core's
//! streaming pipeline through [`EncoderPasses`]: the pipeline then spends its time on the cheap
//! stages, and its outputs are bit for bit those of a one-thread run.
//!
//! The bands are the core's own band plan ([`bino_core::band::BandPlan`], with the band
//! buffer's height [`bino_core::pipeline::band_pixel_rows`]); each pass is stored under the exact
//! pixels it read, and the pipeline is served a pass only for those same pixels. A pass the
//! cache does not hold (a plan this module did not foresee) is computed on the spot, so a
//! wrong guess costs time, never a different answer; [`PassCache::misses`] counts them.

use std::cell::Cell;
use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use anyhow::{anyhow, Result};
use bino_core::band::BandPlan;
use bino_core::config::PATCH_H;
use bino_core::model::encoder::{arena_bytes, Encoder, EncoderPasses, GrayBand, RunReport};
use bino_core::pipeline::{band_pixel_rows, Pathway};
use bino_core::Error;

/// Threads the host's pipeline runs use for the encoder's passes: [`set_threads`], else the
/// cores the OS gives this process.
pub fn threads() -> usize {
    match THREADS.load(Ordering::Relaxed) {
        0 => crate::bench::all_cores::default_threads(),
        n => n,
    }
}

/// Sets [`threads`] for this process (`bino run --threads`); 0 restores the default. One
/// thread computes every pass when the pipeline reaches it, as the board does.
pub fn set_threads(n: usize) {
    THREADS.store(n, Ordering::Relaxed);
}

static THREADS: AtomicUsize = AtomicUsize::new(0);

/// One encoder pass a run will ask for: the descriptors of one view, or the pair's tokens.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Pass {
    Describe { view: Vec<u8> },
    Pair { left: Vec<u8>, right: Vec<u8> },
}

/// A pass's key: its kind, size and every pixel it reads.
fn key(pass: &Pass, width: usize, height: usize) -> Vec<u8> {
    let (kind, pixels): (u8, [&[u8]; 2]) = match pass {
        Pass::Describe { view } => (0, [view, &[]]),
        Pass::Pair { left, right } => (1, [left, right]),
    };
    let mut key = Vec::with_capacity(17 + pixels[0].len() + pixels[1].len());
    key.push(kind);
    key.extend_from_slice(&(width as u64).to_le_bytes());
    key.extend_from_slice(&(height as u64).to_le_bytes());
    key.extend_from_slice(pixels[0]);
    key.extend_from_slice(pixels[1]);
    key
}

/// The encoder passes of one pipeline run, computed ahead on `threads` threads.
pub struct PassCache<'w> {
    encoder: Encoder<'w>,
    passes: HashMap<Vec<u8>, (RunReport, Vec<u8>)>,
    misses: Cell<usize>,
}

impl<'w> PassCache<'w> {
    /// Every pass a `pathway` run over the `width x height` views asks for (the core's band
    /// plan: two descriptor passes a band on the export pathway, one pair pass a band on the
    /// native one), computed on up to `threads` threads at once.
    pub fn compute(
        encoder: Encoder<'w>,
        pathway: Pathway,
        left: &[u8],
        right: &[u8],
        width: usize,
        height: usize,
        threads: usize,
    ) -> Result<Self> {
        let rows = band_pixel_rows(height);
        let plan = BandPlan::new(height / PATCH_H).map_err(anyhow::Error::msg)?;
        let band = |image: &[u8], start: usize| -> Vec<u8> {
            image
                .get(start * width..(start + rows) * width)
                .unwrap_or_default()
                .to_vec()
        };
        let mut jobs = Vec::new();
        for b in plan.iter() {
            let start = b.start * PATCH_H;
            match pathway {
                Pathway::Export => {
                    jobs.push(Pass::Describe {
                        view: band(left, start),
                    });
                    jobs.push(Pass::Describe {
                        view: band(right, start),
                    });
                }
                Pathway::Native => jobs.push(Pass::Pair {
                    left: band(left, start),
                    right: band(right, start),
                }),
            }
        }
        jobs.dedup();
        let done = run_jobs(encoder, &jobs, width, rows, threads)?;
        let passes = jobs
            .iter()
            .zip(done)
            .map(|(pass, out)| (key(pass, width, rows), out))
            .collect();
        Ok(Self {
            encoder,
            passes,
            misses: Cell::new(0),
        })
    }

    /// Passes the pipeline asked for that were not computed ahead (computed when asked).
    pub fn misses(&self) -> usize {
        self.misses.get()
    }

    /// Passes computed ahead.
    pub fn len(&self) -> usize {
        self.passes.len()
    }

    /// Whether no pass was computed ahead.
    pub fn is_empty(&self) -> bool {
        self.passes.is_empty()
    }

    // The stored pass for `pass`, copied to the front of `arena`; `None` if there is none.
    fn serve(
        &self,
        pass: &Pass,
        width: usize,
        height: usize,
        arena: &mut [u8],
    ) -> Option<Result<(RunReport, usize), Error>> {
        let (report, out) = self.passes.get(&key(pass, width, height))?;
        Some(match arena.get_mut(..out.len()) {
            Some(front) => {
                front.copy_from_slice(out);
                Ok((*report, out.len()))
            }
            None => Err(Error::ArenaTooSmall {
                needed: out.len(),
                available: arena.len(),
            }),
        })
    }
}

impl EncoderPasses for PassCache<'_> {
    fn max_width(&self) -> usize {
        self.encoder.max_width()
    }

    fn describe_in_place(&self, view: GrayBand<'_>, arena: &mut [u8]) -> Result<(RunReport, usize), Error> {
        if !view.is_mirrored() {
            let pass = Pass::Describe {
                view: view.pixels().to_vec(),
            };
            if let Some(served) = self.serve(&pass, view.width(), view.height(), arena) {
                return served;
            }
        }
        self.misses.set(self.misses.get() + 1);
        EncoderPasses::describe_in_place(&self.encoder, view, arena)
    }

    fn pair_tokens_in_place(
        &self,
        left: GrayBand<'_>,
        right: GrayBand<'_>,
        arena: &mut [u8],
    ) -> Result<(RunReport, usize), Error> {
        if !left.is_mirrored() && !right.is_mirrored() && left.width() == right.width() {
            let pass = Pass::Pair {
                left: left.pixels().to_vec(),
                right: right.pixels().to_vec(),
            };
            if let Some(served) = self.serve(&pass, left.width(), left.height(), arena) {
                return served;
            }
        }
        self.misses.set(self.misses.get() + 1);
        EncoderPasses::pair_tokens_in_place(&self.encoder, left, right, arena)
    }
}

/// A computed pass: its report and output, or the encoder's error.
type PassResult = Result<(RunReport, Vec<u8>), Error>;

// Each job's report and output, in job order, the jobs shared out to `threads` threads (each
// with its own arena) as they finish their last.
fn run_jobs(
    encoder: Encoder<'_>,
    jobs: &[Pass],
    width: usize,
    rows: usize,
    threads: usize,
) -> Result<Vec<(RunReport, Vec<u8>)>> {
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<PassResult>>> = Mutex::new(vec![None; jobs.len()]);
    let worker = || {
        let mut arena = vec![0u8; arena_bytes(rows, width)];
        loop {
            let i = next.fetch_add(1, Ordering::Relaxed);
            let Some(job) = jobs.get(i) else {
                return;
            };
            let done = match job {
                Pass::Describe { view } => GrayBand::new(view, width, rows)
                    .and_then(|v| EncoderPasses::describe_in_place(&encoder, v, &mut arena)),
                Pass::Pair { left, right } => GrayBand::new(left, width, rows).and_then(|l| {
                    let r = GrayBand::new(right, width, rows)?;
                    EncoderPasses::pair_tokens_in_place(&encoder, l, r, &mut arena)
                }),
            }
            .map(|(report, len)| (report, arena[..len].to_vec()));
            if let Ok(mut slots) = results.lock() {
                slots[i] = Some(done);
            }
        }
    };
    std::thread::scope(|scope| {
        for _ in 1..threads.clamp(1, jobs.len().max(1)) {
            scope.spawn(worker);
        }
        worker();
    });
    let slots = results
        .into_inner()
        .map_err(|_| anyhow!("an encoder thread panicked"))?;
    slots
        .into_iter()
        .map(|slot| match slot {
            Some(Ok(done)) => Ok(done),
            Some(Err(e)) => Err(anyhow!("encoder pass: {e}")),
            None => Err(anyhow!("an encoder pass was never run")),
        })
        .collect()
}
