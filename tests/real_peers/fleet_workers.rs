//! The fleet host scaled out: `retrocomp fleet --workers` shares the machines' diagnoses among
//! three `retrocomp fleet-worker` processes on an MQTT 5 shared subscription of a real Mosquitto
//! (started here on a free loopback port), one worker killed (SIGKILL) while it holds a granted
//! job (crates/fleet/src/dispatch.rs).
//!
//! Seven machines' recordings (the drift test's fixtures: box-3 and box-6 with a thermal effect
//! their model lacks) are diagnosed once in-process (`retrocomp fleet --models`, the reference),
//! then by the workers. Worker w1 holds every job it is granted (the hidden
//! `--hold-after-grant-ms`) and is killed once it holds one: its will frees the job, the host
//! publishes it again, another worker does it. Every machine gets exactly one result, done by
//! exactly one worker (one stdout line per finished job), the killed worker's machine among the
//! others' lines, with the in-process verdicts.
//!
//! Every wait ends on an event (a line, a process exit), with deadlines only a broken
//! implementation reaches; nothing depends on how fast this machine is.

use crate::mosquitto::Broker;
use crate::peers::free_port;
use crate::telemetry_fleet_drift::{Fleet, MODEL, recording};

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

const PATIENCE: Duration = Duration::from_secs(300);
const MACHINES: usize = 7;
const DRIFTING: [&str; 2] = ["box-3", "box-6"];

/// A `retrocomp fleet-worker` child: its stderr lines go to `lines` (tagged with its id), its
/// stdout (one JSON line per finished job) is read when it ends.
struct Worker {
    id: String,
    child: Child,
    out: std::thread::JoinHandle<Vec<serde_json::Value>>,
}

impl Worker {
    fn start(
        port: u16,
        id: &str,
        dirs: (&str, &str),
        extra: &[&str],
        lines: mpsc::Sender<(String, String)>,
    ) -> Worker {
        let mut child = Command::new(env!("CARGO_BIN_EXE_retrocomp"))
            .args(["fleet-worker", "--broker", &format!("127.0.0.1:{port}")])
            .args(["--id", id, "--collect-dir", dirs.0, "--models", dirs.1])
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let err = BufReader::new(child.stderr.take().unwrap());
        let tag = id.to_string();
        std::thread::spawn(move || {
            for l in err.lines().map_while(Result::ok) {
                let _ = lines.send((tag.clone(), l));
            }
        });
        let out = BufReader::new(child.stdout.take().unwrap());
        let out = std::thread::spawn(move || {
            out.lines()
                .map_while(Result::ok)
                .map(|l| serde_json::from_str(&l).unwrap_or_else(|e| panic!("{e}: {l}")))
                .collect()
        });
        Worker {
            id: id.into(),
            child,
            out,
        }
    }

    /// SIGKILL, and the lines it printed.
    fn kill(mut self) -> Vec<serde_json::Value> {
        let _ = self.child.kill();
        let _ = self.child.wait();
        self.out.join().unwrap()
    }
}

/// The next stderr line that contains `what`, of worker `who` (or any): (worker, line).
fn wait_line(
    lines: &mpsc::Receiver<(String, String)>,
    who: Option<&str>,
    what: &str,
) -> (String, String) {
    let deadline = Instant::now() + PATIENCE;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        let (w, l) = lines
            .recv_timeout(left)
            .unwrap_or_else(|_| panic!("{who:?} never said {what:?}"));
        if l.contains(what) && who.is_none_or(|x| x == w) {
            return (w, l);
        }
    }
}

/// The final drift of every machine in a fleet's last JSON line, by edge node.
fn drifts(nodes: &serde_json::Value) -> BTreeMap<String, serde_json::Value> {
    nodes
        .as_array()
        .unwrap()
        .iter()
        .map(|n| {
            (
                n["edge_node"].as_str().unwrap().to_string(),
                n["drift"].clone(),
            )
        })
        .collect()
}

