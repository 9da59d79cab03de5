//! The cycle model: a stage's executed instructions per class (counted by the QEMU plugin,
//! `firmware-sim/qemu-plugin/classify.h`) priced in cycles per class per core, so the budget can
//! put modelled milliseconds beside the IPC-1 ones. A model, not a measurement: the costs and
//! their sources are in `firmware-sim/qemu-plugin/CYCLES.md`.
//!
//! ```
//! use std::collections::BTreeMap;
//! use bino_host::budget::cycles::{cost_table, modelled_cycles};
//! let counts: BTreeMap<String, u64> =
//!     [("mve", 10), ("mve_overlap", 9), ("other", 5)].map(|(k, v)| (k.to_string(), v)).into();
//! // Ten vector instructions at 2 cycles, nine of them overlapping their predecessor by 1.
//! assert_eq!(modelled_cycles(cost_table("m55"), &counts).unwrap(), 10.0 * 2.0 - 9.0 + 5.0);
//! ```

use std::collections::BTreeMap;
use std::fmt::Write as _;

use anyhow::{bail, Result};

use super::{clock, grouped, CoreRun};

/// The instruction classes the plugin counts; a stage's counts of these add up to its instructions.
pub const CLASSES: [&str; 8] = ["mve", "fp", "mul", "div", "load_store", "branch", "loop", "other"];

/// The adjustments the plugin counts besides the classes (not instructions; priced per event).
pub const ADJUSTMENTS: [&str; 3] = ["mve_overlap", "dual_issue_pair", "extra_words"];

/// Where the cost figures come from, for the report.
pub const SOURCE: &str = "firmware-sim/qemu-plugin/CYCLES.md";

/// The cost of one class or adjustment on one core.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cost {
    /// Class or adjustment name, as the plugin writes it.
    pub name: &'static str,
    /// Cycles per instruction of the class, or per adjustment event (negative: cycles saved).
    pub cycles: f64,
}

const fn cost(name: &'static str, cycles: f64) -> Cost {
    Cost { name, cycles }
}

/// Cortex-M55: single-issue scalar pipeline; MVE dual-beat (a 128-bit instruction is 4 beats, 2
/// per cycle), overlapping the next vector instruction of the other unit by one cycle.
pub const M55: [Cost; 11] = [
    cost("mve", 2.0),
    cost("fp", 1.0),
    cost("mul", 1.0),
    cost("div", 7.0),
    cost("load_store", 1.0),
    cost("branch", 2.0),
    cost("loop", 1.0),
    cost("other", 1.0),
    cost("mve_overlap", -1.0),
    cost("dual_issue_pair", 0.0),
    cost("extra_words", 1.0),
];

/// Cortex-M7: dual-issue (half the pipeline-compatible pairs issue together), branch predictor,
/// 64-bit load/store path.
pub const M7: [Cost; 11] = [
    cost("mve", 2.0),
    cost("fp", 1.0),
    cost("mul", 1.0),
    cost("div", 7.0),
    cost("load_store", 1.0),
    cost("branch", 2.0),
    cost("loop", 1.0),
    cost("other", 1.0),
    cost("mve_overlap", 0.0),
    cost("dual_issue_pair", -0.5),
    cost("extra_words", 0.5),
];

/// The cost table of a core (`m7`, else the M55's).
pub fn cost_table(core: &str) -> &'static [Cost] {
    match core {
        "m7" => &M7,
        _ => &M55,
    }
}

/// Modelled cycles of a stage's counts (classes and adjustments): the sum of count x cost. A
/// name the table does not price is an error, so a plugin with a new class cannot be priced at 0.
pub fn modelled_cycles(table: &[Cost], counts: &BTreeMap<String, u64>) -> Result<f64> {
    let mut cycles = 0.0;
    for (name, &n) in counts {
        match table.iter().find(|c| c.name == name) {
            Some(c) => cycles += n as f64 * c.cycles,
            None => bail!("instruction class {name:?} has no cost in the cycle model"),
        }
    }
    Ok(cycles)
}

