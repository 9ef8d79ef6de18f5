//! `retrocomp demo --serve` end to end (issue 16.3/16.4, 35.5): the real binary runs its four runs
//! against the real hil-sim, then keeps a live gateway up and prints, on one line, the page's
//! address and the OPC UA endpoint. The test reads both from its output, GETs `/status` from the
//! page's address (the live gateway's snapshot with the demo's model) and connects Python asyncua
//! (pinned in scripts/setup-peers.sh) to the endpoint, which must show the same box and model
//! hash. Then it watches two passes of the program (each pass cuts the pocket once: z below 0,
//! seen on `/status`, so the passes are counted by the simulated machine, not by a timer): one
//! asyncua subscription held across them gets no status change and a cycle counter that never goes
//! back, `/status` cycles never go back, the page's history spans both passes, and the fault log has
//! no stale START for every sensor at the pass boundary (what a gateway restarted per pass showed).
//! The demo publishes Sparkplug B (`--mqtt`) to a Mosquitto started here on loopback, decoded by a
//! third-party host (paho-mqtt + mqtt-spb-wrapper, `tests/peers/spb_host.py`) subscribed before the
//! demo starts: the live gateway's edge node `mill-live` has exactly one NBIRTH (one bdSeq) and no
//! NDEATH across the pass boundary, its NDATA `seq` runs on mod 256 from the NBIRTH's 0 with no gap,
//! and NDATA arrive during both pocket cuts. Then SIGINT stops the demo.

use crate::hil_sim;
use crate::mosquitto;
use crate::peers;
use crate::spb_lines;

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use retrocomp_gateway::northbound::history::unix_now_s as unix_s;
use serde_json::Value;
use spb_lines::Host;

/// The live gateway's Sparkplug edge node (`src/demo` names it; group `retrocomp-demo`).
const LIVE_NODE: &str = "mill-live";

fn after<'a>(line: &'a str, prefix: &str) -> Option<&'a str> {
    let (_, rest) = line.split_once(prefix)?;
    rest.split_whitespace().next()
}

