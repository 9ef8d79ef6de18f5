//! Switching the model of a RUNNING gateway (issue 16.2, `POST /api/model`): the real
//! `retrocomp run` on the real hil-sim (`gateway_support/web_rig.rs`), started with the demo's full
//! model and `[gateway.models]` declaring the geometric one, the full one and a "fragile" one whose
//! file is broken after start. Without the token: 401 and nothing changes; an undeclared name or a
//! path: 404; the broken file: 422 with the parse error and nothing changes; the model in use:
//! 409. The good switch: 202, then hil-sim's own log of every PLC write shows the correction
//! ramping to exactly 0 within the dosing cap and back up with the new model, and `/status`,
//! `/metrics`, `/api/models` and the OPC UA `Identification/ModelSha256` (read by asyncua) show
//! the new hash.

use crate::configs;
use crate::observe;
use crate::peers;
use crate::run;
use crate::web_rig;

use std::path::Path;
use std::time::{Duration, Instant};

use web_rig::{TOKEN, applied};

fn sha_of(s: &serde_json::Value) -> String {
    s["model"]["sha256"]
        .as_str()
        .unwrap_or_default()
        .to_string()
}

fn tracking(s: &serde_json::Value) -> bool {
    s["enabled"] == true
        && s["axes"]
            .as_array()
            .unwrap()
            .iter()
            .all(|a| a["mode"] == "tracking")
        && applied(s).iter().any(|(_, v)| v.abs() > 1.0)
}

