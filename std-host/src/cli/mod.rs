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

/// Exits with clap's usage error (code 2) for `subcommand`, as a bad value would.
fn usage_error(subcommand: &str, msg: String) -> ! {
    let mut cli = Cli::command().bin_name("bino");
    cli.build();
    match cli.find_subcommand_mut(subcommand) {
        Some(sub) => sub.error(ErrorKind::ArgumentConflict, msg).exit(),
        None => cli.error(ErrorKind::ArgumentConflict, msg).exit(),
    }
}
