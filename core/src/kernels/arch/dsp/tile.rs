//! The Cortex-M7 tile and its layout: rows of int8 widened into interleaved signed 16-bit
//! pairs ([`widen`], `sxtb16` per word), the scratch that takes them ([`words`]), and four
//! widened rows against one weight row ([`tile`]: `sxtb16` and `smlad`), with the portable
//! twin of the tile for host tests.

use super::ROWS;

/// Scratch words for dot products of `k` elements: 2 per 4-element group per row.
pub(super) const fn words(k: usize) -> usize {
    k / 4 * 2 * ROWS
}

/// Rows of int8 to the interleaved 16-bit layout: for group `g` and row `r`, word
/// `8g + 2r` holds elements `(4g, 4g + 2)` and word `8g + 2r + 1` holds `(4g + 1, 4g + 3)`,
/// low halfword first (what `sxtb16` makes of a weight word).
#[inline(always)]
pub(super) fn widen(rows: [&[i8]; ROWS], x: &mut [u32]) {
    fn pair(lo: i8, hi: i8) -> u32 {
        (lo as i16 as u16 as u32) | ((hi as i16 as u16 as u32) << 16)
    }
    for (r, row) in rows.iter().enumerate() {
        if widen_row(row, x, r) {
            continue;
        }
        for (q, dst) in row.chunks_exact(4).zip(x.chunks_exact_mut(2 * ROWS)) {
            if let (Some(&[e0, e1, e2, e3]), Some(d)) = (q.first_chunk::<4>(), dst.get_mut(2 * r..2 * r + 2)) {
                d[0] = pair(e0, e2);
                d[1] = pair(e1, e3);
            }
        }
    }
}

/// Row `r` of [`widen`] on Cortex-M7: per four codes one word load, the two `sxtb16` a weight
/// word gets in the tile, and one `strd` (the portable loop spent about five instructions a
/// code). The row may sit at any address: Armv7-M's `ldr` takes unaligned words (with
/// `CCR.UNALIGN_TRP` clear, its reset value, which the compiler's own code for these targets
/// assumes too). `false` (nothing written) where `x` has fewer groups than the row: the
/// caller's loop then runs.
#[inline(always)]
fn widen_row(row: &[i8], x: &mut [u32], r: usize) -> bool {
    #[cfg(bino_dsp)]
    {
        let groups = row.len() / 4;
        if groups == 0 || x.len() < groups * 2 * ROWS || r >= ROWS {
            return false;
        }
        // SAFETY: the loop runs `groups >= 1` times; each pass reads one word of `row` (`ldr`,
        // any alignment, see above; `4 groups <= row.len()` bytes in all) and writes words `8g + 2r`
        // and `8g + 2r + 1` of `x` (`x` holds `8 groups` words, checked, and `r < 4`), an
        // `[u32]`, so word-aligned for `strd`. Only declared outputs are written; the flags are
        // clobbered.
        unsafe {
            core::arch::asm!(
                "2:",
                "ldr {t}, [{s}], #4",
                "sxtb16 {a}, {t}",
                "sxtb16 {b}, {t}, ror #8",
                "strd {a}, {b}, [{d}], #32",
                "subs {g}, {g}, #1",
                "bne 2b",
                s = inout(reg) row.as_ptr() => _,
                d = inout(reg) x.as_mut_ptr().wrapping_add(2 * r) => _,
                g = inout(reg) groups => _,
                t = out(reg) _,
                a = out(reg) _,
                b = out(reg) _,
                options(nostack),
            );
        }
        true
    }
    #[cfg(not(bino_dsp))]
    {
        let _ = (row, x, r);
        false
    }
}

