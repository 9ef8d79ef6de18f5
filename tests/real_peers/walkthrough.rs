//! docs/walkthrough.md, checked: `retrocomp hub` (the shipped socketcand hub command) carries frames between two python-can 4.6.1
//! clients (`interface="socketcand"`, a third-party implementation of the protocol), and stops on
//! SIGTERM with its counters. Peer: tests/peers/pycan_socketcand.py.

use crate::peers;

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};

#[test]
fn python_can_clients_talk_through_the_hub_command() {
    let _turn = crate::turn::take(file!());
    let mut hub = Command::new(env!("CARGO_BIN_EXE_retrocomp"))
        .args(["hub", "--listen", "127.0.0.1:0"])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start retrocomp hub");
    let mut out = BufReader::new(hub.stdout.take().unwrap());
    let mut first = String::new();
    out.read_line(&mut first).unwrap();
    let addr = first
        .trim()
        .strip_prefix("retrocomp hub: listening on ")
        .unwrap_or_else(|| panic!("unexpected first line {first:?}"))
        .to_owned();
    let port = addr.rsplit(':').next().unwrap().to_owned();

    // A joins first; whatever it sends before B joins has no listener. B's three frames reach A.
    let a = peers::spawn_python("pycan_socketcand.py", &["127.0.0.1", &port, "3"]);
    let b = peers::spawn_python("pycan_socketcand.py", &["127.0.0.1", &port, "3"]);
    let got: Vec<String> = (0..4).map(|_| a.line(30).trim().to_owned()).collect();
    assert_eq!(
        got,
        ["RX 181 0 39300000", "RX 18FF50E5 1", "RX 701 0 05", "DONE"],
        "frames B sent, as A received them through the hub"
    );
    drop(b);
    drop(a);

    let term = Command::new("kill")
        .args(["-TERM", &hub.id().to_string()])
        .status()
        .unwrap();
    assert!(term.success());
    let status = hub.wait().unwrap();
    assert!(status.success(), "hub exit on SIGTERM: {status}");
    let mut last = String::new();
    out.read_line(&mut last).unwrap();
    assert!(
        last.starts_with("retrocomp hub: stopped; clients 2, frames in 6,"),
        "{last:?}"
    );
}

/// docs/walkthrough.md's gateway side loads as written: the field config, and the model its
/// `[model] path` names relative to it (hil-sim's side: hil-sim/tests/sim/fuzz_regressions.rs).
#[test]
fn walkthrough_field_config_and_its_model_load() {
    let _turn = crate::turn::take(file!());
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/walkthrough");
    let cfg = retrocomp_gateway::config::FieldConfig::load(&dir.join("field.toml"))
        .unwrap_or_else(|e| panic!("{e}"));
    retrocomp_gateway::run::require_sink(&cfg).unwrap();
    let model = cfg.model.as_ref().expect("[model] path");
    retrocomp_model::MachineModel::from_toml_path(&dir.join(&model.path))
        .unwrap_or_else(|e| panic!("{e}"));
}
