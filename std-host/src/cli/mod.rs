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
mod describe;
mod eval;
mod pairs;
mod progress;
mod quantize;
mod reference;
mod run;
mod sim;

/// BINO edge: a binocular ViT stereo encoder for edge boards, host tools.
#[derive(Parser)]
#[command(
    name = "bino",
    version,
    about,
    after_help = "(developer): verbs for measuring the engine and making the weights (docs/cli.md)."
)]
pub struct Cli {
    /// The fastest x86 kernels to use: fastest (the CPU's best), avx2 or portable.
    ///
    /// Every set gives the same outputs bit for bit: this times the slower ones.
    #[arg(long, global = true, value_enum, default_value = "fastest")]
    kernels: KernelCap,
    #[command(subcommand)]
    command: Command,
}

/// `--kernels`: the kernel sets a run may use at most.
#[derive(Clone, Copy, clap::ValueEnum)]
enum KernelCap {
    /// The fastest the CPU has (AVX-512 VNNI, else AVX2, else portable).
    Fastest,
    /// AVX2 at most.
    Avx2,
    /// The portable kernels only.
    Portable,
}

// Each verb's help is its `<Verb>Args` doc comment: the first paragraph, one short sentence, is
// its line in `bino --help` (the developer verbs' starts with "(developer)"); the rest is
// `bino <verb> --help`'s. The order here is `bino --help`'s: user verbs, then developer verbs.
#[derive(Subcommand)]
enum Command {
    Demo(demo::DemoArgs),
    Run(run::RunArgs),
    Sim(sim::SimArgs),
    Eval(eval::EvalArgs),
    Bench(bench::BenchArgs),
    Budget(budget::BudgetArgs),
    Reference(reference::ReferenceArgs),
    Pairs(pairs::PairsArgs),
    Compare(compare::CompareArgs),
    Describe(describe::DescribeArgs),
    Quantize(quantize::QuantizeArgs),
}

