//! Attention on Cortex-M55 before its softmax: the scores of four queries against every key,
//! the queries held in vector registers ([`attention_scores`]), and a token's values stored
//! channel-major by a scatter ([`scatter_channels`]).

use crate::config::HEAD_DIM;

/// Attention scores of four queries (`HEAD_DIM` = 32 codes: two vectors each) against every
/// key, two queries at a time held in q0-q3 and three keys a step through q4-q7: per key
/// triple six `vldrb`, twelve `vmladav(a)` and two `stm` (192 MACs in 21 instructions; two
/// keys a step took 15 per 128, one key 18). The last one or two keys of a count not divisible
/// by three are scored in Rust. Declines (`false`) unless `scores` is exactly `4 * n` for
/// `n >= 1` keys.
#[cfg(bino_mve)]
pub(crate) fn attention_scores(queries: &[[i8; HEAD_DIM]; 4], keys: &[i8], scores: &mut [i32]) -> bool {
    const _: () = assert!(HEAD_DIM == 32);
    let n = keys.len() / HEAD_DIM;
    if n == 0 || scores.len() != 4 * n {
        return false;
    }
    let triples = n / 3;
    let (first, second) = scores.split_at_mut(2 * n);
    let [q0, q1, q2, q3] = queries;
    for ((qa, qb), rows) in [((q0, q1), first), ((q2, q3), second)] {
        let (row_a, row_b) = rows.split_at_mut(n);
        if triples > 0 {
            // SAFETY: reads the two 32-byte queries, then loops `triples >= 1` times
            // (`dls`/`le`), each time reading 96 bytes of `keys` (`3 * triples * 32 <= n * 32`
            // bytes in all, checked above) and writing three words to each of `row_a` and
            // `row_b` (`3 * triples <= n` words each). `vldrb.u8` needs no alignment; `stm`
            // needs word alignment, which the `i32` rows have. It writes only its declared
            // outputs: the pointers, r0, r2, r4, r8, r10, r12 (`vmladav` takes even
            // accumulators), `lr` and q0-q7 (through their `d` aliases; the compiler saves the
            // callee-saved d8-d15).
            unsafe {
                core::arch::asm!(
                    "vldrb.u8 q0, [{qa}]",
                    "vldrb.u8 q1, [{qa}, #16]",
                    "vldrb.u8 q2, [{qb}]",
                    "vldrb.u8 q3, [{qb}, #16]",
                    "dls lr, lr",
                    "2:",
                    // Loads interleaved with products: the M55 overlaps a load's beats with
                    // a multiply's (Software Optimization Guide), not two of one kind.
                    "vldrb.u8 q4, [{k}], #16",
                    "vldrb.u8 q5, [{k}], #16",
                    "vmladav.s8 r0, q0, q4",
                    "vldrb.u8 q6, [{k}], #16",
                    "vmladava.s8 r0, q1, q5",
                    "vldrb.u8 q7, [{k}], #16",
                    "vmladav.s8 r8, q2, q4",
                    "vmladava.s8 r8, q3, q5",
                    "vldrb.u8 q4, [{k}], #16",
                    "vmladav.s8 r2, q0, q6",
                    "vldrb.u8 q5, [{k}], #16",
                    "vmladava.s8 r2, q1, q7",
                    "vmladav.s8 r10, q2, q6",
                    "vmladava.s8 r10, q3, q7",
                    "vmladav.s8 r4, q0, q4",
                    "vmladava.s8 r4, q1, q5",
                    "vmladav.s8 r12, q2, q4",
                    "vmladava.s8 r12, q3, q5",
                    "stm {sa}!, {{r0, r2, r4}}",
                    "stm {sb}!, {{r8, r10, r12}}",
                    "le lr, 2b",
                    qa = in(reg) qa.as_ptr(),
                    qb = in(reg) qb.as_ptr(),
                    k = inout(reg) keys.as_ptr() => _,
                    sa = inout(reg) row_a.as_mut_ptr() => _,
                    sb = inout(reg) row_b.as_mut_ptr() => _,
                    inout("lr") triples => _,
                    out("r0") _,
                    out("r2") _,
                    out("r4") _,
                    out("r8") _,
                    out("r10") _,
                    out("r12") _,
                    out("d0") _, out("d1") _, out("d2") _, out("d3") _, out("d4") _, out("d5") _,
                    out("d6") _, out("d7") _, out("d8") _, out("d9") _, out("d10") _, out("d11") _,
                    out("d12") _, out("d13") _, out("d14") _, out("d15") _,
                    options(nostack),
                );
            }
        }
        for j in 3 * triples..n {
            let key = keys.get(j * HEAD_DIM..(j + 1) * HEAD_DIM).unwrap_or(&[]);
            if let (Some(a), Some(b)) = (row_a.get_mut(j), row_b.get_mut(j)) {
                *a = crate::kernels::reference::matmul::dot(qa, key);
                *b = crate::kernels::reference::matmul::dot(qb, key);
            }
        }
    }
    true
}

/// `store[c * tokens + t] = token[c]` for every channel `c` (the attention values stored
/// channel-major, `[channel][token]`): eight channels a step, one widening `vldrb.s16` and one
/// scatter `vstrb.16` through the offsets `0, tokens, .., 7 tokens` (four instructions per
/// eight channels, where the byte loop takes about 50). `false` (nothing written) unless
/// `token` holds a positive multiple of eight channels, `t < tokens`, `7 * tokens` fits the
/// scatter's 16-bit offsets and `store` holds `token.len() * tokens` bytes.
#[cfg(bino_mve)]
pub(crate) fn scatter_channels(token: &[i8], store: &mut [i8], tokens: usize, t: usize) -> bool {
    let n = token.len();
    let fits = n.checked_mul(tokens).is_some_and(|len| len <= store.len());
    let offsets_fit = tokens.checked_mul(7).is_some_and(|last| last <= u16::MAX as usize);
    if n == 0 || !n.is_multiple_of(8) || t >= tokens || !offsets_fit || !fits {
        return false;
    }
    let offsets: [u16; 8] = core::array::from_fn(|i| (i * tokens) as u16);
    // SAFETY: the loop runs `n / 8 >= 1` times (`dls`/`le`), each time reading eight bytes of
    // `token` (`n` in all) and writing eight bytes at `store + t + 8 s tokens + i tokens` for
    // step `s` and lane `i < 8`: channel `c = 8 s + i < n` at `c * tokens + t < n * tokens <=
    // store.len()` (checked above), each offset below 2^16. Bytes need no alignment; `offsets`
    // is a `u16` array. It writes only its declared outputs: the pointers, `lr`, q0 and q1.
    unsafe {
        core::arch::asm!(
            "vldrh.u16 q1, [{off}]",
            "dls lr, lr",
            "2:",
            "vldrb.s16 q0, [{src}], #8",
            "vstrb.16 q0, [{dst}, q1]",
            "add {dst}, {step}",
            "le lr, 2b",
            off = in(reg) offsets.as_ptr(),
            src = inout(reg) token.as_ptr() => _,
            dst = inout(reg) store.as_mut_ptr().wrapping_add(t) => _,
            step = in(reg) 8 * tokens,
            inout("lr") n / 8 => _,
            out("d0") _, out("d1") _, out("d2") _, out("d3") _,
            options(nostack),
        );
    }
    true
}