#[test]
fn demo_serve_prints_the_page_and_the_opcua_endpoint_and_both_answer() {
    let _turn = crate::turn::take(file!());
    let hil_sim = hil_sim::hil_sim_next_to_retrocomp();
    let py = std::env::var_os("RETROCOMP_PYTHON")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(peers::python);
    let dir = tempfile::tempdir_in(env!("CARGO_TARGET_TMPDIR")).unwrap();
    // The broker and the Sparkplug host first: the host sees every birth of every run.
    let mqtt_port = peers::free_port();
    let _broker = mosquitto::Broker::start(dir.path(), mqtt_port);
    let mut spb = Host::new(peers::spawn_python(
        "spb_host.py",
        &[&mqtt_port.to_string(), "retrocomp-demo", "scada"],
    ));
    let demo_log = dir.path().join("demo.stderr");
    let mut demo = Command::new(env!("CARGO_BIN_EXE_retrocomp"))
        .args(["demo", "--seconds", "0", "--serve", "127.0.0.1:0", "--mqtt"])
        .arg(format!("127.0.0.1:{mqtt_port}"))
        .arg("--out")
        .arg(dir.path().join("demo"))
        .env("HIL_SIM_BIN", &hil_sim)
        // Its setup steps (sources, endpoints, OPC UA) logged, so a hang says where it stopped.
        .env(
            "RUST_LOG",
            "error,retrocomp=info,retrocomp_gateway=info,retrocomp_gateway::sources=warn",
        )
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(&demo_log).unwrap())
        .spawn()
        .expect("starting retrocomp demo --serve");
    let (tx, lines) = std::sync::mpsc::channel::<String>();
    let stdout = demo.stdout.take().unwrap();
    std::thread::spawn(move || {
        for l in BufReader::new(stdout).lines().map_while(Result::ok) {
            let _ = tx.send(l);
        }
    });
    // The four runs come first (real time, a loaded machine): a generous deadline.
    let deadline = Instant::now() + Duration::from_secs(600);
    let mut seen = String::new();
    let line = loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match lines.recv_timeout(left) {
            Ok(l) if l.contains("live page http://") => break l,
            Ok(l) => seen += &(l + "\n"),
            Err(e) => {
                let _ = demo.kill();
                let log = std::fs::read_to_string(&demo_log).unwrap_or_default();
                panic!("no live page line ({e}); stdout so far:\n{seen}\nstderr:\n{log}");
            }
        }
    };
    eprintln!("{line}");
    let page = after(&line, "live page http://")
        .unwrap()
        .trim_end_matches('/');
    let opc = after(&line, "OPC UA ").unwrap().to_string();
    assert!(opc.starts_with("opc.tcp://127.0.0.1:"), "{line}");

    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let get = |path: &str| {
        rt.block_on(retrocomp_gateway::northbound::http::request(
            page,
            "GET".parse().unwrap(),
            path,
            &[],
            Default::default(),
            Duration::from_secs(10),
        ))
        .unwrap_or_else(|e| panic!("GET {path}: {e}"))
    };
    // The first snapshot comes with the first cycle; poll until it is there.
    let status = loop {
        let (code, body) = get("/status");
        if code == 200 {
            break serde_json::from_str::<Value>(&body).unwrap();
        }
        assert!(Instant::now() < deadline, "/status: {code} {body}");
        std::thread::sleep(Duration::from_millis(100));
    };
    let sha = status["model"]["sha256"].as_str().unwrap().to_string();
    assert_eq!(sha.len(), 64, "{status}");

    let out = Command::new(&py)
        .arg(peers::repo().join("tests/peers/asyncua_identification.py"))
        .arg(&opc)
        .output()
        .expect("running python asyncua");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    let passes = two_passes(&mut demo, &get, &py, &opc, dir.path(), deadline);
    // Everything the live node published up to the end of the second cut (before SIGINT, whose
    // clean stop sends the session's one NDEATH).
    let second_end_ms = (passes.cuts[1].1 * 1000.0) as u64;
    spb.until("mill-live NDATA after the second cut", |m| {
        live_of(m, "NDATA")
            .iter()
            .any(|d| d["timestamp"].as_u64() >= Some(second_end_ms))
    });
    // SIGINT: the demo stops its gateway and hil-sim (kill_on_drop) and exits.
    let _ = Command::new("kill")
        .args(["-INT", &demo.id().to_string()])
        .status();
    let stop = Instant::now();
    while demo.try_wait().unwrap().is_none() && stop.elapsed() < Duration::from_secs(30) {
        std::thread::sleep(Duration::from_millis(50));
    }
    let _ = demo.kill();
    let _ = demo.wait();
    assert!(
        out.status.success(),
        "asyncua on {opc} failed ({}; {}):\n{stdout}\n{stderr}",
        out.status,
        peers::INSTALL
    );
    let ident: Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    assert_eq!(ident["box"], "demo-full", "{ident}");
    assert_eq!(
        ident["sha256"],
        sha.as_str(),
        "OPC UA and /status show the same model"
    );
    passes.check();
    check_sparkplug(&spb.msgs, &passes.cuts);
}

/// The live node's messages of one type, in arrival order.
fn live_of<'a>(msgs: &'a [Value], kind: &str) -> Vec<&'a Value> {
    spb_lines::of(msgs, kind)
        .into_iter()
        .filter(|m| m["node"] == LIVE_NODE)
        .collect()
}

