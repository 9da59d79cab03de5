//! `bino_core::pipeline` is layered: each module imports only modules below it, so the pipeline
//! has no import cycle. The layers, bottom up, are [`LAYERS`]; a module's `super::` paths (its
//! `use` lines and any path in its code; doc-only imports aside) must name a lower layer's
//! module, or an item the pipeline's root re-exports from one.

use std::collections::HashMap;
use std::path::PathBuf;

/// The pipeline's modules, bottom up; modules of one layer do not import each other.
const LAYERS: &[&[&str]] = &[
    &["layout"],
    &["api"],
    &["refine_stage", "row_passes"],
    &["census_stage", "feeding"],
    &["head_check", "row_buffers"],
    &["sizing"],
    &["context"],
    &["streams", "native", "census_run"],
    &["export"],
    &["driver"],
];

fn pipeline_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../core/src/pipeline")
}

fn layer_of(module: &str) -> Option<usize> {
    LAYERS.iter().position(|layer| layer.contains(&module))
}

/// `source` without its `#[cfg(doc)]` imports (links, not dependencies) and its line comments.
fn code_of(source: &str) -> String {
    let mut out = String::new();
    let mut skipping = false;
    let mut after_doc_cfg = false;
    for line in source.lines() {
        let trimmed = line.trim_start();
        if trimmed.starts_with("//") {
            continue;
        }
        if trimmed.starts_with("#[cfg(doc)]") {
            after_doc_cfg = true;
            continue;
        }
        if after_doc_cfg {
            after_doc_cfg = false;
            skipping = trimmed.starts_with("use ");
        }
        if skipping {
            skipping = !trimmed.ends_with(';');
            continue;
        }
        out.push_str(line);
        out.push('\n');
    }
    out
}

/// Every name that follows `super::` in `code`, expanding `super::{a, b::c}` groups.
fn super_names(code: &str) -> Vec<String> {
    let mut names = Vec::new();
    for (at, _) in code.match_indices("super::") {
        let rest = &code[at + "super::".len()..];
        if let Some(group) = rest.strip_prefix('{') {
            let inner = &group[..group.find('}').unwrap_or(group.len())];
            for part in inner.split(',') {
                let name: String = part
                    .trim()
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                names.push(name);
            }
        } else {
            names.push(rest.chars().take_while(|c| c.is_alphanumeric() || *c == '_').collect());
        }
    }
    names.retain(|n| !n.is_empty() && n != "self");
    names
}

/// The items `pipeline.rs` re-exports, by the module they come from.
fn root_reexports() -> HashMap<String, String> {
    let root = std::fs::read_to_string(pipeline_dir().with_extension("rs")).unwrap();
    let mut items = HashMap::new();
    for statement in root.split(';') {
        let Some(at) = statement.find("pub use ") else { continue };
        let path = statement[at + "pub use ".len()..].trim();
        let Some((module, rest)) = path.split_once("::") else {
            continue;
        };
        let names = rest.trim_start_matches('{').trim_end_matches('}');
        for name in names.split(',').map(str::trim).filter(|n| !n.is_empty()) {
            items.insert(name.to_string(), module.to_string());
        }
    }
    items
}

#[test]
fn each_pipeline_module_imports_only_the_layers_below_it() {
    let reexports = root_reexports();
    let mut seen = Vec::new();
    for entry in std::fs::read_dir(pipeline_dir()).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "rs") {
            continue; // refine_stage/ holds its tests
        }
        let module = path.file_stem().unwrap().to_str().unwrap().to_string();
        let layer = layer_of(&module).unwrap_or_else(|| panic!("{module}.rs is in no layer of LAYERS"));
        let code = code_of(&std::fs::read_to_string(&path).unwrap());
        for name in super_names(&code) {
            let target = match layer_of(&name) {
                Some(_) => name.clone(),
                None => match reexports.get(&name) {
                    Some(module) => module.clone(),
                    None => panic!("{module}.rs: super::{name} is neither a pipeline module nor a re-export"),
                },
            };
            let below = layer_of(&target).is_some_and(|l| l < layer);
            assert!(
                below,
                "{module}.rs (layer {layer}) imports {target} (layer {:?}): a cycle in the making",
                layer_of(&target)
            );
        }
        seen.push(module);
    }
    seen.sort();
    let mut all: Vec<String> = LAYERS.iter().flat_map(|l| l.iter().map(|m| m.to_string())).collect();
    all.sort();
    assert_eq!(seen, all, "every layer's module exists, and no other");
}

#[test]
fn the_checker_sees_groups_paths_and_skips_doc_links() {
    let code = code_of(
        "use super::api::{A, B};\nuse super::{layout, sizing::x};\n#[cfg(doc)]\nuse super::driver::Pipeline;\n\
         // super::native in a comment\nfn f() { super::census_run::run_census(); }\n",
    );
    assert_eq!(super_names(&code), ["api", "layout", "sizing", "census_run"]);
}