#[test]
fn three_workers_diagnose_every_machine_once_and_a_killed_ones_job_is_taken_over() {
    let _turn = crate::turn::take(file!());
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let _broker = Broker::start(dir.path(), port);
    let (collect, models) = (dir.path().join("collect"), dir.path().join("models"));
    std::fs::create_dir_all(&models).unwrap();
    for i in 1..=MACHINES {
        let m = format!("box-{i}");
        let um_per_k = if DRIFTING.contains(&m.as_str()) {
            2.5
        } else {
            0.0
        };
        let d = collect.join("shop").join(&m);
        std::fs::create_dir_all(&d).unwrap();
        std::fs::write(d.join("week-48.csv"), recording(um_per_k)).unwrap();
        std::fs::write(models.join(format!("{m}.toml")), MODEL).unwrap();
    }
    let (c, m) = (collect.to_str().unwrap(), models.to_str().unwrap());
    let n = MACHINES.to_string();
    let host_args = [
        "--collect-dir",
        c,
        "--models",
        m,
        "--diagnose-every-s",
        "1",
        "--drift-um",
        "1.0",
        "--stop-after-diagnosed",
        &n,
    ];
    // The reference: the same diagnoses in-process.
    let reference = drifts(&Fleet::start(port, &host_args).json());
    assert_eq!(reference.len(), MACHINES, "{reference:?}");

    let (tx, lines) = mpsc::channel();
    // w1 holds every job it is granted until it is killed.
    let hold = ["--hold-after-grant-ms", "3600000"];
    let w1 = Worker::start(port, "w1", (c, m), &hold, tx.clone());
    let w2 = Worker::start(port, "w2", (c, m), &[], tx.clone());
    let w3 = Worker::start(port, "w3", (c, m), &[], tx);
    for _ in 0..3 {
        wait_line(&lines, None, "subscribed");
    }
    let mut args = host_args.to_vec();
    // A job stuck behind w1 (delivered, never claimed) goes out again after 3 s.
    args.extend(["--workers", "--unclaimed-s", "3"]);
    let host = Fleet::start(port, &args);
    // The host cannot finish while w1 holds a job: only its death frees it.
    let (_, granted) = wait_line(&lines, Some("w1"), "granted job");
    let killed_machine = granted
        .rsplit_once('/')
        .and_then(|(_, m)| m.strip_suffix(')'))
        .unwrap_or_else(|| panic!("{granted}"))
        .to_string();
    let w1_lines = w1.kill();
    let nodes = host.json();
    let mut done: Vec<serde_json::Value> = w1_lines;
    let mut by_others = vec![];
    for w in [w2, w3] {
        let id = w.id.clone();
        let l = w.kill();
        eprintln!("{id}: {} jobs", l.len());
        by_others.extend(
            l.iter()
                .map(|v| v["edge_node"].as_str().unwrap().to_string()),
        );
        done.extend(l);
    }

    // Every machine exactly once, with the in-process verdict.
    let got = drifts(&nodes);
    assert_eq!(got.len(), MACHINES, "{nodes}");
    for (machine, d) in &got {
        let r = &reference[machine];
        assert_eq!(d["diagnoses"], 1, "{machine}: one result: {d}");
        assert_eq!(d["state"], r["state"], "{machine}: {d} vs in-process {r}");
        assert_eq!(d["verdict"], r["verdict"], "{machine}");
        let (a, b) = (d["rms_um"].as_f64().unwrap(), r["rms_um"].as_f64().unwrap());
        assert!((a - b).abs() < 1e-9, "{machine}: rms {a} vs in-process {b}");
        let want = if DRIFTING.contains(&machine.as_str()) {
            "drifted"
        } else {
            "ok"
        };
        assert_eq!(d["state"], want, "{machine}: {d}");
    }
    // Each machine diagnosed by exactly one worker (a denied claim prints nothing).
    let mut per_machine: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for l in &done {
        per_machine
            .entry(l["edge_node"].as_str().unwrap().into())
            .or_default()
            .push(l["worker"].as_str().unwrap().into());
        assert_eq!(
            l["state"],
            got[l["edge_node"].as_str().unwrap()]["state"],
            "{l}"
        );
    }
    assert_eq!(per_machine.len(), MACHINES, "{per_machine:?}");
    for (machine, ws) in &per_machine {
        assert_eq!(ws.len(), 1, "{machine} done by {ws:?}");
        assert_ne!(
            ws[0], "w1",
            "w1 finished nothing: it held its job until killed"
        );
    }
    assert!(
        by_others.contains(&killed_machine),
        "w1's job ({killed_machine}) was taken over: {per_machine:?}"
    );
}
