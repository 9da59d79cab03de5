//! A pair's encoder passes, kept for the pair's next pipeline runs ([`PassCache`]): `bino eval`
//! runs the core's pipeline once per refined readout of a pair and encodes the pair once. A
//! pass is replayed only for band pixels identical to the ones it was computed from, so each
//! run gets the bytes the blob's encoder gives for that band (the encoder is deterministic:
//! `tests/tests/determinism.rs`); the rest of the pipeline runs as it always does.

use bino_core::model::encoder::{Encoder, GrayBand};
use bino_core::pipeline::BandEncoder;
use bino_core::Error;

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
        self.passes.push(Pass {
            key,
            arena_used,
            output,
        });
        self.encoded += 1;
        Ok((arena_used, len))
    }
}

impl BandEncoder for PassCache<'_> {
    fn view_pass(&mut self, view: GrayBand<'_>, arena: &mut [u8]) -> Result<(usize, usize), Error> {
        let key = Key {
            input: view.pixels().to_vec(),
            width: view.width(),
            pair: false,
            mirrored: [view.is_mirrored(), false],
        };
        self.answer(key, arena, |mut encoder, arena| encoder.view_pass(view, arena))
    }

    fn pair_pass(
        &mut self,
        left: GrayBand<'_>,
        right: GrayBand<'_>,
        arena: &mut [u8],
    ) -> Result<(usize, usize), Error> {
        let key = Key {
            input: [left.pixels(), right.pixels()].concat(),
            width: left.width(),
            pair: true,
            mirrored: [left.is_mirrored(), right.is_mirrored()],
        };
        self.answer(key, arena, |mut encoder, arena| encoder.pair_pass(left, right, arena))
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