#[test]
fn a_declared_model_is_switched_in_through_the_ramps_and_bad_requests_change_nothing() {
    let _turn = crate::turn::take(file!());
    let models = Path::new(env!("CARGO_TARGET_TMPDIR")).join("gateway_model_switch-models");
    let _ = std::fs::remove_dir_all(&models);
    std::fs::create_dir_all(&models).unwrap();
    let demo = Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/demo");
    let geo = models.join("geometric.toml");
    let fragile = models.join("fragile.toml");
    std::fs::copy(demo.join("mill-geometric.toml"), &geo).unwrap();
    std::fs::copy(demo.join("mill-geometric.toml"), &fragile).unwrap();
    let extra = format!(
        "\n[opcua]\nlisten = \"127.0.0.1:0\"\n{}[gateway.models]\ngeometric = \"{}\"\nfragile = \"{}\"\nfull = \"{}\"\n",
        configs::OPCUA_IDENT,
        geo.display(),
        fragile.display(),
        run::demo_truth_model().display()
    );
    // Eight strokes: the program ends by itself after ≈ 25 s (hil-sim then writes its logs); the
    // gateway must still be up for the OPC UA read after the switch on a loaded machine.
    let mut rig = web_rig::start_with("gateway_model_switch", 8, "", &extra);
    let before = rig.wait_status(
        "tracking with a correction",
        Duration::from_secs(30),
        tracking,
    );
    let full_sha = sha_of(&before);
    assert_eq!(full_sha.len(), 64, "{before}");
    // The declared file was loaded at start; now it breaks (an editor mid-save, a bad copy).
    std::fs::write(&fragile, "schema = 1\n[machine\n").unwrap();

    let body = |name: &str| format!(r#"{{"model": "{name}"}}"#);
    for auth in [None, Some("wrong-token-wrong-token")] {
        let (code, text) = rig.call("POST", "/api/model", auth, &body("geometric"));
        assert_eq!(code, 401, "{auth:?}: {text}");
    }
    for (name, want) in [
        ("nope", 404),
        ("../../etc/passwd", 404),
        ("fragile", 422),
        ("full", 409),
    ] {
        let (code, text) = rig.call("POST", "/api/model", Some(TOKEN), &body(name));
        assert_eq!(code, want, "{name}: {text}");
        if name == "fragile" {
            assert!(
                text.contains("cannot be loaded") && text.contains("fragile.toml"),
                "{text}"
            );
        }
    }
    let (code, _) = rig.call(
        "POST",
        "/api/model",
        Some(TOKEN),
        r#"{"path": "/tmp/x.toml"}"#,
    );
    assert_eq!(code, 422, "a path instead of a declared name is refused");
    // Nothing changed: same model, still compensating, nothing ramping.
    let until = Instant::now() + Duration::from_millis(500);
    while Instant::now() < until {
        let s = rig.status().unwrap();
        assert_eq!(
            sha_of(&s),
            full_sha,
            "a refused switch changed the model: {s}"
        );
        assert!(tracking(&s), "a refused switch changed the output: {s}");
        std::thread::sleep(Duration::from_millis(20));
    }
    let m: serde_json::Value =
        serde_json::from_str(&rig.call("GET", "/api/models", None, "").1).unwrap();
    assert_eq!(
        m["declared"],
        serde_json::json!(["fragile", "full", "geometric"])
    );
    assert!(m["switching_to"].is_null(), "{m}");

    let switch_at_s = rig.t0.elapsed().as_secs_f64();
    let (code, text) = rig.call("POST", "/api/model", Some(TOKEN), &body("geometric"));
    assert_eq!(code, 202, "{text}");
    let accepted: serde_json::Value = serde_json::from_str(&text).unwrap();
    let geo_sha = accepted["switching_to"]["sha256"]
        .as_str()
        .unwrap()
        .to_string();
    assert!(geo_sha.len() == 64 && geo_sha != full_sha, "{accepted}");
    let after = rig.wait_status("the new model tracking", Duration::from_secs(20), |s| {
        sha_of(s) == geo_sha && tracking(s)
    });
    assert!(after["model"]["loaded_unix_s"].as_f64() > before["model"]["loaded_unix_s"].as_f64());
    let metrics = rig.call("GET", "/metrics", None, "").1;
    assert!(
        metrics.contains(&format!("sha256=\"{geo_sha}\"")),
        "{metrics}"
    );
    let m: serde_json::Value =
        serde_json::from_str(&rig.call("GET", "/api/models", None, "").1).unwrap();
    assert_eq!(m["current"]["sha256"], geo_sha.as_str());
    assert!(m["switching_to"].is_null(), "switch finished: {m}");
    // The plant's OPC UA view follows (asyncua reads Identification/ModelSha256).
    let opc = rig
        .log_text()
        .lines()
        .find_map(|l| l.split_once("OPC UA endpoint ").map(|(_, r)| r.to_string()))
        .and_then(|r| r.split_whitespace().next().map(str::to_string))
        .expect("OPC UA endpoint in the log");
    let py = std::env::var_os("RETROCOMP_PYTHON")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(peers::python);
    let out = std::process::Command::new(&py)
        .arg(peers::repo().join("tests/peers/asyncua_identification.py"))
        .arg(&opc)
        .output()
        .expect("running python asyncua");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "asyncua on {opc} ({}): {stdout}\n{}",
        peers::INSTALL,
        String::from_utf8_lossy(&out.stderr)
    );
    let ident: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    assert_eq!(
        ident["sha256"],
        geo_sha.as_str(),
        "OPC UA identification: {ident}"
    );
    let actions = rig.call("GET", "/api/actions", None, "").1;
    assert!(actions.contains("accepted: ramping out"), "{actions}");
    let log = rig.log_text();
    assert!(
        log.contains("model switch: ramping the correction out"),
        "{log}"
    );
    assert!(log.contains("model switch: new model in use"), "{log}");

    let text = rig.plc_writes_after_sim_ends();
    let writes: Vec<_> = observe::parse_writes(&text)
        .into_iter()
        .filter(|w| w.address == 0)
        .collect();
    // Every write within the clamp, every step within the dosing cap (+ one register LSB).
    let (_, max_step) = observe::assert_clamp_and_cap(&writes);
    let peak = |u: &[f64; 3]| u.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    let from = writes
        .iter()
        .position(|w| w.t_s >= switch_at_s - 0.05)
        .unwrap();
    let around = &writes[from..];
    assert!(
        peak(&around[0].um) > 1.0,
        "compensating when the switch was asked: {:?}",
        around[0]
    );
    let zero = around
        .iter()
        .position(|w| peak(&w.um) == 0.0)
        .expect("the correction reached exactly 0 before the swap");
    let back = around[zero..]
        .iter()
        .position(|w| peak(&w.um) > 1.0)
        .expect("the correction came back with the new model");
    eprintln!(
        "switch: from {:.1} µm to 0 in {zero} writes, back above 1 µm after {back} more; largest step {max_step:.2} µm",
        peak(&around[0].um)
    );
}
