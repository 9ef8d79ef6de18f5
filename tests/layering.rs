//! The layering of the workspace. The crates' dependencies are the layers, so Cargo enforces them;
//! these tests lock the graph itself (a new upward edge between crates fails here, not in review),
//! what the appliance build leaves out, and that the files inside each crate import each other
//! without a cycle (code lines only, above a file's `#[cfg(test)]`).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
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

fn cargo(args: &[&str]) -> String {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .args(args)
        .current_dir(repo())
        .output()
        .expect("run cargo");
    assert!(
        out.status.success(),
        "cargo {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).unwrap()
}

/// The workspace's packages, from `cargo metadata`.
fn packages() -> Vec<serde_json::Value> {
    let meta: serde_json::Value = serde_json::from_str(&cargo(&[
        "metadata",
        "--format-version",
        "1",
        "--no-deps",
        "--offline",
    ]))
    .unwrap();
    meta["packages"].as_array().unwrap().clone()
}

/// Each workspace crate and the workspace crates it depends on (normal dependencies, every
/// target platform).
fn crate_graph() -> BTreeMap<String, BTreeSet<String>> {
    let packages = packages();
    let names: BTreeSet<String> = packages
        .iter()
        .map(|p| p["name"].as_str().unwrap().to_string())
        .collect();
    let mut graph = BTreeMap::new();
    for p in &packages {
        let deps = p["dependencies"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|d| d["kind"].is_null())
            .map(|d| d["name"].as_str().unwrap().to_string());
        let (internal, _): (BTreeSet<String>, BTreeSet<String>) =
            deps.partition(|d| names.contains(d));
        graph.insert(p["name"].as_str().unwrap().to_string(), internal);
    }
    graph
}

/// Every external crate a package depends on (normal dependencies).
fn external_deps(package: &str) -> BTreeSet<String> {
    let packages = packages();
    let p = packages
        .iter()
        .find(|p| p["name"] == package)
        .unwrap_or_else(|| panic!("no package {package}"));
    p["dependencies"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|d| d["kind"].is_null())
        .map(|d| d["name"].as_str().unwrap().to_string())
        .collect()
}

/// The layers: model at the bottom (no async runtime); the sources on it; the gateway on both; the
/// offline toolkit and diagnose on the model only; the fleet host on the gateway's telemetry and on
/// diagnose; the binary on all. Test programs (hil-sim, the vcan guest) sit beside the product;
/// hil-sim plays the world around the box, a fleet of boxes too (its `fleet_load`), so it uses
/// every library crate.
#[test]
fn the_crates_depend_on_each_other_as_layers() {
    let graph = crate_graph();
    let set = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<BTreeSet<_>>();
    let want = BTreeMap::from([
        ("retrocomp-model".to_string(), set(&[])),
        ("retrocomp-bus".to_string(), set(&["retrocomp-model"])),
        (
            "retrocomp-gateway".to_string(),
            set(&["retrocomp-model", "retrocomp-bus"]),
        ),
        ("retrocomp-analysis".to_string(), set(&["retrocomp-model"])),
        (
            "retrocomp-fleet".to_string(),
            set(&["retrocomp-model", "retrocomp-gateway", "retrocomp-analysis"]),
        ),
        (
            "retrocomp".to_string(),
            set(&[
                "retrocomp-model",
                "retrocomp-bus",
                "retrocomp-gateway",
                "retrocomp-analysis",
                "retrocomp-fleet",
            ]),
        ),
        (
            "hil-sim".to_string(),
            set(&[
                "retrocomp-model",
                "retrocomp-bus",
                "retrocomp-gateway",
                "retrocomp-analysis",
                "retrocomp-fleet",
            ]),
        ),
        (
            "vcan-guest".to_string(),
            set(&["retrocomp-model", "retrocomp-bus", "retrocomp-gateway"]),
        ),
    ]);
    assert_eq!(graph, want);
}

/// The model crate is plain computation: no async runtime, no I/O crate.
#[test]
fn the_model_has_no_runtime() {
    let deps = external_deps("retrocomp-model");
    assert!(deps.contains("nalgebra"), "read {deps:?}");
    for runtime in ["tokio", "tokio-modbus", "tokio-serial", "tracing", "axum"] {
        assert!(
            !deps.contains(runtime),
            "retrocomp-model depends on {runtime}"
        );
    }
}

/// The appliance's gateway without its optional northbound servers builds none of the plant's or
/// the analyst's heavy crates; with its defaults it has the OPC UA and MQTT ones (the check can fail).
/// `scripts/test.sh` compiles that build (`cargo clippy -p retrocomp-gateway --no-default-features`).
#[test]
fn the_bare_gateway_leaves_out_opcua_mqtt_and_the_analysis_crates() {
    let heavy = [
        "async-opcua",
        "rumqttc",
        "statrs",
        "rustfft",
        "realfft",
        "plotters",
    ];
    let tree = |extra: &[&str]| {
        let mut args = vec![
            "tree",
            "--offline",
            "-p",
            "retrocomp-gateway",
            "-e",
            "normal",
            "--prefix",
            "none",
            "--format",
            "{p}",
        ];
        args.extend_from_slice(extra);
        cargo(&args)
            .lines()
            .filter_map(|l| l.split_whitespace().next().map(str::to_string))
            .collect::<BTreeSet<String>>()
    };
    let bare = tree(&["--no-default-features"]);
    assert!(bare.contains("tokio-modbus"), "read {bare:?}");
    for h in heavy {
        assert!(!bare.contains(h), "the bare gateway builds {h}");
    }
    let full = tree(&[]);
    assert!(
        full.contains("async-opcua") && full.contains("rumqttc"),
        "{full:?}"
    );
}

/// `anyhow` is the command line's: the libraries' seams have typed errors
/// (`retrocomp_model::error`), so no library crate depends on it and the root package's library
/// (the demo) does not name it.
#[test]
fn only_the_binary_uses_anyhow() {
    for lib in [
        "retrocomp-model",
        "retrocomp-bus",
        "retrocomp-gateway",
        "retrocomp-analysis",
        "retrocomp-fleet",
    ] {
        assert!(
            !external_deps(lib).contains("anyhow"),
            "{lib} depends on anyhow"
        );
    }
    let mut found = Vec::new();
    for f in rust_files(&repo().join("src/demo")) {
        for (n, l) in code_lines(&f) {
            if l.contains("anyhow") {
                found.push(format!("{}:{n}: {}", f.display(), l.trim()));
            }
        }
    }
    assert!(
        found.is_empty(),
        "anyhow in the demo:\n{}",
        found.join("\n")
    );
}

/// The modules of `dir` (a folder of the repository, `module` its path in its crate, e.g. `nc`; empty
/// for a crate's root) and which
/// of them each one names: a top-level file is one module, a sub-folder is one module (all its
/// files). A file refers to a sibling as `crate::<module>::NAME` (`crate::NAME` at the root) or as `super::NAME` (from a
/// sub-folder's files, `super::super::NAME` one level down, and so on), also inside a `{…}` group.
fn module_graph(dir: &str, module: &str) -> BTreeMap<String, BTreeSet<String>> {
    let root = repo().join(dir);
    let mut members: BTreeMap<String, Vec<(PathBuf, usize)>> = BTreeMap::new();
    for e in std::fs::read_dir(&root).unwrap_or_else(|e| panic!("{}: {e}", root.display())) {
        let p = e.unwrap().path();
        let name = p.file_stem().unwrap().to_string_lossy().to_string();
        if p.is_dir() {
            // `super::` from `sub/mod.rs` reaches `dir`; from `sub/x.rs` it takes `super::super::`.
            let files: Vec<(PathBuf, usize)> = rust_files(&p)
                .into_iter()
                .map(|f| {
                    let depth = f.strip_prefix(&p).unwrap().components().count();
                    let up = if f.file_name().is_some_and(|n| n == "mod.rs") {
                        depth
                    } else {
                        depth + 1
                    };
                    (f, up)
                })
                .collect();
            // `x.rs` and its folder `x/` are one module.
            members.entry(name).or_default().extend(files);
        } else if name != "mod" && name != "lib" && p.extension().is_some_and(|x| x == "rs") {
            members.entry(name).or_default().push((p, 1));
        }
    }
    let names: BTreeSet<String> = members.keys().cloned().collect();
    let mut edges = BTreeMap::new();
    for (name, files) in &members {
        let mut to = BTreeSet::new();
        for (path, up) in files {
            let own = if module.is_empty() {
                "crate::".to_string()
            } else {
                format!("crate::{module}::")
            };
            let prefixes = [own, "super::".repeat(*up)];
            for (_, l) in code_lines(path) {
                for prefix in &prefixes {
                    to.extend(refs_after(&l, prefix, &names));
                }
            }
        }
        to.remove(name);
        edges.insert(name.clone(), to);
    }
    edges
}

/// The names of `names` that `line` reaches through `prefix` (`prefixNAME` or `prefix{…, NAME…}`),
/// not counting a longer `super::super::` chain as `super::`.
fn refs_after(line: &str, prefix: &str, names: &BTreeSet<String>) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    for (i, _) in line.match_indices(prefix) {
        if line[..i].ends_with("super::") {
            continue;
        }
        let rest = &line[i + prefix.len()..];
        if rest.starts_with("super::") {
            continue;
        }
        let name: String = rest
            .chars()
            .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
            .collect();
        if names.contains(&name) {
            out.insert(name);
        }
        if let Some(group) = rest.strip_prefix('{') {
            for part in group.split('}').next().unwrap_or("").split(',') {
                let name = part.trim().split("::").next().unwrap_or("").trim();
                if names.contains(name) {
                    out.insert(name.to_string());
                }
            }
        }
    }
    out
}

