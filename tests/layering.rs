//! The folder list is the architecture (issue 14.2), locked by reading the sources:
//!
//! - the sinks (`origin_shift/`, `quadrature/`), the buses (`bus/`), `telemetry/` and the shared
//!   vocabulary below the gateway (`fault.rs`, `sink.rs`, `status.rs`, `realtime.rs`) never import
//!   `crate::gateway`, the demo or the CLI;
//! - telemetry ↔ gateway is one-way: the gateway's runtime starts the publisher and hands it the
//!   status snapshot (`crate::status`, below both); nothing below the gateway but `telemetry/`
//!   itself imports `crate::telemetry` (the snapshot embeds no telemetry type from there);
//! - the gateway never imports the demo application or the CLI;
//! - the files of `src/gateway/` import each other without a cycle.
//!
//! Only code lines count (comments may name anything), and only above a file's `#[cfg(test)]`.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

fn rust_files(p: &Path) -> Vec<PathBuf> {
    if p.is_file() {
        return vec![p.to_path_buf()];
    }
    let mut out = Vec::new();
    for e in std::fs::read_dir(p).unwrap_or_else(|e| panic!("{}: {e}", p.display())) {
        let path = e.unwrap().path();
        if path.is_dir() {
            out.extend(rust_files(&path));
        } else if path.extension().is_some_and(|x| x == "rs") {
            out.push(path);
        }
    }
    out.sort();
    out
}

/// The code lines of a file above its test module (comments dropped).
fn code_lines(path: &Path) -> Vec<(usize, String)> {
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .enumerate()
        .take_while(|(_, l)| l.trim() != "#[cfg(test)]")
        .filter(|(_, l)| !l.trim_start().starts_with("//"))
        .map(|(i, l)| (i + 1, l.to_string()))
        .collect()
}

/// Every `path:line: text` in `dirs` (under `src/`) that names one of `forbidden` and none of
/// `allowed`.
fn offenders(dirs: &[&str], forbidden: &[&str], allowed: &[&str]) -> Vec<String> {
    offenders_in(&src(), dirs, forbidden, allowed)
}

fn offenders_in(root: &Path, dirs: &[&str], forbidden: &[&str], allowed: &[&str]) -> Vec<String> {
    let mut out = Vec::new();
    for d in dirs {
        for f in rust_files(&root.join(d)) {
            for (n, l) in code_lines(&f) {
                let bad = forbidden.iter().any(|p| l.contains(p));
                if bad && !allowed.iter().any(|p| l.contains(p)) {
                    out.push(format!("{}:{n}: {}", f.display(), l.trim()));
                }
            }
        }
    }
    out
}

#[test]
fn the_layers_below_the_gateway_do_not_import_it() {
    let up = ["crate::gateway", "crate::demo", "crate::cli"];
    let found = offenders(
        &[
            "origin_shift",
            "quadrature",
            "bus",
            "telemetry",
            "fault.rs",
            "sink.rs",
            "status.rs",
            "realtime.rs",
        ],
        &up,
        &[],
    );
    assert!(found.is_empty(), "upward imports:\n{}", found.join("\n"));
}

/// The layers below telemetry: what it reads (the snapshot, the fault vocabulary, the buses, the
/// models) never imports it back.
const BELOW_TELEMETRY: [&str; 7] = [
    "origin_shift",
    "quadrature",
    "bus",
    "fault.rs",
    "sink.rs",
    "status.rs",
    "realtime.rs",
];

#[test]
fn telemetry_and_the_gateway_import_one_way() {
    let found = offenders(&BELOW_TELEMETRY, &["crate::telemetry"], &[]);
    assert!(
        found.is_empty(),
        "imports of telemetry from below it:\n{}",
        found.join("\n")
    );
    // The check can fail: telemetry reads the snapshot from `crate::status`, and the gateway's
    // runtime does import telemetry (it starts the publisher).
    assert!(!offenders(&["telemetry"], &["crate::status::"], &[]).is_empty());
    assert!(!offenders(&["gateway"], &["crate::telemetry"], &[]).is_empty());
}

