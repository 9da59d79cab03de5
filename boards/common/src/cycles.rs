//! A 32-bit cycle counter extended to 64 bits: every reading folds in the wraps seen since the
//! last one. Exact as long as readings come less than one wrap apart (the boards read from
//! SysTick every 2^24 cycles; the counter wraps every 2^32).

/// The extension's state: wraps seen and the last raw reading.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Extender {
    wraps: u32,
    last: u32,
}

impl Extender {
    /// A counter that has not wrapped yet.
    pub const fn new() -> Self {
        Self { wraps: 0, last: 0 }
    }

    /// Folds the raw reading `now` in and returns the 64-bit count.
    pub fn extend(&mut self, now: u32) -> u64 {
        if now < self.last {
            self.wraps = self.wraps.wrapping_add(1);
        }
        self.last = now;
        (u64::from(self.wraps) << 32) | u64::from(now)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_on_across_wraps() {
        let mut e = Extender::new();
        assert_eq!(e.extend(10), 10);
        assert_eq!(e.extend(u32::MAX - 5), u64::from(u32::MAX) - 5);
        // Wrapped: 16 cycles after the previous reading.
        assert_eq!(e.extend(10), (1 << 32) + 10);
        assert_eq!(e.extend(10), (1 << 32) + 10);
        assert_eq!(e.extend(3), (2 << 32) + 3);
    }
}