/// The first import cycle of `edges`, as `a → b → a`.
fn first_cycle(edges: &BTreeMap<String, BTreeSet<String>>) -> Option<String> {
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
        if state.get(n.as_str()).copied().unwrap_or(0) == 0
            && let Some(c) = visit(n, edges, &mut state, &mut Vec::new())
        {
            return Some(c.join(" → "));
        }
    }
    None
}

#[test]
fn the_files_of_each_crate_import_each_other_without_a_cycle() {
    let folders = [
        ("crates/model/src", ""),
        ("crates/bus/src", ""),
        ("crates/gateway/src", ""),
        ("crates/gateway/src/config", "config"),
        ("crates/gateway/src/engine", "engine"),
        ("crates/gateway/src/sinks", "sinks"),
        ("crates/gateway/src/northbound", "northbound"),
        ("crates/analysis/src", ""),
        ("crates/analysis/src/nc", "nc"),
        ("crates/analysis/src/fit", "fit"),
        ("crates/analysis/src/identify", "identify"),
        ("crates/analysis/src/export", "export"),
        ("crates/analysis/src/diagnose", "diagnose"),
    ];
    for (dir, module) in folders {
        let edges = module_graph(dir, module);
        assert!(edges.len() > 2, "{dir}: read {edges:?}");
        if let Some(c) = first_cycle(&edges) {
            panic!("{dir}: import cycle: {c}");
        }
    }
    // The check can fail: these edges exist (the runtime on the engine, the term readers below
    // the model parser, the motion blocks below the rewriter, the nc folder on the analysis
    // tables) ...
    let gateway = module_graph("crates/gateway/src", "");
    assert!(gateway["run"].contains("engine"), "{gateway:?}");
    // The engine never reaches up to the runtime, the sinks or the plant's servers.
    for up in ["run", "cycle", "sinks", "northbound"] {
        assert!(
            !gateway["engine"].contains(up),
            "engine → {up}: {gateway:?}"
        );
    }
    let models = module_graph("crates/model/src", "");
    assert!(models["parse"].contains("parse_terms"), "{models:?}");
    let nc = module_graph("crates/analysis/src/nc", "nc");
    assert!(nc["motion"].contains("rewrite"), "{nc:?}");
    let analysis = module_graph("crates/analysis/src", "");
    assert!(analysis["nc"].contains("table"), "{analysis:?}");
    // The search calls the held-out score and the exchange step, which name its types in
    // `selection`; `select/tests.rs` counts as `select`.
    let diagnose = module_graph("crates/analysis/src/diagnose", "diagnose");
    assert!(diagnose["select"].contains("heldout"), "{diagnose:?}");
    assert!(diagnose["select"].contains("swap"), "{diagnose:?}");
    assert!(diagnose["swap"].contains("selection"), "{diagnose:?}");
    assert!(diagnose["select"].contains("features"), "{diagnose:?}");
    // ... and one back edge closes a cycle.
    let mut injected = nc.clone();
    injected.get_mut("rewrite").unwrap().insert("motion".into());
    assert!(first_cycle(&injected).is_some_and(|c| c.contains("motion → rewrite")));
}
