//! The board program: the weight blob in flash, the arena in RAM, one band pair from the camera
//! stand-in, its digests checked against the firmware's. On a Cortex-M target it prints and
//! exits through semihosting (QEMU or a debug probe); built for the host it is a plain program
//! (`cargo run --release`) that does the same.
#![cfg_attr(target_os = "none", no_std, no_main)]

use bino_example_board::{run_band, Camera, ARENA_BYTES, EXPECTED, OUTPUTS};

#[repr(C, align(16))]
struct Aligned<T>(T);

const BLOB_LEN: usize = include_bytes!("../../../weights/bino_int8.bin").len();

/// The int8 weight blob, read in place from flash (`.weights`: `memory/weights.x`).
#[cfg_attr(target_os = "none", link_section = ".weights")]
static BLOB: Aligned<[u8; BLOB_LEN]> = Aligned(*include_bytes!("../../../weights/bino_int8.bin"));

/// The camera's frame (the shipped 48x160 test band).
static LEFT: &[u8] = include_bytes!("../../../firmware-sim/assets/band_48x160_left.gray");
static RIGHT: &[u8] = include_bytes!("../../../firmware-sim/assets/band_48x160_right.gray");

/// Everything the pipeline needs besides the blob: one static arena, sized at compile time.
static mut ARENA: Aligned<[u8; ARENA_BYTES]> = Aligned([0; ARENA_BYTES]);

/// Runs the band and checks it; `print` reports each digest (name, found, expected), `fail` an
/// error.
fn run(print: impl Fn(&str, u32, u32), fail: impl Fn(bino_core::Error)) -> bool {
    // SAFETY: called once; nothing else refers to ARENA.
    let arena = unsafe { &mut (*core::ptr::addr_of_mut!(ARENA)).0 };
    // black_box: the blob is read from flash at run time, never folded into the code.
    let blob: &[u8] = core::hint::black_box(&BLOB.0);
    match run_band(blob, &mut Camera::new(LEFT, RIGHT), arena) {
        Ok((digests, _report)) => {
            for ((name, found), expected) in OUTPUTS.iter().zip(digests.0).zip(EXPECTED.0) {
                print(name, found, expected);
            }
            digests == EXPECTED
        }
        Err(e) => {
            fail(e);
            false
        }
    }
}

#[cfg(target_os = "none")]
mod board {
    use cortex_m_rt::entry;
    use cortex_m_semihosting::{debug, hprintln};

    #[entry]
    fn main() -> ! {
        let ok = super::run(
            |name, found, expected| hprintln!("{name:<18} {found:08x} expected {expected:08x}"),
            |e| hprintln!("error: {e}"),
        );
        hprintln!(
            "bino example: {}",
            if ok { "digests match the firmware's" } else { "MISMATCH" }
        );
        debug::exit(if ok { debug::EXIT_SUCCESS } else { debug::EXIT_FAILURE });
        loop {
            cortex_m::asm::wfi();
        }
    }

    #[panic_handler]
    fn panic(_: &core::panic::PanicInfo) -> ! {
        debug::exit(debug::EXIT_FAILURE);
        loop {
            cortex_m::asm::wfi();
        }
    }
}

#[cfg(not(target_os = "none"))]
fn main() -> std::process::ExitCode {
    let ok = run(
        |name, found, expected| println!("{name:<18} {found:08x} expected {expected:08x}"),
        |e| eprintln!("error: {e}"),
    );
    println!(
        "bino example: {}",
        if ok { "digests match the firmware's" } else { "MISMATCH" }
    );
    if ok {
        std::process::ExitCode::SUCCESS
    } else {
        std::process::ExitCode::FAILURE
    }
}
