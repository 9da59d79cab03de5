//! The `bino` command line: one file per verb, each with its arguments (`<Verb>Args`) and
//! `run`; argument groups several verbs share are in [`args`], progress on stderr in
//! [`progress`].

use anyhow::Result;
use clap::error::ErrorKind;
use clap::{CommandFactory, Parser, Subcommand};

mod args;
mod bench;
mod budget;
mod compare;
mod demo;
mod eval;
mod pairs;
mod progress;
mod quantize;
mod reference;
mod run;
mod sim;

/// BINO edge: a binocular ViT stereo encoder for edge boards, host tools.
#[derive(Parser)]
#[command(version, about)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

// Each verb's help is its `<Verb>Args` doc comment; the order here is `bino --help`'s.
#[derive(Subcommand)]
enum Command {
    Reference(reference::ReferenceArgs),
    Demo(demo::DemoArgs),
    Sim(sim::SimArgs),
    Quantize(quantize::QuantizeArgs),
    Pairs(pairs::PairsArgs),
    Compare(compare::CompareArgs),
    Eval(eval::EvalArgs),
    Run(run::RunArgs),
    Bench(bench::BenchArgs),
    Budget(budget::BudgetArgs),
}

impl Cli {
    /// Runs the verb asked for.
    pub fn run(self) -> Result<()> {
        match self.command {
            Command::Reference(args) => reference::run(args),
            Command::Demo(args) => demo::run(args),
            Command::Sim(args) => sim::run(args),
            Command::Quantize(args) => quantize::run(args),
            Command::Pairs(args) => pairs::run(args),
            Command::Compare(args) => compare::run(args),
            Command::Eval(args) => eval::run(args),
            Command::Run(args) => run::run(args),
            Command::Bench(args) => bench::run(args),
            Command::Budget(args) => budget::run(args),
        }
    }
}

/// Writes a report's JSON to `--json PATH` (atomically) when given, and says so.
fn write_json(path: Option<&std::path::Path>, json: impl FnOnce() -> String) -> Result<()> {
    if let Some(path) = path {
        bino_host::io::files::write_atomic(path, |file| Ok(std::io::Write::write_all(file, json().as_bytes())?))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

/// Exits with clap's usage error (code 2) for `subcommand`, as a bad value would.
fn usage_error(subcommand: &str, msg: String) -> ! {
    let mut cli = Cli::command().bin_name("bino");
    cli.build();
    match cli.find_subcommand_mut(subcommand) {
        Some(sub) => sub.error(ErrorKind::ArgumentConflict, msg).exit(),
        None => cli.error(ErrorKind::ArgumentConflict, msg).exit(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `(default, help)` of `--flag` of `bino verb`.
    fn flag(verb: &str, id: &str) -> (String, String) {
        let cli = Cli::command();
        let sub = cli.find_subcommand(verb).unwrap_or_else(|| panic!("no verb {verb}"));
        let arg = sub
            .get_arguments()
            .find(|a| a.get_id() == id)
            .unwrap_or_else(|| panic!("{verb}: no {id}"));
        let default: Vec<_> = arg.get_default_values().iter().map(|v| v.to_string_lossy()).collect();
        (
            default.join(","),
            arg.get_help().map(|h| h.to_string()).unwrap_or_default(),
        )
    }

    #[test]
    fn shared_groups_keep_each_verbs_default_and_help() {
        Cli::command().debug_assert();
        // run and sim look further than the rest: their own group type (see `PairCandidates`).
        for verb in ["run", "sim"] {
            assert_eq!(flag(verb, "max_cols").0, "16", "{verb}");
        }
        for verb in ["eval", "compare", "demo"] {
            assert_eq!(
                flag(verb, "max_cols").0,
                bino_host::eval::DEFAULT_MAX_COLS.to_string(),
                "{verb}"
            );
        }
        for verb in ["demo", "compare"] {
            assert_eq!(flag(verb, "max_cols").1, args::NOLINK_CANDIDATES_HELP, "{verb}");
        }
        assert_eq!(
            flag("eval", "max_cols").1,
            "Disparity candidates of nolink and sgm, in patch columns"
        );
        // The firmware's penalties, so a default run computes what the board computes.
        let firmware = bino_core::preset::OPTIONS.penalties;
        for verb in ["demo", "sim", "run", "eval"] {
            assert_eq!(flag(verb, "sgm_p1").0, firmware.p1.to_string(), "{verb}");
            assert_eq!(flag(verb, "sgm_p2").0, firmware.p2.to_string(), "{verb}");
        }
        for verb in ["sim", "run", "eval"] {
            assert_eq!(flag(verb, "lr_max_diff").0, "1", "{verb}");
        }
    }
}
