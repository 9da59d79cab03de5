//! CRC-32/ISO-HDLC, the checksum of zlib, PNG and Ethernet (reflected polynomial `0xEDB88320`,
//! initial value and final xor `0xFFFFFFFF`), so any host tool can verify a weight blob.
//!
//! ```
//! use bino_core::crc32::{crc32, Crc32};
//! assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
//! assert_eq!(Crc32::new().update(b"1234").update(b"56789").finish(), 0xCBF4_3926);
//! ```

/// The reflected generator polynomial.
const POLYNOMIAL: u32 = 0xEDB8_8320;

/// Byte-at-a-time lookup table, built at compile time and kept in flash (1 KiB).
static TABLE: [u32; 256] = build_table();

const fn build_table() -> [u32; 256] {
    let mut table = [0u32; 256];
    let mut byte = 0;
    while byte < 256 {
        let mut crc = byte as u32;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ POLYNOMIAL
            } else {
                crc >> 1
            };
            bit += 1;
        }
        table[byte] = crc;
        byte += 1;
    }
    table
}

/// The CRC-32 of `bytes`.
pub fn crc32(bytes: &[u8]) -> u32 {
    Crc32::new().update(bytes).finish()
}

/// An incremental CRC-32, for data that arrives in pieces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Crc32 {
    /// The running register, before the final xor.
    state: u32,
}

impl Crc32 {
    /// A CRC over no bytes yet.
    pub const fn new() -> Self {
        Self { state: u32::MAX }
    }

    /// Feeds `bytes` after everything fed so far.
    pub fn update(&mut self, bytes: &[u8]) -> &mut Self {
        for &byte in bytes {
            // The index is a `u8`, so it always lies inside the 256-entry table.
            let index = (self.state as u8 ^ byte) as usize;
            self.state = (self.state >> 8) ^ TABLE[index];
        }
        self
    }

    /// The CRC of everything fed so far (feeding may go on afterwards).
    pub const fn finish(&self) -> u32 {
        self.state ^ u32::MAX
    }
}

impl Default for Crc32 {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn standard_check_value() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32(b""), 0);
    }

    #[test]
    fn matches_crc32fast_whole_and_in_pieces() {
        let mut data = [0u8; 1000];
        let mut x: u32 = 12345;
        for byte in data.iter_mut() {
            x = x.wrapping_mul(1_103_515_245).wrapping_add(12_345);
            *byte = (x >> 16) as u8;
        }
        for len in [0, 1, 3, 17, 256, 999, 1000] {
            let part = data.get(..len).unwrap_or(&[]);
            let expected = crc32fast::hash(part);
            assert_eq!(crc32(part), expected, "length {len}");
            for split in [0, len / 3, len / 2, len] {
                let (a, b) = part.split_at(split);
                assert_eq!(
                    Crc32::new().update(a).update(b).finish(),
                    expected,
                    "length {len} split {split}"
                );
            }
        }
    }
}
