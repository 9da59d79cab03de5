//! A figure lives in one measured file and the docs render it from there: the comments of the
//! examples, the boards and their linker scripts must not carry measured figures of their own
//! (byte counts with thousands separators, or a number on a line that says it was measured, is a
//! peak or is "about" something), since nothing re-renders them when the measurement changes.

use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// Source and linker-script files under `dir`, build outputs aside.
fn files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else { return };
    for entry in entries.flatten() {
        let path = entry.path();
        let name = path.file_name().and_then(|n| n.to_str()).unwrap_or_default();
        if path.is_dir() {
            if name != "target" && !name.starts_with('.') {
                files(&path, out);
            }
        } else if name.ends_with(".rs") || name.ends_with(".x") {
            out.push(path);
        }
    }
}

/// The comment text of `line` (Rust `//` comments, or any line of a linker script's `/* */`
/// blocks, which `in_block` tracks), if it is one.
fn comment_of(line: &str, linker: bool, in_block: &mut bool) -> Option<String> {
    if linker {
        let starts = line.contains("/*");
        let was = *in_block || starts;
        *in_block = was && !line.contains("*/");
        return was.then(|| line.to_string());
    }
    line.find("//").map(|at| line[at..].to_string())
}

/// Whether `comment` states a figure that belongs in a measured file.
fn carries_a_figure(comment: &str) -> bool {
    let has_digit = comment.chars().any(|c| c.is_ascii_digit());
    let separated = comment
        .as_bytes()
        .windows(5)
        .any(|w| w[0].is_ascii_digit() && w[1] == b',' && w[2..].iter().all(u8::is_ascii_digit));
    let lower = comment.to_lowercase();
    let claims = ["measured", "peak", "about "].iter().any(|w| lower.contains(w));
    separated || (claims && has_digit && !lower.contains(".json") && !lower.contains("docs/"))
}

#[test]
fn example_and_board_comments_carry_no_measured_figures() {
    let mut all = Vec::new();
    for dir in ["examples", "boards"] {
        files(&repo().join(dir), &mut all);
    }
    assert!(all.len() > 10, "found {} files", all.len());
    let mut found = Vec::new();
    for path in &all {
        let linker = path.extension().is_some_and(|e| e == "x");
        let text = std::fs::read_to_string(path).unwrap();
        let mut in_block = false;
        for (i, line) in text.lines().enumerate() {
            if let Some(comment) = comment_of(line, linker, &mut in_block) {
                if carries_a_figure(&comment) {
                    found.push(format!("{}:{}: {}", path.display(), i + 1, line.trim()));
                }
            }
        }
    }
    assert!(found.is_empty(), "figures in comments:\n{}", found.join("\n"));
}

#[test]
fn the_rule_catches_byte_counts_and_measured_numbers_only() {
    assert!(carries_a_figure("// The arena: 466,598 bytes for the band."));
    assert!(carries_a_figure(
        "   firmware's measured peak is 14.4 KiB on the M7). */"
    ));
    assert!(carries_a_figure("// about 41 KB of arena"));
    assert!(!carries_a_figure("// keep at least 32 KiB for the stack"));
    assert!(!carries_a_figure("// measured: firmware-sim/measured/m55.json"));
    assert!(!carries_a_figure("// the measured peak: docs/firmware.md"));
}
