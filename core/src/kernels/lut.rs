//! Elementwise functions of an int8 input by table: 256 entries give the exact quantised
//! output (GELU in each block: input scale, function and output scale are all in the table).

/// Maps every value through `table`, indexed by the value's two's-complement byte.
#[inline]
pub fn apply_lut(x: &mut [i8], table: &[i8; 256]) {
    for v in x {
        *v = table[*v as u8 as usize];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn indexes_by_twos_complement() {
        let table: [i8; 256] = core::array::from_fn(|i| (i as u8 as i8) / 2);
        let mut x = [-128i8, -1, 0, 1, 127];
        apply_lut(&mut x, &table);
        assert_eq!(x, [-64, 0, 0, 0, 63]);
    }
}
