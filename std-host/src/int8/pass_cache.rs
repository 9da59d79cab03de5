//! A pair's encoder passes, kept for the pair's next pipeline runs ([`PassCache`]): `bino eval`
//! runs the core's pipeline once per refined readout of a pair and encodes the pair once. A
//! pass is replayed only for band pixels identical to the ones it was computed from, so each
//! run gets the bytes the blob's encoder gives for that band (the encoder is deterministic:
//! `tests/tests/determinism.rs`); the rest of the pipeline runs as it always does.
//!
//! On a host with several cores the record is filled ahead ([`PassCache::prefill`]): the
//! passes of the core's band plan ([`BandPlan`], band buffers of [`band_pixel_rows`]; with
//! independent token rows a pass a few token rows) computed a pass a thread, so the pipeline that follows spends its time on the cheap stages, with the
//! same outputs as one thread's (`tests/tests/threads.rs`). A band the plan did not foresee is
//! encoded when asked, so a wrong guess costs time, never a different answer.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;

use anyhow::{anyhow, Result};
use bino_core::band::BandPlan;
use bino_core::config::PATCH_H;
use bino_core::model::encoder::{arena_bytes, Encoder, GrayBand};
use bino_core::pipeline::{band_pixel_rows, BandEncoder, Pathway, TOKEN_ROWS_PER_PASS};
use bino_core::Error;

/// Threads [`PassCache::prefill`] runs on for the host's pipeline runs (`bino run`, `bino eval`,
/// `bino demo`): [`set_threads`], else the cores the OS gives this process.
pub fn threads() -> usize {
    match THREADS.load(Ordering::Relaxed) {
        0 => crate::bench::all_cores::default_threads(),
        n => n,
    }
}

/// Sets [`threads`] for this process (`bino run --threads`); 0 restores the default. With one
/// thread nothing is computed ahead: each pass runs when the pipeline reaches it, as on a board.
pub fn set_threads(n: usize) {
    THREADS.store(n, Ordering::Relaxed);
}

static THREADS: AtomicUsize = AtomicUsize::new(0);

/// The blob's encoder, answering a band it has encoded before from its record.
pub struct PassCache<'w> {
    encoder: Encoder<'w>,
    passes: Vec<Pass>,
    /// Passes the encoder ran.
    pub encoded: usize,
    /// Passes answered from the record.
    pub replayed: usize,
}

/// What a pass reads.
#[derive(PartialEq)]
struct Key {
    /// The band's pixels: the view's, or (a pair pass) the left view's then the right's.
    input: Vec<u8>,
    width: usize,
    pair: bool,
    /// Each view read right to left.
    mirrored: [bool; 2],
}

/// One recorded pass: what it read, and what it wrote at the front of the arena.
struct Pass {
    key: Key,
    arena_used: usize,
    output: Vec<u8>,
}

impl<'w> PassCache<'w> {
    /// An empty record over `encoder`.
    pub fn new(encoder: Encoder<'w>) -> Self {
        Self {
            encoder,
            passes: Vec::new(),
            encoded: 0,
            replayed: 0,
        }
    }

