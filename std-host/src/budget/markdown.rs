//! The report as Markdown tables: memory, stages per core, the targets' verdicts and the cycle
//! model.

use std::fmt::Write as _;

use super::frame::{FramesReport, Pathway, Scaling, RULE};
use super::presets::{PresetsReport, Source, NOTE as PRESETS_NOTE};
use super::{clock, cycles, e7_frame_stage, verdicts, CoreRun, TARGETS};

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
    if runs.iter().any(|r| r.stages.iter().any(|s| e7_frame_stage(&s.name))) {
        md.push_str(
            "\nThe `census320_*` and `frame320_*` stages are both presets on the Alif E7's whole \
             320x240 frame with the options of that width (`scripts/firmware.sh --frame320`; a core \
             without them did not run it), in an arena of their own outside the static one.\n",
        );
    }
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

/// The frames section: per frame, core and pathway the instructions, seconds and frames per
/// second at IPC 1 and under the cycle model, and the exact arena; then the scaling rule's check
/// against the second measured band width.
pub fn frames_markdown(runs: &[CoreRun], frames: &FramesReport) -> String {
    let mut md = String::from("\n### Frames (scaled from the band pair)\n\n");
    let band = runs.first().map_or((48, 160), |r| r.band);
    let clocks = match frames.clock_override_mhz {
        Some(mhz) => format!("every core at {mhz} MHz (`--clock-mhz`)"),
        None => runs
            .iter()
            .map(|r| format!("{} at {} MHz", r.core.to_uppercase(), clock(&r.core).mhz))
            .collect::<Vec<_>>()
            .join(", "),
    };
    let _ = writeln!(
        md,
        "A frame runs the bands the pipeline cuts it into (48 rows each, overlapping: \
         `bino_core::band::BandPlan`); its figures come from the {}x{} band pair, {RULE}. Times at {clocks}; IPC 1 and the cycle model as above. The arena is the \
         firmware's for a frame of that size, exact: `preset::export_arena_bytes(h, w)` (export) and \
         `preset::arena_bytes(h, w)` (native, the board's learned preset). \"fitted\" adds to each stage a constant per \
         run (per band for the encoder, per token row for the others) fitted through both measured \
         band widths: exact at both, an estimate elsewhere. On either pathway each band's head \
         lives in the encoder's scratch, so a frame's arena is the band pair's and what carries \
         from band to band (the refinement's ring; on the export pathway the SGMs' state and the \
         head's check), whatever its height; in bold: above the {} KiB arena target.\n",
        band.0,
        band.1,
        TARGETS.arena_bytes / 1024
    );
    let _ = writeln!(
        md,
        "| frame (W x H) | bands | core | pathway | instructions | band pairs | IPC 1 s | IPC 1 fps | modelled s | modelled fps | fitted instructions | arena |\n\
         |---|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"
    );
    for e in &frames.estimates {
        let opt = |v: Option<f64>, f: &dyn Fn(f64) -> String| v.map_or("-".to_string(), f);
        let _ = writeln!(
            md,
            "| {} | {} | {} at {} MHz | {} | {} | {:.2} | {:.2} | {} | {} | {} | {} | {} |",
            e.frame,
            e.bands,
            e.core.to_uppercase(),
            e.clock_mhz,
            e.pathway.name(),
            grouped(e.instructions),
            e.band_pairs,
            e.seconds_ipc1,
            fps(e.frames_per_s_ipc1),
            opt(e.modelled_seconds, &|s| format!("{s:.2}")),
            opt(e.modelled_frames_per_s, &fps),
            e.fitted_instructions.map_or("-".to_string(), grouped),
            if e.arena_bytes > TARGETS.arena_bytes {
                format!("**{} B**", grouped(e.arena_bytes))
            } else {
                format!("{} B", grouped(e.arena_bytes))
            },
        );
    }
    if frames.scaling_check.is_empty() {
        md.push_str(
            "\nNo second band width measured (`scripts/firmware.sh --band small --out \
             <firmware>/small`), so the rule is not checked here.\n",
        );
        return md;
    }
    let first = &frames.scaling_check[0];
    let _ = writeln!(
        md,
        "\n#### The rule checked: the {} band pair scaled to {}, against the {} run\n",
        hw(first.from),
        hw(first.to),
        hw(first.to)
    );
    let mut header = String::from("| stage | scaled by |");
    let mut rule = String::from("|---|---|");
    for c in &frames.scaling_check {
        let _ = write!(
            header,
            " {0} predicted | {0} measured | {0} error |",
            c.core.to_uppercase()
        );
        rule.push_str("---:|---:|---:|");
    }
    let _ = writeln!(md, "{header}\n{rule}");
    for (i, s) in first.stages.iter().enumerate() {
        let by = match s.scaling {
            Some(Scaling::Encoder) => "encoder MACs per band",
            Some(Scaling::Pairs) => "rows x candidate pairs",
            Some(Scaling::Cells) => "rows x cells",
            Some(Scaling::HeadRows) => "head rows per band x cells",
            Some(Scaling::Boot) => "once per boot",
            None => "",
        };
        let bold = s.scaling.is_none();
        let name = if bold {
            format!("**{}**", s.name)
        } else {
            s.name.clone()
        };
        let _ = write!(md, "| {name} | {by} |");
        for c in &frames.scaling_check {
            match c.stages.get(i).filter(|t| t.name == s.name) {
                Some(t) => {
                    let _ = write!(
                        md,
                        " {} | {} | {:+.1} % |",
                        grouped(t.predicted),
                        grouped(t.measured),
                        t.error_percent
                    );
                }
                None => md.push_str(" - | - | - |"),
            }
        }
        md.push('\n');
    }
    let _ = writeln!(
        md,
        "\nThe rule counts work, not the fixed costs beside it: the rows stage's per-row camera \
         interrupt and line-buffer queue (a constant per row, whatever the width), the encoder's \
         per-token work besides its MACs (LayerNorm, requantisation, rotary embedding, softmax) \
         and per-pass set-up, which the M55's cheap MVE MACs make weigh more than the M7's, the \
         matcher's per-cell work (norms, the right view's costs) and the refinement's per-row \
         work. They make a narrow band cost more than its share of the work, so scaled down to \
         {} the rule under-predicts those stages; scaled up from {} px it over- rather than \
         under-estimates them. A frame {} px wide only multiplies bands and rows, where the rule \
         holds but for per-band costs. The {} pathway's figures use the stages without the \
         `native_` prefix, the {} pathway's the `native_*` stages.",
        hw(first.to),
        first.from.width,
        first.from.width,
        Pathway::Export.name(),
        Pathway::Native.name(),
    );
    md
}

