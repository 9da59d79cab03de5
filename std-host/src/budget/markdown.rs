//! The report as Markdown tables: memory, stages per core, the targets' verdicts and the cycle
//! model.

use std::fmt::Write as _;

use super::{clock, cycles, verdicts, CoreRun};

/// `1234567` as `1,234,567`.
pub fn grouped(n: u64) -> String {
    let digits = n.to_string();
    let mut out = String::new();
    for (i, c) in digits.chars().enumerate() {
        if i > 0 && (digits.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// The report as Markdown tables.
pub fn markdown(runs: &[CoreRun]) -> String {
    let mut md = String::new();
    let cores: Vec<String> = runs
        .iter()
        .map(|r| format!("{} ({}, {})", r.core.to_uppercase(), r.cpu, r.board))
        .collect();
    let first = &runs[0];
    let _ = writeln!(
        md,
        "Band pair {}x{} (height x width); numbers from the firmware runs under QEMU and the firmware ELF.\n",
        first.band.0, first.band.1
    );
    let _ = writeln!(md, "| memory | {} |", cores.join(" | "));
    let _ = writeln!(md, "|---|{}", "---:|".repeat(runs.len()));
    let row = |md: &mut String, label: &str, f: &dyn Fn(&CoreRun) -> String| {
        let cells: Vec<String> = runs.iter().map(f).collect();
        let _ = writeln!(md, "| {label} | {} |", cells.join(" | "));
    };
    let b = |n: u64| format!("{} B", grouped(n));
    row(&mut md, "weights flash (`.weights`)", &|r| b(r.sections.weights));
    row(&mut md, "code flash (`.text .rodata .vector_table .data`)", &|r| {
        b(r.sections.code_flash())
    });
    row(
        &mut md,
        "arena, static (`pipeline::arena_bytes`)",
        &|r| b(r.arena_bytes),
    );
    row(&mut md, "arena high-water (measured)", &|r| b(r.arena_used));
    if runs.iter().any(|r| r.refine_arena.is_some()) {
        row(&mut md, "of which the refinement (`pipeline::refine_bytes`)", &|r| {
            r.refine_arena.map_or("-".to_string(), b)
        });
    }
    row(&mut md, "stack peak / reserved", &|r| {
        format!("{} / {}", b(r.stack_peak()), b(r.stack_bytes))
    });
    row(&mut md, "RAM reserved (`.data .bss .uninit` + stack)", &|r| {
        b(r.ram_reserved())
    });
    row(&mut md, "RAM used (`.data .bss` + arena + stack peak)", &|r| {
        b(r.ram_used())
    });
    row(&mut md, "QEMU wall time", &|r| format!("{:.0} s", r.qemu_wall_seconds));
    row(&mut md, "outputs bit-identical to the host", &|r| {
        if r.passed { "yes" } else { "**no**" }.to_string()
    });

    let _ = writeln!(md);
    let mut header = String::from("| stage | arena in use |");
    let mut rule = String::from("|---|---:|");
    for r in runs {
        let c = clock(&r.core);
        let _ = write!(
            header,
            " {0} stack | {0} instructions | {0} ms at {1} MHz |",
            r.core.to_uppercase(),
            c.mhz
        );
        rule.push_str("---:|---:|---:|");
    }
    let _ = writeln!(md, "{header}\n{rule}");
    for (i, s) in first.stages.iter().enumerate() {
        let _ = write!(md, "| {} | {} |", s.name, b(s.arena_in_use));
        for r in runs {
            let c = clock(&r.core);
            match r.stages.get(i).filter(|t| t.name == s.name) {
                Some(t) => {
                    let _ = write!(
                        md,
                        " {} | {} | {:.1} |",
                        b(t.stack_peak),
                        grouped(t.instructions),
                        c.ms(t.instructions)
                    );
                }
                None => md.push_str(" - | - | - |"),
            }
        }
        md.push('\n');
    }
    let _ = write!(
        md,
        "| **band pair, export pathway** (all but load and native_*) | {} |",
        b(first.arena_high_water())
    );
    for r in runs {
        let n = r.band_pair_instructions();
        let _ = write!(
            md,
            " {} | **{}** | **{:.0}** |",
            b(r.stack_peak()),
            grouped(n),
            clock(&r.core).ms(n)
        );
    }
    md.push('\n');
    if runs.iter().any(|r| r.native_band_pair_instructions().is_some()) {
        let _ = write!(md, "| **band pair, native pathway** (native_*) | |");
        for r in runs {
            let n = r.native_band_pair_instructions().unwrap_or(0);
            let _ = write!(md, " | **{}** | **{:.0}** |", grouped(n), clock(&r.core).ms(n));
        }
        md.push('\n');
    }
    let _ = write!(md, "| outside the stages (digests, logging) | |");
    for r in runs {
        let _ = write!(
            md,
            " | {} | |",
            grouped(r.outside_instructions + r.startup_instructions)
        );
    }
    md.push('\n');
    let _ = writeln!(
        md,
        "\nInstructions are executed instructions counted by a QEMU TCG plugin, not cycles. The \
         milliseconds assume {}; real parts differ (memory wait states, the M7's dual issue, \
         the M55's MVE beats). `load` (blob CRC and parsing) runs once at boot.\n",
        runs.iter()
            .map(|r| {
                let c = clock(&r.core);
                format!(
                    "{} at {} MHz and {} instruction per cycle",
                    r.core.to_uppercase(),
                    c.mhz,
                    c.ipc
                )
            })
            .collect::<Vec<_>>()
            .join(", ")
    );
    let _ = writeln!(md, "| target | measured | state |\n|---|---|---|");
    for v in verdicts(runs) {
        let _ = writeln!(
            md,
            "| {} | {} | {} |",
            v.target,
            v.measured,
            if v.met { "met" } else { "**missed**" }
        );
    }
    md.push_str(&cycles::markdown(runs));
    md
}