    /// Records every pass a `pathway` run over the `width x height` views will ask for (two
    /// descriptor passes a band, or a few token rows with independent rows, on the export
    /// pathway; one pair pass on the native one) that is not recorded yet, computed on up to `threads` threads at once, each with its own
    /// arena. Counted in [`PassCache::encoded`].
    #[allow(clippy::too_many_arguments)]
    pub fn prefill(
        &mut self,
        pathway: Pathway,
        left: &[u8],
        right: &[u8],
        width: usize,
        height: usize,
        threads: usize,
    ) -> Result<()> {
        let plan = BandPlan::new(height / PATCH_H).map_err(anyhow::Error::msg)?;
        let mut keys: Vec<Key> = Vec::new();
        // With independent token rows the pipeline encodes a band's rows from the first the band
        // before did not (`BandPlan::encoded`), `TOKEN_ROWS_PER_PASS` token rows a pass.
        let by_row = self.encoder.rows_independent();
        // Pixel rows of the tallest pass.
        let rows = match by_row {
            true => TOKEN_ROWS_PER_PASS * PATCH_H,
            false => band_pixel_rows(height),
        };
        for i in 0..plan.len() {
            let Some(encoded) = plan.encoded(i, by_row) else {
                continue;
            };
            let (first, end) = (encoded.start * PATCH_H, encoded.end * PATCH_H);
            for start in (first..end).step_by(rows.max(1)) {
                let pass_rows = rows.min(end - start);
                let rows_of = start * width..(start + pass_rows) * width;
                let (l, r) = (
                    band_view(left.get(rows_of.clone()).unwrap_or_default(), width, pass_rows, false),
                    band_view(right.get(rows_of).unwrap_or_default(), width, pass_rows, false),
                );
                // A band the views do not hold is left to the run (encoded when asked, or refused).
                let (Ok(l), Ok(r)) = (l, r) else {
                    continue;
                };
                let wanted = match pathway {
                    Pathway::Export => vec![Key::of_view(&l), Key::of_view(&r)],
                    Pathway::Native => vec![Key::of_pair(&l, &r)],
                };
                for key in wanted {
                    let known = self.passes.iter().any(|p| p.key == key) || keys.contains(&key);
                    if !known {
                        keys.push(key);
                    }
                }
            }
        }
        let done = encode_all(self.encoder, &keys, rows, threads)?;
        for (key, (arena_used, output)) in keys.into_iter().zip(done) {
            self.record(key, arena_used, output);
        }
        Ok(())
    }

    /// Keeps a pass the encoder ran.
    fn record(&mut self, key: Key, arena_used: usize, output: Vec<u8>) {
        self.passes.push(Pass {
            key,
            arena_used,
            output,
        });
        self.encoded += 1;
    }

    /// The recorded pass of `input` when there is one, else `encode`'s, recorded.
    fn answer(
        &mut self,
        key: Key,
        arena: &mut [u8],
        encode: impl FnOnce(Encoder<'w>, &mut [u8]) -> Result<(usize, usize), Error>,
    ) -> Result<(usize, usize), Error> {
        if let Some(pass) = self.passes.iter().find(|p| p.key == key) {
            let available = arena.len();
            let out = arena.get_mut(..pass.output.len()).ok_or(Error::ArenaTooSmall {
                needed: pass.output.len(),
                available,
            })?;
            out.copy_from_slice(&pass.output);
            self.replayed += 1;
            return Ok((pass.arena_used, pass.output.len()));
        }
        let (arena_used, len) = encode(self.encoder, arena)?;
        let output = arena.get(..len).unwrap_or_default().to_vec();
        self.record(key, arena_used, output);
        Ok((arena_used, len))
    }
}

impl Key {
    /// What a view pass over `view` reads.
    fn of_view(view: &GrayBand<'_>) -> Self {
        Self {
            input: view.pixels().to_vec(),
            width: view.width(),
            pair: false,
            mirrored: [view.is_mirrored(), false],
        }
    }

    /// What a pair pass over `left` and `right` reads.
    fn of_pair(left: &GrayBand<'_>, right: &GrayBand<'_>) -> Self {
        Self {
            input: [left.pixels(), right.pixels()].concat(),
            width: left.width(),
            pair: true,
            mirrored: [left.is_mirrored(), right.is_mirrored()],
        }
    }