/// The detector flags an injected upward import (a copy of `src/` with one line added), and only
/// in code: the same line as a comment passes.
#[test]
fn an_injected_upward_import_is_caught() {
    let dir = tempfile::tempdir().unwrap();
    let tel = dir.path().join("telemetry");
    std::fs::create_dir_all(&tel).unwrap();
    let original = std::fs::read_to_string(src().join("telemetry/metrics.rs")).unwrap();
    let up = ["crate::gateway", "crate::demo", "crate::cli"];
    std::fs::write(tel.join("metrics.rs"), &original).unwrap();
    assert!(offenders_in(dir.path(), &["telemetry"], &up, &[]).is_empty());
    std::fs::write(
        tel.join("metrics.rs"),
        format!("// use crate::gateway::status::StatusSnapshot;\n{original}"),
    )
    .unwrap();
    assert!(offenders_in(dir.path(), &["telemetry"], &up, &[]).is_empty());
    std::fs::write(
        tel.join("metrics.rs"),
        format!("use crate::gateway::status::StatusSnapshot;\n{original}"),
    )
    .unwrap();
    let found = offenders_in(dir.path(), &["telemetry"], &up, &[]);
    assert_eq!(found.len(), 1, "{found:?}");
    assert!(found[0].ends_with("metrics.rs:1: use crate::gateway::status::StatusSnapshot;"));
}

#[test]
fn the_gateway_does_not_import_the_demo_or_the_cli() {
    let found = offenders(&["gateway"], &["crate::demo", "crate::cli"], &[]);
    assert!(found.is_empty(), "{}", found.join("\n"));
    assert!(
        !src().join("gateway/demo").exists(),
        "the demo application lives in src/demo"
    );
}

/// The gateway file (module name) a code line refers to, for `super::NAME` and
/// `crate::gateway::NAME`.
fn gateway_refs(line: &str, names: &BTreeSet<String>) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    for prefix in ["super::", "crate::gateway::"] {
        for (i, _) in line.match_indices(prefix) {
            let rest = &line[i + prefix.len()..];
            let name: String = rest
                .chars()
                .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                .collect();
            if names.contains(&name) {
                out.insert(name);
            }
        }
        // `use super::{a, b::C}`
        if let Some(i) = line.find(&format!("{prefix}{{")) {
            let group = &line[i + prefix.len() + 1..];
            let group = group.split('}').next().unwrap_or("");
            for part in group.split(',') {
                let name = part.trim().split("::").next().unwrap_or("").trim();
                if names.contains(name) {
                    out.insert(name.to_string());
                }
            }
        }
    }
    out
}

#[test]
fn the_gateway_files_import_each_other_without_a_cycle() {
    let dir = src().join("gateway");
    // Top-level files of the gateway (its sub-folders, e.g. `opcua/`, count as one module).
    let mut files: BTreeMap<String, PathBuf> = BTreeMap::new();
    for e in std::fs::read_dir(&dir).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_stem().unwrap().to_string_lossy().to_string();
        if p.is_dir() {
            files.insert(name, p.join("mod.rs"));
        } else if name != "mod" && p.extension().is_some_and(|x| x == "rs") {
            files.insert(name, p);
        }
    }
    let names: BTreeSet<String> = files.keys().cloned().collect();
    assert!(names.len() > 10, "read {names:?}");
    let mut edges: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for (name, path) in &files {
        let mut to = BTreeSet::new();
        for (_, l) in code_lines(path) {
            to.extend(gateway_refs(&l, &names));
        }
        to.remove(name);
        edges.insert(name.clone(), to);
    }
    // Depth-first search; a back edge closes a cycle.
    fn visit(
        n: &str,
        edges: &BTreeMap<String, BTreeSet<String>>,
        state: &mut BTreeMap<String, u8>,
        path: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        state.insert(n.to_string(), 1);
        path.push(n.to_string());
        for m in &edges[n] {
            match state.get(m.as_str()).copied().unwrap_or(0) {
                1 => {
                    let start = path.iter().position(|p| p == m).unwrap();
                    let mut cycle = path[start..].to_vec();
                    cycle.push(m.clone());
                    return Some(cycle);
                }
                0 => {
                    if let Some(c) = visit(m, edges, state, path) {
                        return Some(c);
                    }
                }
                _ => {}
            }
        }
        path.pop();
        state.insert(n.to_string(), 2);
        None
    }
    let mut state = BTreeMap::new();
    for n in edges.keys() {
        if state.get(n.as_str()).copied().unwrap_or(0) == 0 {
            let cycle = visit(n, &edges, &mut state, &mut Vec::new());
            assert!(
                cycle.is_none(),
                "import cycle: {}",
                cycle.unwrap().join(" → ")
            );
        }
    }
    // The check can fail: the runtime does import the engine.
    assert!(edges["run"].contains("engine"), "{edges:?}");
}
