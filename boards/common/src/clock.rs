//! The DWT cycle counter extended to 64 bits. The 32-bit counter wraps every 8.9 s at
//! 480 MHz, shorter than one encoder pass, so SysTick (every 2^24 cycles) calls [`tick`] and
//! every wrap is seen. The board's `#[exception] fn SysTick` calls [`tick`].

use core::cell::Cell;

use cortex_m::interrupt::{self, Mutex};
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m::peripheral::{DCB, DWT, SYST};

use crate::cycles::Extender;
use crate::summary::Clock;

static STATE: Mutex<Cell<Extender>> = Mutex::new(Cell::new(Extender::new()));

/// Starts the cycle counter and the SysTick that keeps it extended. Returns whether the core
/// has a cycle counter (`DWT_CTRL.NOCYCCNT` clear); without one every reading is 0.
pub fn start(dcb: &mut DCB, dwt: &mut DWT, syst: &mut SYST) -> bool {
    dcb.enable_trace();
    DWT::unlock();
    dwt.enable_cycle_counter();
    syst.set_clock_source(SystClkSource::Core);
    syst.set_reload(0x00FF_FFFF);
    syst.clear_current();
    syst.enable_interrupt();
    syst.enable_counter();
    DWT::has_cycle_counter()
}

/// Folds the counter's current value into the extension (from SysTick and every reading).
pub fn tick() -> u64 {
    interrupt::free(|cs| {
        let state = STATE.borrow(cs);
        let mut e = state.get();
        let now = e.extend(DWT::cycle_count());
        state.set(e);
        now
    })
}

/// [`Clock`] over the extended DWT counter.
#[derive(Debug, Clone, Copy, Default)]
pub struct DwtClock;

impl Clock for DwtClock {
    fn now(&mut self) -> u64 {
        tick()
    }
}