    /// The pass this key names, on `encoder`, in `arena`: its high-water and output length.
    fn encode(&self, mut encoder: Encoder<'_>, arena: &mut [u8]) -> Result<(usize, usize), Error> {
        let half = if self.pair {
            self.input.len() / 2
        } else {
            self.input.len()
        };
        // Passes of bands that share rows are shorter than the band.
        let rows = half / self.width.max(1);
        let (width, input) = (self.width, &self.input[..]);
        let left = band_view(&input[..half], width, rows, self.mirrored[0])?;
        match self.pair {
            false => encoder.view_pass(left, arena),
            true => encoder.pair_pass(left, band_view(&input[half..], width, rows, self.mirrored[1])?, arena),
        }
    }
}

/// `pixels` as a `width x rows` band, read right to left when `mirrored`.
fn band_view(pixels: &[u8], width: usize, rows: usize, mirrored: bool) -> Result<GrayBand<'_>, Error> {
    let band = GrayBand::new(pixels, width, rows)?;
    Ok(if mirrored { band.mirrored() } else { band })
}

/// A pass computed ahead: its high-water and output, or the encoder's error.
type Computed = Result<(usize, Vec<u8>), Error>;

// Each key's pass, in key order, the keys shared out to `threads` threads (each with its own
// arena) as they finish their last.
fn encode_all(encoder: Encoder<'_>, keys: &[Key], rows: usize, threads: usize) -> Result<Vec<(usize, Vec<u8>)>> {
    let width = keys.first().map_or(0, |k| k.width);
    let next = AtomicUsize::new(0);
    let results: Mutex<Vec<Option<Computed>>> = Mutex::new(vec![None; keys.len()]);
    let worker = || {
        let mut arena = vec![0u8; arena_bytes(rows, width)];
        loop {
            let i = next.fetch_add(1, Ordering::Relaxed);
            let Some(key) = keys.get(i) else {
                return;
            };
            let done = key
                .encode(encoder, &mut arena)
                .map(|(used, len)| (used, arena[..len].to_vec()));
            if let Ok(mut slots) = results.lock() {
                slots[i] = Some(done);
            }
        }
    };
    std::thread::scope(|scope| {
        for _ in 1..threads.clamp(1, keys.len().max(1)) {
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

impl BandEncoder for PassCache<'_> {
    fn view_pass(&mut self, view: GrayBand<'_>, arena: &mut [u8]) -> Result<(usize, usize), Error> {
        self.answer(Key::of_view(&view), arena, |mut encoder, arena| {
            encoder.view_pass(view, arena)
        })
    }

    fn pair_pass(
        &mut self,
        left: GrayBand<'_>,
        right: GrayBand<'_>,
        arena: &mut [u8],
    ) -> Result<(usize, usize), Error> {
        self.answer(Key::of_pair(&left, &right), arena, |mut encoder, arena| {
            encoder.pair_pass(left, right, arena)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::demo::DEFAULT_BLOB;
    use crate::int8::Int8Model;

    /// A replayed pass writes the bytes and reports the high-water the encoder did; another
    /// band is encoded, not replayed.
    #[test]
    fn replays_only_the_same_band_and_answers_as_the_encoder() {
        let model = Int8Model::load(std::path::Path::new(DEFAULT_BLOB)).unwrap();
        let encoder = model.encoder().unwrap();
        let scene = crate::data::synthetic::default_scene(64, 16);
        let view = GrayBand::new(&scene.left.pixels, 64, 16).unwrap();
        let other = GrayBand::new(&scene.right.pixels, 64, 16).unwrap();
        let size = bino_core::model::encoder::arena_bytes(16, 64);
        let mut direct = vec![0u8; size];
        let mut plain = encoder;
        let (used, len) = plain.view_pass(view, &mut direct).unwrap();
        let mut cache = PassCache::new(encoder);
        let mut arena = vec![0u8; size];
        assert_eq!(cache.view_pass(view, &mut arena).unwrap(), (used, len));
        let mut replayed = vec![0x5Au8; size];
        assert_eq!(cache.view_pass(view, &mut replayed).unwrap(), (used, len));
        assert_eq!(replayed[..len], direct[..len]);
        assert_eq!((cache.encoded, cache.replayed), (1, 1));
        cache.view_pass(other, &mut arena).unwrap();
        cache.view_pass(view.mirrored(), &mut arena).unwrap();
        assert_eq!((cache.encoded, cache.replayed), (3, 1));
    }
}
