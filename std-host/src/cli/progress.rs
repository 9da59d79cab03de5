//! Progress on stderr: an `indicatif` bar or spinner when a person is watching, else the plain
//! lines the commands have always written (CI logs and the integration tests read those).
//!
//! A bar is drawn only when stderr is a terminal, `CI` is not set and the command was not asked
//! for `--json`; in every other case the output is byte for byte the plain log.

use std::borrow::Cow;
use std::ffi::OsString;
use std::io::IsTerminal;
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressFinish, ProgressStyle};

/// Whether to draw a bar: a terminal on stderr, not CI, no `--json` (whose runs are records).
pub fn wants_bar(json: bool, stderr_is_terminal: bool, ci: Option<OsString>) -> bool {
    !json && stderr_is_terminal && ci.is_none_or(|v| v.is_empty() || v == "0" || v == "false")
}

/// A command's progress: a spinner with the current step, which becomes a bar once items are
/// counted (pairs, bands: their total is known when the first one is done).
pub struct Progress {
    bar: Option<ProgressBar>,
    started: Instant,
}

const SPINNER: &str = "{elapsed:>4} {spinner} {msg}";
const BAR: &str = "{elapsed:>4} [{bar:30}] {pos}/{len} {msg}";

fn style(template: &str) -> ProgressStyle {
    ProgressStyle::with_template(template)
        .expect("a valid template")
        .progress_chars("=> ")
}

impl Progress {
    /// The progress of one command; `json`: the command was asked for `--json` (no bar).
    pub fn new(json: bool) -> Self {
        let bar = wants_bar(json, std::io::stderr().is_terminal(), std::env::var_os("CI")).then(|| {
            // Cleared on drop too, so an error message starts on a clean line.
            let bar = ProgressBar::no_length()
                .with_style(style(SPINNER))
                .with_finish(ProgressFinish::AndClear);
            bar.enable_steady_tick(Duration::from_millis(120));
            bar
        });
        Self {
            bar,
            started: Instant::now(),
        }
    }

    fn count(bar: &ProgressBar, done: usize, total: usize) {
        if bar.length().is_none() {
            bar.set_style(style(BAR));
        }
        bar.set_length(total as u64);
        bar.set_position(done as u64);
    }

    /// A new step begins: the spinner's message, or the plain `[  t s] step ...` line.
    pub fn step(&self, step: &str) {
        match &self.bar {
            Some(bar) => bar.set_message(step.to_string()),
            None => eprintln!("[{:5.1} s] {step} ...", self.started.elapsed().as_secs_f64()),
        }
    }

    /// What the command is doing, shown only on the bar (the plain log has no line for it).
    pub fn status(&self, what: impl Into<Cow<'static, str>>) {
        if let Some(bar) = &self.bar {
            bar.set_message(what);
        }
    }

    /// Item `done` of `total` finished: the bar moves; `line` is printed above the bar, or as
    /// the plain log's line.
    pub fn item(&self, done: usize, total: usize, line: &str) {
        match &self.bar {
            Some(bar) => {
                Self::count(bar, done, total);
                bar.println(line);
            }
            None => eprintln!("{line}"),
        }
    }

    /// Item `done` of `total` finished, with nothing to log: the bar moves; in plain, `plain`
    /// is called to write what the command always wrote (or nothing).
    pub fn tick(&self, done: usize, total: usize, plain: impl FnOnce()) {
        match &self.bar {
            Some(bar) => Self::count(bar, done, total),
            None => plain(),
        }
    }

    /// A line of the plain log that names what runs now (no timestamp): the bar's message, or
    /// the line on stderr.
    pub fn note(&self, line: &str) {
        match &self.bar {
            Some(bar) => bar.set_message(line.to_string()),
            None => eprintln!("{line}"),
        }
    }

    /// Removes the bar (before the command prints its results).
    pub fn finish(&self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bar_only_for_a_person_at_a_terminal() {
        assert!(wants_bar(false, true, None));
        assert!(!wants_bar(true, true, None), "--json runs are records: plain log");
        assert!(!wants_bar(false, false, None), "stderr piped or in a file: plain log");
        assert!(!wants_bar(false, true, Some("true".into())), "CI: plain log");
        assert!(!wants_bar(false, true, Some("1".into())));
        assert!(wants_bar(false, true, Some("false".into())), "CI=false is not CI");
        assert!(wants_bar(false, true, Some("".into())));
    }

    #[test]
    fn json_runs_never_draw_a_bar() {
        assert!(Progress::new(true).bar.is_none());
    }
}
