//! The int8 engine on every core at once: one encoder pass per thread, each on its own arena,
//! all started together. A round's wall time covers `threads` bands, so the host's throughput
//! is `threads` bands per round; the one-thread comparison stays the bench's headline.

use anyhow::{anyhow, Result};
use bino_core::model::encoder::{Encoder, GrayBand};
use bino_core::model::probe::NoProbe;
use serde::Serialize;

use super::{Timing, TimingJson};

/// The threads `bino bench` and `bino run` use by default: the cores the OS gives this process.
pub fn default_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Rounds of `threads` encoder passes run at once.
#[derive(Debug, Clone)]
pub struct AllCores {
    /// Passes per round, one per thread.
    pub threads: usize,
    /// Wall time of each round, in seconds.
    pub rounds: Timing,
}

impl AllCores {
    /// Median seconds per band: a round's median over its bands.
    pub fn per_band(&self) -> f64 {
        self.rounds.median() / self.threads as f64
    }

    /// Multiply-accumulates per second over the median round, all threads together.
    pub fn gmac_per_s(&self, macs: u64) -> f64 {
        macs as f64 / self.per_band() / 1e9
    }

    pub(super) fn json(&self, macs: u64) -> AllCoresJson<'_> {
        AllCoresJson {
            threads: self.threads,
            per_band_s: self.per_band(),
            gmac_per_s: self.gmac_per_s(macs),
            rounds: self.rounds.json(macs * self.threads as u64),
        }
    }
}

// The JSON of the all-cores figure.
#[derive(Serialize)]
pub(super) struct AllCoresJson<'a> {
    threads: usize,
    per_band_s: f64,
    gmac_per_s: f64,
    rounds: TimingJson<'a>,
}

/// Arenas and outputs for one round of `threads` passes over `band`.
pub(super) struct Round<'e> {
    encoder: Encoder<'e>,
    buffers: Vec<(Vec<u8>, Vec<i8>)>,
}

impl<'e> Round<'e> {
    pub(super) fn new(encoder: Encoder<'e>, threads: usize, arena_len: usize, out_len: usize) -> Self {
        Self {
            encoder,
            buffers: (0..threads)
                .map(|_| (vec![0u8; arena_len], vec![0i8; out_len]))
                .collect(),
        }
    }

    /// One pass per thread over `band`, all at once; the round's wall time in seconds.
    pub(super) fn run(&mut self, band: GrayBand<'_>) -> Result<f64> {
        let encoder = self.encoder;
        super::timed(|| {
            std::thread::scope(|scope| {
                let passes: Vec<_> = self
                    .buffers
                    .iter_mut()
                    .map(|(arena, out)| scope.spawn(move || encoder.describe(band, arena, out, &mut NoProbe)))
                    .collect();
                for pass in passes {
                    pass.join()
                        .map_err(|_| anyhow!("an encoder thread panicked"))?
                        .map_err(anyhow::Error::msg)?;
                }
                Ok(())
            })
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_round_of_bands_is_shared_out_per_band() {
        let all = AllCores {
            threads: 2,
            rounds: Timing {
                runs: vec![0.4, 0.2, 0.3],
            },
        };
        assert!((all.per_band() - 0.15).abs() < 1e-12);
        assert!((all.gmac_per_s(3_000_000_000) - 20.0).abs() < 1e-9);
        assert!(default_threads() >= 1);
    }
}
