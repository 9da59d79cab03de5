//! The boards' report over defmt (RTT on the boards): one line for the frame's summary, one
//! per pipeline stage with its cycles, one for the whole frame's, and for a camera's frame one
//! for its line queue.

use bino_core::pipeline::Report;

use crate::line_queue::QueueStats;

use crate::summary::{Clock, Summary, SECTORS};

/// Prints `frame`'s summary and stage cycles; `core_hz` turns cycles into milliseconds.
pub fn print<C: Clock>(frame: u32, summary: &Summary<C>, report: &Report, core_hz: u32) {
    let sectors = summary.sectors();
    let near: [u16; SECTORS] = core::array::from_fn(|s| sectors[s].near_px);
    let median: [u16; SECTORS] = core::array::from_fn(|s| sectors[s].median_px);
    let consistent: [u16; SECTORS] = core::array::from_fn(|s| sectors[s].consistent_permille);
    let nearest_mm: [u32; SECTORS] = core::array::from_fn(|s| sectors[s].nearest_mm);
    defmt::println!(
        "bino frame={=u32} near_px={} median_px={} nearest_mm={} consistent_permille={} refined_rows={=usize} refined_crc={=u32:08x} arena_used={=usize}",
        frame,
        near,
        median,
        nearest_mm,
        consistent,
        summary.refined_rows(),
        summary.refined_crc(),
        report.arena_used
    );
    let mut total = 0u64;
    for (stage, cycles) in summary.stage_cycles() {
        total += cycles;
        defmt::println!(
            "bino frame={=u32} stage={=str} cycles={=u64} ms={=u64}",
            frame,
            stage.name(),
            cycles,
            millis(cycles, core_hz)
        );
    }
    defmt::println!(
        "bino frame={=u32} frame_cycles={=u64} ms={=u64} core_hz={=u32}",
        frame,
        total,
        millis(total, core_hz),
        core_hz
    );
}

/// Prints what `frame`'s line queue saw: rows handed to the pipeline, lines queued and lost,
/// the most lines waiting at once, and the camera frames its rows came from (1 + re-arms).
pub fn print_queue(frame: u32, delivered: usize, stats: &QueueStats) {
    defmt::println!(
        "bino frame={=u32} rows_delivered={=usize} lines_queued={=usize} lines_lost={=usize} queue_high_water={=usize} captures={=usize}",
        frame,
        delivered,
        stats.queued,
        stats.lost,
        stats.high_water,
        stats.captures
    );
}

fn millis(cycles: u64, hz: u32) -> u64 {
    cycles * 1000 / u64::from(hz.max(1))
}
