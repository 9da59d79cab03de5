//! The kernels' layers, checked on the source: shared types at the bottom, the reference
//! kernels on them, one module per instruction set on those two, the portable families beside
//! them, and one dispatch point above all of these: the only kernel module the model and the
//! pipeline call, and (with `kernels/arch/`) the only place that names an instruction set. A
//! file that imports against the direction fails here with its path and line.

use std::fs;
use std::path::{Path, PathBuf};
use std::sync::LazyLock;

/// The crate's `src/`, found at run time: a test binary built in one checkout and reused from a
/// shared target folder by another (cargo keeps it fresh across a moved workspace) must scan
/// the checkout it runs in, not the one it was compiled in.
static SRC: LazyLock<PathBuf> = LazyLock::new(|| {
    let manifest = std::env::var_os("CARGO_MANIFEST_DIR").unwrap_or_else(|| env!("CARGO_MANIFEST_DIR").into());
    PathBuf::from(manifest).join("src")
});

/// Kernel modules above the reference kernels: the portable families, the instruction sets
/// and the dispatch. (The instruction sets come last: they may not import the others.)
const ABOVE_REFERENCE: [&str; 4] = ["dispatch", "layernorm", "lut", "arch"];

/// The kernel modules `model/` and `pipeline/` may name: the dispatch and the shared types
/// (with their long-standing re-exports `params`, `exp` and `I32s`).
const CALLABLE_FROM_MODEL: [&str; 5] = ["dispatch", "types", "params", "exp", "I32s"];

/// What names an instruction set in a cfg: the Cortex-M cfgs of `core/build.rs` and x86 (run-time
/// detection lives behind `cfg(target_arch = "x86_64")`).
const ISA_CFGS: [&str; 3] = ["bino_dsp", "bino_mve", "target_arch"];

/// Files outside `kernels/dispatch/` and `kernels/arch/` allowed some lines naming an
/// instruction set (lint-only `cfg_attr(..., allow(...))` lines are never counted), with how
/// many:
/// - `kernels/types/prepared.rs`: the Helium requantisation's column-record trait and its two
///   implementations exist only where that kernel reads them (`cfg(any(bino_mve, test))`).
const ISA_CFG_EXCEPTIONS: [(&str, usize); 1] = [("kernels/types/prepared.rs", 3)];

/// The `.rs` files under `dir` (or `dir` itself where it is a file).
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    if dir.is_file() {
        out.push(dir.to_path_buf());
        return;
    }
    for entry in fs::read_dir(dir).unwrap_or_else(|e| panic!("{}: {e}", dir.display())) {
        let path = entry.expect("directory entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|x| x == "rs") {
            out.push(path);
        }
    }
}

