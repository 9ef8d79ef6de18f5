//! `retrocomp demo --serve` end to end (issue 16.3/16.4): the real binary runs its four runs
//! against the real hil-sim, then keeps a live gateway up and prints, on one line, the page's
//! address and the OPC UA endpoint. The test reads both from its output, GETs `/status` from the
//! page's address (the live gateway's snapshot with the demo's model) and connects Python asyncua
//! (pinned in scripts/setup-peers.sh) to the endpoint, which must show the same box and model
//! hash. Then SIGINT stops the demo.

#[path = "gateway_support/hil_sim.rs"]
mod hil_sim;
mod peers;

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn after<'a>(line: &'a str, prefix: &str) -> Option<&'a str> {
    let (_, rest) = line.split_once(prefix)?;
    rest.split_whitespace().next()
}

#[test]
fn demo_serve_prints_the_page_and_the_opcua_endpoint_and_both_answer() {
    let hil_sim = hil_sim::hil_sim_next_to_retrocomp();
    let py = std::env::var_os("RETROCOMP_PYTHON")
        .map(std::path::PathBuf::from)
        .unwrap_or_else(peers::python);
    let dir = tempfile::tempdir_in(env!("CARGO_TARGET_TMPDIR")).unwrap();
    let mut demo = Command::new(env!("CARGO_BIN_EXE_retrocomp"))
        .args(["demo", "--seconds", "0", "--serve", "127.0.0.1:0", "--out"])
        .arg(dir.path().join("demo"))
        .env("HIL_SIM_BIN", &hil_sim)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
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
                panic!("no live page line ({e}); stdout so far:\n{seen}");
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
            break serde_json::from_str::<serde_json::Value>(&body).unwrap();
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
    let ident: serde_json::Value = serde_json::from_str(stdout.lines().last().unwrap()).unwrap();
    assert_eq!(ident["box"], "demo-full", "{ident}");
    assert_eq!(
        ident["sha256"],
        sha.as_str(),
        "OPC UA and /status show the same model"
    );
}
