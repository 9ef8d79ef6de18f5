//! The live page in a real browser (issue 16.3): Debian's headless Chromium, driven by
//! `playwright-core` (tests/browser/page_check.mjs, Node), against the real `retrocomp run` on the
//! real hil-sim (`gateway_support/web_rig.rs`). Checks that the numbers the page shows are the ones
//! of the `/status` answers it received, that a sensor fault injected mid-run (hil-sim silences the
//! temperature CAN node 10 at 20 s) appears on the page (an event wait; the latency from hil-sim's
//! fault edge to the page is printed, not asserted: the machine is loaded), and that an action
//! without the token is refused and changes nothing. Screenshots go to target/screenshots/
//! (docs/img/ with RETROCOMP_UPDATE_SCREENSHOTS=1).
//!
//! Needs `node`, tests/browser/node_modules (`npm ci --prefix tests/browser`) and
//! /usr/bin/chromium (apt `chromium`): `scripts/setup-peers.sh` installs all three.

use crate::web_rig;

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use serde_json::Value;

const FAULT_FROM_S: f64 = 20.0;
const FAULTS: &str = r#"
[[io.faults]]
kind = "can_node_silent"
node = 10
from_s = 20.0
to_s = 45.0
"#;
const EDGE: &str = "hil-sim: fault CanNodeSilent (node 10) started";

fn unix_ms() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_secs_f64()
        * 1e3
}

/// "+12.345" / "−0.500" / "–" as the page prints µm values → number (None for "–").
fn shown_um(text: &str) -> Option<f64> {
    let t = text.trim().trim_end_matches("µm").trim();
    if t == "–" {
        return None;
    }
    Some(
        t.replace('−', "-")
            .parse()
            .unwrap_or_else(|e| panic!("{text:?}: {e}")),
    )
}

fn check_shown(ev: &Value) -> bool {
    let Some(st) = ev.get("status").filter(|s| !s.is_null()) else {
        return false;
    };
    let shown = &ev["shown"];
    let axes = st["axes"].as_array().unwrap();
    assert_eq!(shown["axes"].as_array().unwrap().len(), axes.len(), "{ev}");
    for (a, s) in axes.iter().zip(shown["axes"].as_array().unwrap()) {
        assert_eq!(a["axis"], s["axis"]);
        let applied = shown_um(s["applied"].as_str().unwrap()).unwrap();
        assert!(
            (applied - a["applied_um"].as_f64().unwrap()).abs() <= 5e-4 + 1e-9,
            "{ev}"
        );
        let target = shown_um(s["target"].as_str().unwrap());
        match (target, a["target_um"].as_f64()) {
            (Some(x), Some(y)) => assert!((x - y).abs() <= 5e-4 + 1e-9, "{ev}"),
            (None, None) => {}
            other => panic!("target shown vs /status: {other:?} in {ev}"),
        }
    }
    let channels = st["channels"].as_object().unwrap();
    assert_eq!(
        shown["channels"].as_array().unwrap().len(),
        channels.len(),
        "{ev}"
    );
    for c in shown["channels"].as_array().unwrap() {
        let s = &channels[c["channel"].as_str().unwrap()];
        if let Some(v) = s["value"].as_f64() {
            let x: f64 = c["value"].as_str().unwrap().parse().unwrap();
            assert!((x - v).abs() <= 5e-4 + 1e-9, "{ev}");
        }
        let bad = s["health"] != "ok" || !s["faults"].as_array().unwrap().is_empty();
        assert_eq!(c["bad"].as_bool().unwrap(), bad, "{ev}");
    }
    let model = st["model"]["name"].as_str().unwrap();
    assert!(shown["model"].as_str().unwrap().contains(model), "{ev}");
    true
}