impl Cli {
    /// Runs the verb asked for.
    pub fn run(self) -> Result<()> {
        use bino_core::kernels::dispatch::{limit, Isa};
        limit(match self.kernels {
            KernelCap::Fastest => Isa::Avx512Vnni,
            KernelCap::Avx2 => Isa::Avx2,
            KernelCap::Portable => Isa::Portable,
        });
        match self.command {
            Command::Demo(args) => demo::run(args),
            Command::Run(args) => run::run(args),
            Command::Sim(args) => sim::run(args),
            Command::Eval(args) => eval::run(args),
            Command::Bench(args) => bench::run(args),
            Command::Budget(args) => budget::run(args),
            Command::Reference(args) => reference::run(args),
            Command::Pairs(args) => pairs::run(args),
            Command::Compare(args) => compare::run(args),
            Command::Describe(args) => describe::run(args),
            Command::Quantize(args) => quantize::run(args),
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

    /// The verbs `bino --help` labels "(developer)": for measuring the engine and making weights.
    const DEVELOPER_VERBS: [&str; 5] = ["reference", "pairs", "compare", "describe", "quantize"];

    /// Words that point inside the project rather than at what a user can see.
    const INTERNAL: [&str; 6] = ["EVAL.md", "paper", "issue", "session", "bino_core::", "README"];

    fn assert_public(what: &str, text: &str) {
        for word in INTERNAL {
            assert!(!text.contains(word), "{what} cites {word:?}: {text}");
        }
    }

    #[test]
    fn each_verb_has_a_one_sentence_summary_and_developer_verbs_are_labelled_and_last() {
        let cli = Cli::command();
        let verbs: Vec<_> = cli.get_subcommands().collect();
        for (i, verb) in verbs.iter().enumerate() {
            let name = verb.get_name();
            let about = verb.get_about().map(|a| a.to_string()).unwrap_or_default();
            assert!(
                !about.is_empty() && about.len() <= 90,
                "{name}: {} chars: {about}",
                about.len()
            );
            assert!(
                !about.contains('\n') && !about.trim_end_matches('.').contains(". "),
                "{name}: {about}"
            );
            assert_public(name, &about);
            let long = verb.get_long_about().map(|a| a.to_string()).unwrap_or_default();
            assert_public(name, &long);
            let developer = DEVELOPER_VERBS.contains(&name);
            assert_eq!(about.starts_with("(developer) "), developer, "{name}: {about}");
            assert_eq!(
                developer,
                i >= verbs.len() - DEVELOPER_VERBS.len(),
                "{name}: developer verbs last"
            );
        }
    }

    #[test]
    fn every_flags_first_help_line_is_short_and_public() {
        let mut long = Vec::new();
        for verb in Cli::command().get_subcommands() {
            for arg in verb.get_arguments() {
                let what = format!("bino {} --{}", verb.get_name(), arg.get_id());
                let help = arg.get_help().map(|h| h.to_string()).unwrap_or_default();
                if help.len() > 100 || help.contains('\n') {
                    long.push(format!("{what}: {} chars: {help}", help.len()));
                }
                assert_public(&what, &help);
                assert_public(&what, &arg.get_long_help().map(|h| h.to_string()).unwrap_or_default());
            }
        }
        assert!(long.is_empty(), "first help lines over 100 chars:\n{}", long.join("\n"));
    }

    #[test]
    fn profile_defaults_w320_for_one_pairs_output_and_w160_for_measuring() {
        for verb in ["run", "sim"] {
            let (default, help) = flag(verb, "profile");
            assert_eq!(default, "w320", "{verb}");
            assert!(
                help.contains("the default is the product's output size"),
                "{verb}: {help}"
            );
        }
        for verb in ["eval", "compare", "reference", "bench", "quantize"] {
            let (default, help) = flag(verb, "profile");
            assert_eq!(default, "w160", "{verb}");
            assert!(help.contains("the default is"), "{verb}: {help}");
        }
    }

    #[test]
    fn every_default_input_file_is_the_checkouts_found_by_one_rule() {
        use bino_host::io::checkout;
        let expected = [
            ("blob", checkout::BLOB),
            ("onnx", checkout::ENCODER_ONNX),
            ("head_onnx", checkout::HEAD_ONNX),
            ("native_head_onnx", checkout::NATIVE_HEAD_ONNX),
            ("data", checkout::DATA),
            ("calib", checkout::DATA),
            ("firmware", checkout::FIRMWARE_RUNS),
        ];
        let mut seen = 0;
        for verb in Cli::command().get_subcommands() {
            for arg in verb.get_arguments() {
                let id = arg.get_id().as_str();
                let default: Vec<_> = arg.get_default_values().iter().map(std::path::PathBuf::from).collect();
                if (verb.get_name(), id) == ("quantize", "out") {
                    continue; // below
                }
                let Some(&(_, file)) = expected.iter().find(|(flag, _)| *flag == id) else {
                    // No other flag defaults to a checkout file, relative or not.
                    for d in &default {
                        let d = d.to_string_lossy();
                        assert!(
                            !d.contains("weights/") && !d.contains("shared/"),
                            "{}: {d}",
                            verb.get_name()
                        );
                    }
                    continue;
                };
                assert_eq!(default, [checkout::path(file)], "bino {} --{id}", verb.get_name());
                assert!(default[0].is_absolute());
                seen += 1;
            }
        }
        // demo, run, sim, eval, compare, bench, describe: --blob; eval, compare, bench, reference,
        // quantize: --onnx; eval: --head-onnx, --native-head-onnx; eval, compare, pairs: --data;
        // quantize: --calib; budget: --firmware.
        assert_eq!(seen, 7 + 5 + 2 + 3 + 1 + 1);
        // quantize writes where the others read.
        assert_eq!(
            flag("quantize", "out").0,
            checkout::path(checkout::BLOB).display().to_string()
        );
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