/// One Sparkplug session across the pass boundary: one NBIRTH (so one bdSeq), no NDEATH, NDATA
/// `seq` continuous mod 256 from the birth's 0, NDATA during both cuts.
fn check_sparkplug(msgs: &[Value], cuts: &[(f64, f64)]) {
    let births = live_of(msgs, "NBIRTH");
    let deaths = live_of(msgs, "NDEATH");
    let data = live_of(msgs, "NDATA");
    let bd_seq = |m: &Value| {
        m["metrics"]
            .as_array()
            .and_then(|ms| ms.iter().find(|x| x["name"] == "bdSeq"))
            .and_then(|x| x["value"].as_u64())
    };
    eprintln!(
        "sparkplug {LIVE_NODE}: {} NBIRTH (bdSeq {:?}), {} NDEATH, {} NDATA",
        births.len(),
        births.iter().map(|b| bd_seq(b)).collect::<Vec<_>>(),
        deaths.len(),
        data.len()
    );
    assert_eq!(births.len(), 1, "one NBIRTH per session: {births:?}");
    assert!(deaths.is_empty(), "NDEATH while running: {deaths:?}");
    assert!(bd_seq(births[0]).is_some(), "NBIRTH without bdSeq");
    assert_eq!(births[0]["seq"], 0, "NBIRTH seq");
    // In arrival order, the birth first, then every NDATA one seq on (mod 256).
    let live: Vec<&Value> = msgs.iter().filter(|m| m["node"] == LIVE_NODE).collect();
    assert_eq!(
        live[0]["type"], "NBIRTH",
        "data before the birth: {:?}",
        live[0]
    );
    let mut gaps = vec![];
    for w in live.windows(2) {
        let (a, b) = (w[0]["seq"].as_u64().unwrap(), w[1]["seq"].as_u64().unwrap());
        if b != (a + 1) % 256 {
            gaps.push((a, b, w[1]["timestamp"].clone()));
        }
    }
    assert!(
        gaps.is_empty(),
        "NDATA seq gaps (from, to, at ms): {gaps:?}"
    );
    assert!(data.iter().all(|m| m["wrapper_parsed"] == true));
    let during = |(a, b): (f64, f64)| {
        let (a, b) = ((a * 1000.0) as u64, (b * 1000.0) as u64);
        data.iter()
            .filter_map(|m| m["timestamp"].as_u64())
            .filter(|t| *t >= a && *t <= b)
            .count()
    };
    let boundary = (cuts[0].1, cuts[1].0);
    assert!(
        during(cuts[0]) > 0 && during(boundary) > 0 && during(cuts[1]) > 0,
        "NDATA during the first cut, between the cuts and during the second: {}, {}, {}",
        during(cuts[0]),
        during(boundary),
        during(cuts[1])
    );
}

/// What the test saw across two passes of the live program.
struct Passes {
    /// Wall time (Unix s) of the two pocket cuts: (first seen, last seen).
    cuts: Vec<(f64, f64)>,
    history: Value,
    faults: Value,
    watch: Value,
    cycles_went_back: Option<(u64, u64)>,
    /// Every channel of the last `/status`.
    sensors: Vec<String>,
}

