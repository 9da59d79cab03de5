//! AVX-512 VBMI table lookups of x86-64 host builds, where the CPU has them besides the VNNI
//! kernels ([`super::vnni::available`]): `vpermi2b` indexes two 64-byte tables by the low
//! seven bits of 64 codes at once, and the sign bit picks between the table's halves. The
//! result is the scalar lookup's, byte for byte.

use core::arch::x86_64::{
    __cpuid, __cpuid_count, __m512i, _mm512_mask_blend_epi8, _mm512_movepi8_mask, _mm512_permutex2var_epi8,
};

use core::sync::atomic::{AtomicU8, Ordering};

use bytemuck::must_cast;

/// Codes per step: one 512-bit vector.
const STEP: usize = 64;

// Whether the CPU has VBMI: 0 not yet looked, 1 no, 2 yes (`cpuid` traps in a virtual
// machine: asked once).
static CPU: AtomicU8 = AtomicU8::new(0);

/// Whether the VNNI kernels run and the CPU also has AVX-512 VBMI.
pub fn available() -> bool {
    if !super::vnni::available() {
        return false;
    }
    match CPU.load(Ordering::Relaxed) {
        1 => false,
        2 => true,
        _ => {
            let has = __cpuid(0).eax >= 7 && __cpuid_count(7, 0).ecx >> 1 & 1 == 1;
            CPU.store(if has { 2 } else { 1 }, Ordering::Relaxed);
            has
        }
    }
}

/// Maps every value of `x` through `table` (indexed by the value's two's-complement byte);
/// `false` (nothing written) where the CPU lacks VBMI or the VNNI kernels are off.
pub fn apply_lut(x: &mut [i8], table: &[i8; 256]) -> bool {
    if !available() {
        return false;
    }
    // SAFETY: `available()` saw AVX-512 F/BW/VL/VNNI (enabled by the OS) and VBMI on this CPU.
    #[allow(unsafe_code)]
    unsafe {
        apply_lut_vbmi(x, table)
    };
    true
}

#[target_feature(enable = "avx512f,avx512bw,avx512vbmi")]
fn apply_lut_vbmi(x: &mut [i8], table: &[i8; 256]) {
    let quarter = |q: usize| -> __m512i {
        let bytes: [i8; STEP] = table
            .get(q * STEP..(q + 1) * STEP)
            .and_then(|t| t.try_into().ok())
            .unwrap_or([0; STEP]);
        must_cast(bytes)
    };
    let (t0, t1, t2, t3) = (quarter(0), quarter(1), quarter(2), quarter(3));
    let mut steps = x.chunks_exact_mut(STEP);
    for chunk in &mut steps {
        let codes: [i8; STEP] = (&*chunk).try_into().unwrap_or([0; STEP]);
        let v: __m512i = must_cast(codes);
        // Entries 0..128 (codes 0..=127) and 128..256 (codes -128..=-1) by the low seven bits.
        let low = _mm512_permutex2var_epi8(t0, v, t1);
        let high = _mm512_permutex2var_epi8(t2, v, t3);
        let out: [i8; STEP] = must_cast(_mm512_mask_blend_epi8(_mm512_movepi8_mask(v), low, high));
        chunk.copy_from_slice(&out);
    }
    for v in steps.into_remainder() {
        *v = table[*v as u8 as usize];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testutil::Rng;

    #[test]
    fn lookups_equal_the_scalar_table_for_every_code_and_tail() {
        let mut rng = Rng::new(5);
        let mut table = [0i8; 256];
        rng.fill_i8(&mut table);
        for len in [0, 1, 63, 64, 65, 256 + 7, 3840] {
            let mut x = [0i8; 3840];
            for (i, v) in x.iter_mut().enumerate() {
                *v = (i as u8).wrapping_mul(37) as i8;
            }
            let want: [i8; 3840] = core::array::from_fn(|i| table[x[i] as u8 as usize]);
            let took = apply_lut(&mut x[..len], &table);
            assert_eq!(took, available(), "len {len}");
            if took {
                assert_eq!(x[..len], want[..len], "len {len}");
            }
        }
    }
}