/// The non-test lines of every file under `dir` (a file's unit tests, from `#[cfg(test)]`
/// followed by `mod tests`, and `tests.rs` files may use any layer).
fn code_lines(dir: &str) -> Vec<(String, usize, String)> {
    let mut files = Vec::new();
    rust_files(&SRC.join(dir), &mut files);
    let mut lines = Vec::new();
    for file in files {
        if file.file_name().is_some_and(|n| n == "tests.rs") {
            continue;
        }
        let text = fs::read_to_string(&file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        let all: Vec<&str> = text.lines().collect();
        for (i, line) in all.iter().enumerate() {
            if line.trim() == "#[cfg(test)]" && all.get(i + 1).is_some_and(|l| l.trim_start().starts_with("mod tests"))
            {
                break;
            }
            let code = line.split("//").next().unwrap_or("");
            lines.push((file.display().to_string(), i + 1, code.to_string()));
        }
    }
    lines
}

fn violations(dir: &str, forbidden: &[String]) -> Vec<String> {
    code_lines(dir)
        .into_iter()
        .filter_map(|(file, n, code)| {
            let hit = forbidden.iter().find(|f| code.contains(f.as_str()))?;
            Some(format!("{file}:{n}: `{hit}` in {}", code.trim()))
        })
        .collect()
}

fn kernel_paths(modules: &[&str]) -> Vec<String> {
    modules.iter().map(|m| format!("kernels::{m}")).collect()
}

#[test]
fn the_shared_types_import_no_kernel() {
    let mut forbidden = kernel_paths(&ABOVE_REFERENCE);
    forbidden.push("kernels::reference".into());
    forbidden.push("super::super".into());
    let found = violations("kernels/types", &forbidden);
    assert!(found.is_empty(), "types reach up:\n{}", found.join("\n"));
}

#[test]
fn the_reference_kernels_import_the_types_only() {
    let mut forbidden = kernel_paths(&ABOVE_REFERENCE);
    forbidden.push("super::super".into());
    let found = violations("kernels/reference", &forbidden);
    assert!(found.is_empty(), "reference kernels reach up:\n{}", found.join("\n"));
}

#[test]
fn each_instruction_set_imports_the_types_and_the_reference_only() {
    let mut forbidden = kernel_paths(&ABOVE_REFERENCE[..ABOVE_REFERENCE.len() - 1]);
    // `super::` inside arch/ names arch's own modules; two levels up is `kernels`.
    forbidden.push("super::super".into());
    let found = violations("kernels/arch", &forbidden);
    assert!(
        found.is_empty(),
        "instruction-set kernels reach up:\n{}",
        found.join("\n")
    );
}

#[test]
fn the_portable_families_import_the_types_and_the_reference_only() {
    let forbidden = kernel_paths(&["dispatch", "arch"]);
    let mut found = Vec::new();
    for family in ABOVE_REFERENCE.iter().filter(|m| !["dispatch", "arch"].contains(m)) {
        found.extend(violations(&format!("kernels/{family}.rs"), &forbidden));
    }
    assert!(found.is_empty(), "portable families reach up:\n{}", found.join("\n"));
}

#[test]
fn the_model_and_the_pipeline_never_name_an_instruction_set() {
    let forbidden = vec!["kernels::arch".to_string(), "arch::".to_string()];
    let mut found = violations("model", &forbidden);
    found.extend(violations("pipeline", &forbidden));
    assert!(found.is_empty(), "callers of an instruction set:\n{}", found.join("\n"));
}

/// Every `kernels::<name>` a line names (`{` for a grouped import, which hides the names).
fn kernel_modules_named(code: &str) -> Vec<String> {
    code.match_indices("kernels::")
        .map(|(at, _)| {
            let rest = &code[at + "kernels::".len()..];
            if rest.starts_with('{') {
                return "{".to_string();
            }
            rest.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect()
        })
        .collect()
}

#[test]
fn the_model_and_the_pipeline_call_the_kernels_through_the_dispatch_only() {
    let mut found = Vec::new();
    for dir in ["model", "pipeline"] {
        for (file, n, code) in code_lines(dir) {
            for name in kernel_modules_named(&code) {
                if !CALLABLE_FROM_MODEL.contains(&name.as_str()) {
                    found.push(format!("{file}:{n}: `kernels::{name}` in {}", code.trim()));
                }
            }
        }
    }
    assert!(
        found.is_empty(),
        "kernel modules named past the dispatch (call `kernels::dispatch`):\n{}",
        found.join("\n")
    );
}

#[test]
fn only_the_dispatch_and_the_instruction_sets_name_an_instruction_set() {
    let mut files = Vec::new();
    rust_files(&SRC, &mut files);
    let mut found = Vec::new();
    for file in files {
        let rel = file
            .strip_prefix(&*SRC)
            .unwrap_or(&file)
            .to_string_lossy()
            .replace('\\', "/");
        if rel.starts_with("kernels/dispatch/") || rel.starts_with("kernels/arch/") {
            continue;
        }
        let text = fs::read_to_string(&file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        let hits: Vec<String> = text
            .lines()
            .enumerate()
            .filter_map(|(i, line)| {
                let code = line.split("//").next().unwrap_or("");
                let lint_only = code.contains("cfg_attr(") && code.contains("allow(");
                (!lint_only && ISA_CFGS.iter().any(|c| code.contains(c)))
                    .then(|| format!("{rel}:{}: {}", i + 1, line.trim()))
            })
            .collect();
        let allowed = ISA_CFG_EXCEPTIONS
            .iter()
            .find(|(path, _)| *path == rel)
            .map_or(0, |&(_, count)| count);
        if hits.len() > allowed {
            found.push(format!(
                "{rel}: {} lines (allowed {allowed}):\n{}",
                hits.len(),
                hits.join("\n")
            ));
        }
    }
    assert!(
        found.is_empty(),
        "instruction-set cfgs outside kernels/dispatch/ and kernels/arch/:\n{}",
        found.join("\n")
    );
}

#[test]
fn the_scan_finds_what_is_there() {
    // The dispatch does call the instruction sets, and names their cfgs: the scans must see
    // those lines, or the checks above would pass on anything.
    let found = violations("kernels/dispatch", &["crate::kernels::arch".to_string()]);
    assert!(
        !found.is_empty(),
        "the scan found no `crate::kernels::arch` under kernels/dispatch/"
    );
    let cfgs = violations(
        "kernels/dispatch",
        &["cfg(bino_dsp)".to_string(), "cfg(bino_mve)".to_string()],
    );
    assert!(
        !cfgs.is_empty(),
        "the scan found no instruction-set cfg under kernels/dispatch/"
    );
    let model: Vec<String> = code_lines("model")
        .into_iter()
        .flat_map(|(_, _, code)| kernel_modules_named(&code))
        .collect();
    assert!(
        model.iter().any(|m| m == "dispatch"),
        "the scan found no `kernels::dispatch` in model/"
    );
}

/// A module's name at the granularity of the check: a top-level module, or a submodule of
/// `kernels` or `model` (`kernels::arch` is one module with its instruction sets).
fn module_of(file: &Path) -> String {
    let rel = file.strip_prefix(&*SRC).unwrap_or(file).with_extension("");
    let mut parts: Vec<String> = rel.iter().map(|p| p.to_string_lossy().into_owned()).collect();
    if parts.last().is_some_and(|p| p == "mod" || p == "lib") {
        parts.pop();
    }
    match parts.as_slice() {
        [] => "crate".into(),
        [top, sub, ..] if top == "kernels" || top == "model" => format!("{top}::{sub}"),
        [top, ..] => top.clone(),
    }
}

/// The modules each module names (`crate::a::b`, and `super::b` from a file of `kernels/` or
/// `model/`), outside unit tests.
fn import_graph() -> std::collections::BTreeMap<String, std::collections::BTreeSet<String>> {
    let mut files = Vec::new();
    rust_files(&SRC, &mut files);
    let mut graph = std::collections::BTreeMap::<String, std::collections::BTreeSet<String>>::new();
    for file in files {
        if file.file_name().is_some_and(|n| n == "tests.rs") {
            continue;
        }
        let from = module_of(&file);
        let rel: Vec<String> = file
            .strip_prefix(&*SRC)
            .unwrap_or(&file)
            .iter()
            .map(|p| p.to_string_lossy().into_owned())
            .collect();
        let text = fs::read_to_string(&file).unwrap_or_else(|e| panic!("{}: {e}", file.display()));
        let lines: Vec<&str> = text.lines().collect();
        for (i, line) in lines.iter().enumerate() {
            if line.trim() == "#[cfg(test)]"
                && lines
                    .get(i + 1)
                    .is_some_and(|l| l.trim_start().starts_with("mod tests"))
            {
                break;
            }
            let code = line.split("//").next().unwrap_or("");
            let mut targets = Vec::new();
            for (at, _) in code.match_indices("crate::") {
                let path: Vec<&str> = code[at + 7..]
                    .split(|c: char| !(c.is_alphanumeric() || c == '_' || c == ':'))
                    .next()
                    .unwrap_or("")
                    .split("::")
                    .collect();
                match path.as_slice() {
                    [top, sub, ..]
                        if (*top == "kernels" || *top == "model") && sub.starts_with(|c: char| c.is_lowercase()) =>
                    {
                        targets.push(format!("{top}::{sub}"))
                    }
                    [top, ..] if !top.is_empty() => targets.push((*top).to_string()),
                    _ => {}
                }
            }
            if rel.len() == 2 && (rel[0] == "kernels" || rel[0] == "model") {
                for (at, _) in code.match_indices("super::") {
                    let sub: String = code[at + 7..]
                        .chars()
                        .take_while(|c| c.is_alphanumeric() || *c == '_')
                        .collect();
                    if sub.starts_with(|c: char| c.is_lowercase()) && sub != "super" {
                        targets.push(format!("{}::{sub}", rel[0]));
                    }
                }
            }
            for to in targets {
                if to != from && !from.starts_with(&format!("{to}::")) {
                    graph.entry(from.clone()).or_default().insert(to);
                }
            }
        }
    }
    graph
}

#[test]
fn no_two_modules_import_each_other_even_through_others() {
    let graph = import_graph();
    // Depth-first search for a path back to the start from each module.
    let mut cycles = Vec::new();
    for start in graph.keys() {
        let mut stack = vec![(start.clone(), vec![start.clone()])];
        let mut seen = std::collections::BTreeSet::new();
        while let Some((at, path)) = stack.pop() {
            for next in graph.get(&at).into_iter().flatten() {
                if next == start {
                    cycles.push(format!("{} -> {start}", path.join(" -> ")));
                } else if seen.insert(next.clone()) {
                    let mut longer = path.clone();
                    longer.push(next.clone());
                    stack.push((next.clone(), longer));
                }
            }
        }
    }
    assert!(cycles.is_empty(), "import circles:\n{}", cycles.join("\n"));
    // The graph is real: the encoder names the dispatch, which names the families.
    assert!(graph
        .get("model::encoder")
        .is_some_and(|to| to.contains("kernels::dispatch")));
    assert!(graph
        .get("kernels::dispatch")
        .is_some_and(|to| to.contains("kernels::layernorm")));
}