/// The report's cycle-model section: per stage and core, IPC-1 and modelled milliseconds side
/// by side, then the band pair's class mix with each class's cost.
pub(super) fn markdown(runs: &[CoreRun]) -> String {
    let mut md = String::from("\n### Cycle model (a model, not a measurement)\n\n");
    let modelled: Vec<&CoreRun> = runs.iter().filter(|r| r.has_class_counts()).collect();
    for r in runs.iter().filter(|r| !r.has_class_counts()) {
        let _ = writeln!(
            md,
            "{}: no class counts in this run (measured before the plugin classified instructions; \
             `scripts/firmware.sh` counts them), so IPC-1 figures only.\n",
            r.core.to_uppercase()
        );
    }
    let Some(first) = modelled.first() else {
        return md;
    };
    let _ = writeln!(
        md,
        "Modelled cycles = the sum over instruction classes of executed count x cycles per class \
         (the plugin classifies every instruction from its bytes), with the per-core costs of \
         `{SOURCE}`, taken from Arm's Cortex-M55 Software Optimization Guide and the cores' \
         TRMs. It assumes zero-wait-state memory (TCM) and decodes no register dependencies; \
         IPC 1 is the executed instructions at one per cycle. Both at the clocks above.\n"
    );
    let mut header = String::from("| stage |");
    let mut rule = String::from("|---|");
    for r in &modelled {
        let _ = write!(
            header,
            " {0} ms IPC 1 | {0} modelled cycles | {0} modelled ms | {0} cycles per instruction |",
            r.core.to_uppercase()
        );
        rule.push_str("---:|---:|---:|---:|");
    }
    let _ = writeln!(md, "{header}\n{rule}");
    let cells = |md: &mut String, r: &CoreRun, instructions: u64, cycles: Option<f64>| {
        let c = clock(&r.core);
        match cycles {
            Some(n) => {
                let _ = write!(
                    md,
                    " {:.1} | {} | {:.1} | {:.2} |",
                    c.ms(instructions),
                    grouped(n.round() as u64),
                    c.cycles_ms(n),
                    n / instructions.max(1) as f64
                );
            }
            None => md.push_str(" - | - | - | - |"),
        }
    };
    for (i, s) in first.stages.iter().enumerate() {
        let _ = write!(md, "| {} |", s.name);
        for r in &modelled {
            match r.stages.get(i).filter(|t| t.name == s.name) {
                Some(t) => cells(&mut md, r, t.instructions, t.modelled_cycles(&r.core)),
                None => md.push_str(" - | - | - | - |"),
            }
        }
        md.push('\n');
    }
    md.push_str("| **band pair** (all but load) |");
    for r in &modelled {
        cells(&mut md, r, r.band_pair_instructions(), r.band_pair_modelled_cycles());
    }
    md.push_str("\n\n| class (band pair) |");
    let mut rule = String::from("|---|");
    for r in &modelled {
        let _ = write!(md, " {0} count | {0} cycles each |", r.core.to_uppercase());
        rule.push_str("---:|---:|");
    }
    let _ = writeln!(md, "\n{rule}");
    let totals: Vec<BTreeMap<String, u64>> = modelled
        .iter()
        .map(|r| r.band_pair_class_counts().unwrap_or_default())
        .collect();
    for name in CLASSES.iter().chain(ADJUSTMENTS.iter()) {
        let _ = write!(md, "| {name} |");
        for (r, total) in modelled.iter().zip(&totals) {
            let each = cost_table(&r.core)
                .iter()
                .find(|c| c.name == *name)
                .map_or(0.0, |c| c.cycles);
            let _ = write!(md, " {} | {} |", grouped(total.get(*name).copied().unwrap_or(0)), each);
        }
        md.push('\n');
    }
    let _ = writeln!(
        md,
        "\nThe last three rows are not instructions: `mve_overlap` counts vector instructions that \
         start while the previous one (of the other unit: load/store against ALU/MAC) finishes its \
         beats, `dual_issue_pair` scalar pairs the Cortex-M7's pipelines could issue together (the \
         model takes half of them, dependencies being unknown), `extra_words` the words a \
         multi-word load or store moves beyond its first."
    );
    md
}

#[cfg(test)]
mod tests {
    use super::*;

    fn counts(pairs: &[(&str, u64)]) -> BTreeMap<String, u64> {
        pairs.iter().map(|&(k, v)| (k.to_string(), v)).collect()
    }

    #[test]
    fn every_class_and_adjustment_is_priced_on_both_cores() {
        for table in [&M55[..], &M7[..]] {
            let names: Vec<&str> = table.iter().map(|c| c.name).collect();
            let want: Vec<&str> = CLASSES.iter().chain(ADJUSTMENTS.iter()).copied().collect();
            assert_eq!(names, want);
        }
    }

    #[test]
    fn cycles_are_count_times_cost() {
        let c = counts(&[
            ("mul", 100),
            ("load_store", 100),
            ("dual_issue_pair", 80),
            ("extra_words", 10),
        ]);
        assert_eq!(modelled_cycles(&M7, &c).unwrap(), 100.0 + 100.0 - 40.0 + 5.0);
        assert_eq!(modelled_cycles(&M55, &c).unwrap(), 100.0 + 100.0 + 10.0);
        assert_eq!(modelled_cycles(&M55, &counts(&[("div", 3)])).unwrap(), 21.0);
        let err = modelled_cycles(&M55, &counts(&[("crypto", 1)])).unwrap_err();
        assert!(err.to_string().contains("\"crypto\""), "{err}");
    }
}