/// Watch `/status` until the simulated machine has cut the pocket twice (two passes, one pass
/// boundary between them), with one asyncua subscription held throughout.
fn two_passes(
    demo: &mut std::process::Child,
    get: &dyn Fn(&str) -> (u16, String),
    py: &std::path::Path,
    opc: &str,
    dir: &std::path::Path,
    deadline: Instant,
) -> Passes {
    let stop = dir.join("watch.stop");
    let mut watch = Command::new(py)
        .arg(peers::repo().join("tests/peers/asyncua_watch.py"))
        .arg(opc)
        .arg(&stop)
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("running python asyncua");
    let mut out = BufReader::new(watch.stdout.take().unwrap()).lines();
    let first = out.next().and_then(Result::ok).unwrap_or_default();
    assert!(first.contains("subscribed"), "asyncua_watch: {first:?}");
    let (mut cuts, mut in_cut) = (Vec::<(f64, f64)>::new(), false);
    let (mut last_cycles, mut cycles_went_back) = (0u64, None);
    let mut sensors = Vec::new();
    while cuts.len() < 2 || in_cut {
        assert!(demo.try_wait().unwrap().is_none(), "the demo ended");
        assert!(Instant::now() < deadline, "two passes not seen: {cuts:?}");
        let (code, body) = get("/status");
        assert_eq!(code, 200, "{body}");
        let st: Value = serde_json::from_str(&body).unwrap();
        let cycles = st["cycles"].as_u64().unwrap();
        if cycles < last_cycles && cycles_went_back.is_none() {
            cycles_went_back = Some((last_cycles, cycles));
        }
        last_cycles = cycles;
        sensors = st["channels"]
            .as_object()
            .unwrap()
            .keys()
            .cloned()
            .collect();
        let z = st["channels"]["z_mm"]["value"].as_f64();
        let now = unix_s();
        match (z.is_some_and(|z| z < -0.25), in_cut) {
            (true, false) => {
                cuts.push((now, now));
                in_cut = true;
            }
            (true, true) => cuts.last_mut().unwrap().1 = now,
            (false, true) => in_cut = false,
            _ => {}
        }
        std::thread::sleep(Duration::from_millis(150));
    }
    std::fs::write(&stop, "").unwrap();
    let line = out.next().and_then(Result::ok).unwrap_or_default();
    let _ = watch.wait();
    let json = |path: &str| {
        let (code, body) = get(path);
        assert_eq!(code, 200, "{path}: {body}");
        serde_json::from_str::<Value>(&body).unwrap()
    };
    Passes {
        cuts,
        history: json("/api/history?window=fine"),
        faults: json("/api/faults"),
        watch: serde_json::from_str(&line).unwrap_or_else(|e| panic!("{line:?}: {e}")),
        cycles_went_back,
        sensors,
    }
}

impl Passes {
    fn check(&self) {
        eprintln!(
            "pocket cuts (unix s): {:?}; OPC UA watch: {}",
            self.cuts, self.watch
        );
        assert_eq!(
            self.cycles_went_back, None,
            "/status cycles went back: a restart"
        );
        // One subscription, one session, across the pass boundary.
        let w = &self.watch;
        assert!(w["error"].is_null(), "{w}");
        assert_eq!(w["status_changes"], serde_json::json!([]), "{w}");
        assert_eq!(w["went_back"], false, "OPC UA cycle counter went back: {w}");
        assert!(w["notifications"].as_u64().unwrap() >= 2, "{w}");
        assert!(w["last"].as_u64() > w["first"].as_u64(), "{w}");
        // The page's history holds both passes: points before the first cut and after the second.
        let t: Vec<f64> = self.history["t_unix_s"]
            .as_array()
            .unwrap()
            .iter()
            .map(|v| v.as_f64().unwrap())
            .collect();
        let (first_cut, second_cut) = (self.cuts[0], self.cuts[1]);
        assert!(
            t.first().is_some_and(|&t0| t0 <= first_cut.0)
                && t.last().is_some_and(|&t1| t1 >= second_cut.0),
            "history {:?}..{:?} does not span the cuts {:?}",
            t.first(),
            t.last(),
            self.cuts
        );
        let applied = self.history["series"]["x/applied"].as_array().unwrap();
        let during = |(a, b): (f64, f64)| {
            t.iter()
                .zip(applied)
                .filter(|(t, v)| **t >= a - 1.0 && **t <= b + 1.0 && v.is_number())
                .count()
        };
        assert!(
            during(first_cut) > 0 && during(second_cut) > 0,
            "x/applied during both cuts"
        );
        // The pass boundary lies between the cuts: no stale START for every sensor there.
        let log = self.faults["log"].as_array().unwrap();
        let stale_there: std::collections::BTreeSet<&str> = log
            .iter()
            .filter(|e| e["event"] == "start" && e["kind"] == "stale")
            .filter(|e| {
                let u = e["unix_s"].as_f64().unwrap();
                u > first_cut.1 && u < second_cut.0
            })
            .filter_map(|e| e["source"].as_str())
            .filter(|s| self.sensors.iter().any(|c| c == s))
            .collect();
        assert!(
            self.sensors.len() >= 6 && stale_there.len() < self.sensors.len(),
            "every sensor went stale at the pass boundary: {stale_there:?}"
        );
    }
}