/// The presets section: per frame, core and preset the instructions per frame, where they come
/// from, the frame rate at IPC 1 and under the cycle model, the arena and the stack peak.
pub fn presets_markdown(presets: &PresetsReport) -> String {
    let mut md = String::from("\n### Presets per frame\n\n");
    let _ = writeln!(md, "{PRESETS_NOTE}.\n");
    let _ = writeln!(
        md,
        "| frame (W x H) | core | preset | readout | instructions per frame | from | IPC 1 fps | modelled fps | arena | stack peak |\n\
         |---|---|---|---|---:|---|---:|---:|---:|---:|"
    );
    for p in &presets.frames {
        let from = match p.source {
            Source::MeasuredFrame => "measured frame",
            Source::ScaledFrame => "scaled from the measured frame",
            Source::ScaledBandPair => "scaled from the band pair",
        };
        let _ = writeln!(
            md,
            "| {} | {} at {} MHz | {} | `{}` | {} | {from} | {} | {} | {} B | {} B |",
            p.frame,
            p.core.to_uppercase(),
            p.clock_mhz,
            p.preset.name(),
            p.readout,
            grouped(p.instructions),
            fps(p.frames_per_s_ipc1),
            p.modelled_frames_per_s.map_or("-".to_string(), fps),
            grouped(p.arena_bytes),
            grouped(p.stack_peak_bytes),
        );
    }
    md.push_str(&which_measured(presets));
    md
}

/// One sentence per kind of source: which cores and frames were counted on a whole frame, and
/// which were scaled because their core measured no frame of that size (a preset named where
/// the other one's came otherwise).
fn which_measured(presets: &PresetsReport) -> String {
    let pairs = |measured: bool| {
        let mut out: Vec<String> = Vec::new();
        let is = |p: &super::PresetFrame| (p.source == Source::MeasuredFrame) == measured;
        for p in presets.frames.iter().filter(|p| is(p)) {
            let same = |q: &&super::PresetFrame| q.core == p.core && q.frame == p.frame;
            let all = presets.frames.iter().filter(same).all(is);
            let pair = match all {
                true => format!("{} {}", p.core.to_uppercase(), p.frame),
                false => format!("{} {} ({})", p.core.to_uppercase(), p.frame, p.preset.name()),
            };
            if !out.contains(&pair) {
                out.push(pair);
            }
        }
        out
    };
    let (measured, scaled) = (pairs(true), pairs(false));
    let mut md = String::new();
    if !measured.is_empty() {
        let _ = write!(
            md,
            "\nCounted on a whole frame the firmware ran (\"measured frame\"): {}.",
            measured.join(", ")
        );
    }
    if !scaled.is_empty() {
        let _ = write!(
            md,
            " Scaled, as no frame of that size was measured on that core: {} (the fast preset from its \
             measured frame by token rows x cells, keeping that frame's options; the learned one from \
             its band pair).",
            scaled.join(", ")
        );
    }
    md.push('\n');
    md
}

/// A band as the report names it: height x width.
fn hw(f: super::Frame) -> String {
    format!("{}x{}", f.height, f.width)
}

/// Frames per second to three significant digits (`0.082`, `0.00298`).
fn fps(x: f64) -> String {
    let digits = if x > 0.0 {
        (2 - x.log10().floor() as i32).max(0)
    } else {
        3
    };
    format!("{x:.*}", digits as usize)
}