#[test]
fn live_page_in_headless_chromium_shows_status_faults_and_refuses_actions_without_token() {
    let _turn = crate::turn::take(file!());
    let browser_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/browser");
    assert!(
        browser_dir.join("node_modules/playwright-core").is_dir(),
        "playwright-core missing: run scripts/setup-peers.sh (npm ci --prefix tests/browser)"
    );
    let chromium = std::env::var("RETROCOMP_CHROMIUM").unwrap_or("/usr/bin/chromium".into());
    assert!(
        Path::new(&chromium).is_file(),
        "{chromium} missing: bash scripts/apt-install-safe.sh chromium chromium-driver (or set RETROCOMP_CHROMIUM)"
    );
    // Into target/ so a test run leaves the work tree clean; RETROCOMP_UPDATE_SCREENSHOTS=1 writes
    // the README's and docs/shopfloor.md's pictures in docs/img/ instead.
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let shots = if std::env::var_os("RETROCOMP_UPDATE_SCREENSHOTS").is_some() {
        root.join("docs/img")
    } else {
        root.join("target/screenshots")
    };
    std::fs::create_dir_all(&shots).unwrap();

    let mut rig = web_rig::start("gateway_web_browser", 20, FAULTS);
    rig.wait_status("first cycles", Duration::from_secs(30), |s| {
        s["axes"].as_array().is_some_and(|a| !a.is_empty())
    });
    let mut node = Command::new("node")
        .arg(browser_dir.join("page_check.mjs"))
        .current_dir(&browser_dir)
        .env("PAGE_URL", format!("http://{}/", rig.addr))
        .env("SHOT_DIR", &shots)
        .env("FAULT_CHANNEL", "T_spindle_C")
        .env("CHROMIUM", &chromium)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("node missing: install nodejs (scripts/setup-peers.sh)");
    let (tx, rx) = mpsc::channel::<(f64, String)>();
    let out = node.stdout.take().unwrap();
    std::thread::spawn(move || {
        for l in BufReader::new(out).lines().map_while(Result::ok) {
            let _ = tx.send((unix_ms(), l));
        }
    });

    let mut events: Vec<Value> = Vec::new();
    let mut edge_ms: Option<f64> = None;
    let deadline = Instant::now() + Duration::from_secs(240);
    while !events.iter().any(|e| e["event"] == "done") {
        rig.assert_alive("while the page is open");
        if edge_ms.is_none() && rig.sim.log_text().contains(EDGE) {
            edge_ms = Some(unix_ms());
        }
        if let Ok((_, l)) = rx.recv_timeout(Duration::from_millis(10)) {
            eprintln!("page: {}", l.chars().take(300).collect::<String>());
            events.push(serde_json::from_str(&l).unwrap_or_else(|e| panic!("{l}: {e}")));
        }
        if let Some(st) = node.try_wait().unwrap()
            && rx.try_recv().is_err()
            && !events.iter().any(|e| e["event"] == "done")
        {
            panic!("the browser script ended ({st}) before it was done: {events:?}");
        }
        assert!(
            Instant::now() < deadline,
            "browser script timed out: {events:?}"
        );
    }
    let _ = node.wait();
    let ev = |name: &str| {
        events
            .iter()
            .find(|e| e["event"] == name)
            .unwrap_or_else(|| panic!("no {name} event: {events:?}"))
            .clone()
    };

    // Numbers shown = numbers received (the /status answers the page got, matched by cycle).
    let matched = events
        .iter()
        .filter(|e| e["event"] == "shown")
        .filter(|e| check_shown(e))
        .count();
    assert!(
        matched >= 3,
        "only {matched} renderings matched to their /status answer: {events:?}"
    );

    // The fault: the page shows it (event wait, generous timeout). The latency from hil-sim's fault
    // edge is measured only when the browser was up before the edge: on a loaded machine Chromium
    // may take longer to start than hil-sim takes to reach it, and the page must show the fault then
    // too (the node stays silent).
    let ready = ev("ready")["unix_ms"].as_f64().unwrap();
    let edge = edge_ms.expect("hil-sim printed the fault edge");
    let shown = ev("fault_shown");
    assert!(
        shown["banner"].as_str().unwrap().contains("FAULT"),
        "{shown}"
    );
    if ready < edge {
        let latency_ms = shown["unix_ms"].as_f64().unwrap() - edge;
        eprintln!("MEASURED: sensor fault edge (hil-sim) → shown on the page: {latency_ms:.0} ms");
    } else {
        eprintln!(
            "NOT MEASURED: the browser became ready {:.0} ms after the fault edge at {FAULT_FROM_S} s (loaded machine); the page shows the fault",
            ready - edge
        );
    }
    let st = rig.status().unwrap();
    let faults = st["channels"]["T_spindle_C"]["faults"].as_array().unwrap();
    assert!(!faults.is_empty(), "/status agrees: {st}");

    // The fault's start is a line on the charts; the silent sensor's age (from its own last
    // reading) is older than every healthy one's.
    let ma = ev("marks_and_ages");
    assert!(ma["marks"][0].as_u64().unwrap() >= 1, "{ma}");
    let ages = ma["ages"].as_array().unwrap();
    let age = |ch: &str| {
        ages.iter()
            .find(|a| a["channel"] == ch)
            .and_then(|a| a["age_s"].as_f64())
            .unwrap_or_else(|| panic!("no age for {ch}: {ma}"))
    };
    let silent = age("T_spindle_C");
    for a in ages.iter().filter(|a| !a["bad"].as_bool().unwrap()) {
        let fresh = a["age_s"].as_f64().unwrap_or_else(|| panic!("{ma}"));
        assert!(fresh >= 0.0 && fresh < silent, "{ma}");
    }
    // A phone, resized to and loaded at 390 × 844: no horizontal scroll, charts and legends inside.
    let narrow: Vec<&Value> = events.iter().filter(|e| e["event"] == "narrow").collect();
    assert_eq!(narrow.len(), 2, "{events:?}");
    for n in narrow {
        let l = &n["layout"];
        let w = l["inner_w"].as_f64().unwrap();
        assert_eq!(w, 390.0, "{n}");
        assert!(
            l["scroll_w"].as_f64().unwrap() <= w,
            "horizontal scroll: {n}"
        );
        for key in ["charts", "legends"] {
            let boxes = l[key].as_array().unwrap();
            assert!(boxes.len() >= 2, "{key}: {n}");
            for b in boxes {
                let (left, right) = (b[0].as_f64().unwrap(), b[1].as_f64().unwrap());
                assert!(left >= 0.0 && right <= w, "{key} off the screen: {n}");
            }
        }
    }

    // The action without a token: refused on the page, logged, and nothing changed.
    let refused = ev("refused")["text"].as_str().unwrap().to_string();
    assert!(refused.contains("401"), "{refused}");
    assert!(
        ev("action_logged")["text"]
            .as_str()
            .unwrap()
            .contains("POST /api/compensation")
    );
    assert_eq!(
        rig.status().unwrap()["enabled"],
        true,
        "the refused action changed nothing"
    );
    // The one expected console error is the browser reporting the refused request's 401.
    let errors = ev("done")["errors"].as_array().unwrap().clone();
    let unexpected: Vec<_> = errors
        .iter()
        .filter(|e| !e.as_str().unwrap().contains("status of 401"))
        .collect();
    assert!(
        unexpected.is_empty(),
        "script errors on the page: {unexpected:?}"
    );
    for f in ["web-live.png", "web-fault.png", "web-phone.png"] {
        let b = std::fs::read(shots.join(f)).unwrap();
        assert!(b.starts_with(b"\x89PNG") && b.len() > 10_000, "{f}");
    }
}
