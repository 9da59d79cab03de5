//! Attention's block scores in portable Rust: the specification of every scores kernel.

use crate::config::HEAD_DIM;
use crate::kernels::reference::matmul::dot4_portable;
use crate::kernels::types::attention::QUERY_BLOCK;

/// The scores of the [`QUERY_BLOCK`] queries against `keys.len() / HEAD_DIM` keys (`scores[q *
/// n + j] = queries[q] . keys[j]`), as far as `scores` has room: the specification of
/// `dispatch::scores_block` and its kernels.
pub fn scores_block_reference(queries: &[[i8; HEAD_DIM]; QUERY_BLOCK], keys: &[i8], scores: &mut [i32]) {
    scores_block_with(queries, keys, scores, HEAD_DIM, dot4_portable::<i8>)
}

/// [`scores_block_reference`] with the head size `hd` (`HEAD_DIM`, possibly as an opaque
/// run-time value so that the loop shape suits the core) and the four-row dot product `dot4`
/// (the portable one, or a faster one with the same sums) given by the caller.
#[inline(always)]
pub fn scores_block_with(
    queries: &[[i8; HEAD_DIM]; QUERY_BLOCK],
    keys: &[i8],
    scores: &mut [i32],
    hd: usize,
    dot4: impl Fn(&[i8], &[i8], &[i8], &[i8], &[i8]) -> [i32; 4],
) {
    let n = (keys.len() / HEAD_DIM).min(scores.len() / QUERY_BLOCK);
    if n == 0 {
        return;
    }
    let mut score_rows = scores.chunks_exact_mut(n);
    let (Some(s0), Some(s1), Some(s2), Some(s3)) = (
        score_rows.next(),
        score_rows.next(),
        score_rows.next(),
        score_rows.next(),
    ) else {
        return;
    };
    let [q0, q1, q2, q3] = queries.each_ref().map(|q| q.get(..hd).unwrap_or(&[]));
    let score_slots = s0.iter_mut().zip(s1.iter_mut()).zip(s2.iter_mut()).zip(s3.iter_mut());
    for ((((x0, x1), x2), x3), k) in score_slots.zip(keys.chunks_exact(hd)) {
        let s = dot4(q0, q1, q2, q3, k);
        (*x0, *x1, *x2, *x3) = (s[0], s[1], s[2], s[3]);
    }
}
