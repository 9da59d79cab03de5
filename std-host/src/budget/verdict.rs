//! The targets judged on the runs: each a [`Verdict`] with the figure it was judged on.

use serde::Serialize;

use super::{clock, Clock, CoreRun, EXPORT_CEILINGS, NATIVE_SHARE_OF_EXPORT, REFINE_SHARE_OF_ENCODER, TARGETS};

/// Bytes in a KiB.
const KIB: f64 = 1024.0;

/// Whether a target is met, with the figure it was judged on.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Verdict {
    // Declared in the JSON's key order (alphabetical; see `report`).
    /// What was measured.
    pub measured: String,
    /// Met or not.
    pub met: bool,
    /// What the target is.
    pub target: String,
}

/// The targets judged on the runs.
pub fn verdicts(runs: &[CoreRun]) -> Vec<Verdict> {
    let mut out = Vec::new();
    if let Some(r) = runs.first() {
        out.push(Verdict {
            target: format!(
                "weights <= {:.1} MiB, both heads (this firmware runs both pathways)",
                TARGETS.weights_bytes as f64 / KIB / KIB
            ),
            measured: kib(r.sections.weights),
            met: r.sections.weights <= TARGETS.weights_bytes,
        });
        let learned = super::presets::learned_weights_bytes(r);
        out.push(Verdict {
            target: format!(
                "weights <= {:.1} MiB, the board's learned preset (the encoder and the native head)",
                TARGETS.weights_bytes as f64 / KIB / KIB
            ),
            measured: kib(learned),
            met: learned <= TARGETS.weights_bytes,
        });
        out.push(Verdict {
            target: format!("arena <= {}", kib(TARGETS.arena_bytes)),
            measured: format!("{} (static {})", kib(r.arena_used), kib(r.arena_bytes)),
            met: r.arena_bytes <= TARGETS.arena_bytes,
        });
    }
    for r in runs {
        let n = r.band_pair_instructions();
        let c = clock(&r.core);
        // The time targets judge the band pair the board runs: its preset's native pathway
        // where the firmware ran it, else the export pathway.
        let (board, pathway) = match r.native_band_pair_instructions() {
            Some(native) => (native, "the board's native pathway"),
            None => (n, "the export pathway"),
        };
        match r.core.as_str() {
            "m55" => out.push(Verdict {
                target: format!(
                    "Cortex-M55 <= {}M instructions per band pair, {pathway} ({:.1} s at {} MHz, IPC {})",
                    TARGETS.m55_instructions / 1_000_000,
                    Clock::ms(&c, TARGETS.m55_instructions) / 1e3,
                    c.mhz,
                    c.ipc
                ),
                measured: format!(
                    "{:.0}M ({:.1}x the target; {:.2} s)",
                    board as f64 / 1e6,
                    board as f64 / TARGETS.m55_instructions as f64,
                    c.ms(board) / 1e3
                ),
                met: board <= TARGETS.m55_instructions,
            }),
            "m7" => out.push(Verdict {
                target: format!(
                    "Cortex-M7 <= {} s per band pair, {pathway}, at {} MHz, IPC {}",
                    TARGETS.m7_seconds, c.mhz, c.ipc
                ),
                measured: format!(
                    "{:.2} s ({:.0}M instructions; {:.1}x the target)",
                    c.ms(board) / 1e3,
                    board as f64 / 1e6,
                    c.ms(board) / 1e3 / TARGETS.m7_seconds
                ),
                met: c.ms(board) / 1e3 <= TARGETS.m7_seconds,
            }),
            _ => {}
        }
        if let Some(native) = r.native_band_pair_instructions() {
            let share = native as f64 / n.max(1) as f64;
            out.push(Verdict {
                target: format!(
                    "{} native band pair with the head's check (one encoder pass on (L, R), native head, \
                     right view from its logits, census SGM) <= {:.0} % of the export pathway's",
                    core_name(&r.core),
                    100.0 * NATIVE_SHARE_OF_EXPORT
                ),
                measured: format!(
                    "{:.0}M ({:.1} % of {:.0}M)",
                    native as f64 / 1e6,
                    100.0 * share,
                    n as f64 / 1e6,
                ),
                met: share <= NATIVE_SHARE_OF_EXPORT,
            });
        }
        if let (Some(refine), Some(encoder)) = (r.stage_instructions("refine"), r.stage_instructions("encode_left")) {
            let share = refine as f64 / encoder.max(1) as f64;
            out.push(Verdict {
                target: format!(
                    "{} refinement <= {:.0} % of one encoder pass in instructions",
                    core_name(&r.core),
                    100.0 * REFINE_SHARE_OF_ENCODER
                ),
                measured: format!(
                    "{:.1}M ({:.2} % of encode_left's {:.0}M)",
                    refine as f64 / 1e6,
                    100.0 * share,
                    encoder as f64 / 1e6
                ),
                met: share <= REFINE_SHARE_OF_ENCODER,
            });
        }
    }
    if let Some((met, measured)) = super::presets::fast_target(runs) {
        let (frame, fps) = super::FAST_PRESET_TARGET;
        out.push(Verdict {
            target: format!(
                "Cortex-M55 fast preset (census+lr+ref) >= {fps} frames per second at {}x{}, {} MHz, IPC 1",
                frame.width,
                frame.height,
                clock("m55").mhz
            ),
            measured,
            met,
        });
    }
    // The export pathway's ceilings, which its kernels were tuned against: judged apart, since
    // the board runs the native pathway.
    for r in runs {
        let ceiling = match r.core.as_str() {
            "m55" => EXPORT_CEILINGS.m55,
            "m7" => EXPORT_CEILINGS.m7,
            _ => continue,
        };
        let n = r.band_pair_instructions();
        let (side, margin) = if n <= ceiling {
            ("under", ceiling - n)
        } else {
            ("over", n - ceiling)
        };
        out.push(Verdict {
            target: format!(
                "{} <= {}G instructions per export band pair",
                core_name(&r.core),
                ceiling as f64 / 1e9
            ),
            measured: format!("{:.1}M ({side} by {:.1}M)", n as f64 / 1e6, margin as f64 / 1e6),
            met: n <= ceiling,
        });
    }
    out
}

fn core_name(core: &str) -> &str {
    match core {
        "m55" => "Cortex-M55",
        "m7" => "Cortex-M7",
        other => other,
    }
}

fn kib(bytes: u64) -> String {
    format!("{:.1} KiB", bytes as f64 / KIB)
}
