//! The right view's disparity read from the left head's own logits, without a second pass:
//! right cell `q` at disparity `k` is left cell `q + k` at `k`, so the diagonal of the left
//! row's logits is the right row's cost volume (the way SGM gets its right map), read out by
//! the same soft-argmin as the left view.

use super::sizing::check_candidates;
use super::stream::soft_argmin;
use super::{HeadRow, HeadWeights};
use crate::config::HEAD_CANDIDATES_LIMIT;
use crate::fixed::Requant;
use crate::Error;

/// Right-view disparities (Q8 patch columns) of the left head's output `row`, into `out`
/// (`row.disparity_q8.len()` cells): right cell `q` soft-argmins over `k` the logit of left
/// cell `q + k` at `k`; candidates whose left cell lies outside the row take no part.
pub fn right_view_row(weights: &HeadWeights<'_>, row: &HeadRow<'_>, out: &mut [u16]) -> Result<(), Error> {
    diagonal_soft_argmin(row.logits, row.candidates, weights.softmax, out)
}

/// [`right_view_row`] on a row of `logits` (`out.len() x candidates`, candidates fastest),
/// `to_log2_q8` the head's softmax scale.
fn diagonal_soft_argmin(logits: &[i32], candidates: usize, to_log2_q8: Requant, out: &mut [u16]) -> Result<(), Error> {
    check_candidates(candidates)?;
    let cols = out.len();
    Error::check_len("head logits row", cols.saturating_mul(candidates), logits.len())?;
    let mut diagonal = [i32::MIN; HEAD_CANDIDATES_LIMIT];
    for (q, o) in out.iter_mut().enumerate() {
        for (k, slot) in diagonal.iter_mut().take(candidates).enumerate() {
            *slot = logits.get((q + k) * candidates + k).copied().unwrap_or(i32::MIN);
        }
        *o = soft_argmin(&diagonal[..candidates], to_log2_q8).0;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::Rng;

    /// Logits unit = log2 Q8, so a gap of 4096 weighs 2^-16: an exact winner.
    const UNIT: Requant = Requant {
        mult: 1 << 30,
        shift: 30,
    };

    /// A left row whose every cell `p` is sure of `disparity[p]` (a peak 4096 above the rest).
    fn peaked(disparity: &[usize], candidates: usize) -> [i32; 16 * 8] {
        let mut logits = [0i32; 16 * 8];
        for (p, &d) in disparity.iter().enumerate() {
            logits[p * candidates + d] = 4096;
        }
        logits
    }

    #[test]
    fn a_consistent_scene_reads_the_same_disparity_from_the_right() {
        // Left cells 0..16 at disparity 3 except a nearer object (5) on cells 9..12.
        let (cols, nd) = (16, 8);
        let disparity: [usize; 16] = core::array::from_fn(|p| if (9..12).contains(&p) { 5 } else { 3 });
        let logits = peaked(&disparity, nd);
        let mut right = [0u16; 16];
        diagonal_soft_argmin(&logits[..cols * nd], nd, UNIT, &mut right).unwrap();
        for (q, &r) in right.iter().enumerate() {
            // Right cell q is seen by each left cell q + k whose disparity is k; where two see
            // it (the background beside the nearer object's left edge, which a real right view
            // would hide) the equal peaks average.
            let seen: ([usize; 8], usize) =
                (0..nd)
                    .filter(|&k| q + k < cols && disparity[q + k] == k)
                    .fold(([0; 8], 0), |(mut ks, n), k| {
                        ks[n] = k;
                        (ks, n + 1)
                    });
            match seen {
                (_, 0) => assert!(r < (nd * 256) as u16, "right cell {q}: {r}"),
                (ks, n) => assert_eq!(r as usize, ks[..n].iter().sum::<usize>() * 256 / n, "right cell {q}"),
            }
        }
        // Seen once: the background left of the object, and the object itself.
        assert_eq!(right[..4], [768; 4]);
        assert_eq!(right[6], 1280);
    }

    #[test]
    fn it_is_the_soft_argmin_of_each_diagonal_and_checks_its_input() {
        let mut rng = Rng::new(5);
        let (cols, nd) = (11, 7);
        let mut logits = [0i32; 11 * 7];
        for l in logits.iter_mut() {
            *l = if rng.range(0, 9) == 0 {
                i32::MIN
            } else {
                rng.range(-3000, 3000) as i32
            };
        }
        let mut right = [0u16; 11];
        diagonal_soft_argmin(&logits, nd, UNIT, &mut right).unwrap();
        for (q, &r) in right.iter().enumerate() {
            let diagonal: [i32; 7] = core::array::from_fn(|k| {
                if q + k < cols {
                    logits[(q + k) * nd + k]
                } else {
                    i32::MIN
                }
            });
            assert_eq!(r, soft_argmin(&diagonal, UNIT).0, "right cell {q}");
        }
        // The last cell has only candidate 0 (or none).
        assert_eq!(right[cols - 1], 0);
        let err = diagonal_soft_argmin(&logits[1..], nd, UNIT, &mut right);
        assert!(matches!(err, Err(Error::BufferSize { .. })), "{err:?}");
        let err = diagonal_soft_argmin(&logits, 0, UNIT, &mut right);
        assert!(matches!(err, Err(Error::Candidates { .. })), "{err:?}");
    }
}