/// `acc[r] + sum_t a_r[t] * w[t]` for the 4 widened rows of `x` against one weight row.
#[cfg(bino_dsp)]
#[inline(always)]
pub(super) fn tile(x: &[u32], w: &[i8], acc: [i32; ROWS]) -> [i32; ROWS] {
    let groups = w.len() / 4;
    if groups == 0 || x.len() < groups * 2 * ROWS || !(w.as_ptr() as usize).is_multiple_of(4) {
        return acc;
    }
    let [mut a0, mut a1, mut a2, mut a3] = acc;
    if groups.is_multiple_of(8) {
        // SAFETY: as below, with the loop running `groups / 8 >= 1` times over eight groups
        // each (every encoder and attention dot product: k = 32, 128, 480, 960): the same
        // `4 * groups` bytes of `w` and `32 * groups` bytes of `x`.
        unsafe {
            core::arch::asm!(
                "2:",
                groups8!(),
                "subs {g}, {g}, #1",
                "bne 2b",
                w = inout(reg) w.as_ptr() => _,
                x = inout(reg) x.as_ptr() => _,
                g = inout(reg) groups / 8 => _,
                a0 = inout(reg) a0,
                a1 = inout(reg) a1,
                a2 = inout(reg) a2,
                a3 = inout(reg) a3,
                t0 = out(reg) _,
                t1 = out(reg) _,
                x0 = out(reg) _,
                x1 = out(reg) _,
                options(nostack, readonly, pure),
            );
        }
        return [a0, a1, a2, a3];
    }
    if groups.is_multiple_of(2) {
        // SAFETY: as below, with the loop running `groups / 2 >= 1` times over two groups
        // each: the same `4 * groups` bytes of `w` and `32 * groups` bytes of `x`.
        unsafe {
            core::arch::asm!(
                "2:",
                group!(),
                group!(),
                "subs {g}, {g}, #1",
                "bne 2b",
                w = inout(reg) w.as_ptr() => _,
                x = inout(reg) x.as_ptr() => _,
                g = inout(reg) groups / 2 => _,
                a0 = inout(reg) a0,
                a1 = inout(reg) a1,
                a2 = inout(reg) a2,
                a3 = inout(reg) a3,
                t0 = out(reg) _,
                t1 = out(reg) _,
                x0 = out(reg) _,
                x1 = out(reg) _,
                options(nostack, readonly, pure),
            );
        }
        return [a0, a1, a2, a3];
    }
    // SAFETY: the loop runs `groups >= 1` times and reads `4 * groups` bytes of `w` (checked
    // above to be in `w` and word-aligned) and `32 * groups` bytes of `x` (checked above; an
    // `[u32]`, so word-aligned for `ldrd`). It writes only its declared outputs and
    // temporaries, touches no stack (`nostack`) and clobbers the flags (not preserved).
    unsafe {
        core::arch::asm!(
            "2:",
            group!(),
            "subs {g}, {g}, #1",
            "bne 2b",
            w = inout(reg) w.as_ptr() => _,
            x = inout(reg) x.as_ptr() => _,
            g = inout(reg) groups => _,
            a0 = inout(reg) a0,
            a1 = inout(reg) a1,
            a2 = inout(reg) a2,
            a3 = inout(reg) a3,
            t0 = out(reg) _,
            t1 = out(reg) _,
            x0 = out(reg) _,
            x1 = out(reg) _,
            options(nostack, readonly, pure),
        );
    }
    [a0, a1, a2, a3]
}

/// The same sums as the assembly tile, in portable Rust (host tests of the driver and layout).
#[cfg(not(bino_dsp))]
pub(super) fn tile(x: &[u32], w: &[i8], mut acc: [i32; ROWS]) -> [i32; ROWS] {
    fn smlad(acc: i32, x: u32, y: u32) -> i32 {
        let (xl, xh, yl, yh) = (
            x as i16 as i32,
            (x >> 16) as i16 as i32,
            y as i16 as i32,
            (y >> 16) as i16 as i32,
        );
        acc.wrapping_add(xl * yl).wrapping_add(xh * yh)
    }
    for (q, xs) in w.chunks_exact(4).zip(x.chunks_exact(2 * ROWS)) {
        let word = u32::from_le_bytes([q[0] as u8, q[1] as u8, q[2] as u8, q[3] as u8]);
        let even = (word as u8 as i8 as i16 as u16 as u32) | (((word >> 16) as u8 as i8 as i16 as u16 as u32) << 16);
        let odd =
            ((word >> 8) as u8 as i8 as i16 as u16 as u32) | (((word >> 24) as u8 as i8 as i16 as u16 as u32) << 16);
        for (r, a) in acc.iter_mut().enumerate() {
            *a = smlad(smlad(*a, xs[2 * r], even), xs[2 * r + 1], odd);
        }
    }
    acc
}
