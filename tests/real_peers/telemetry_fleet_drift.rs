//! Recordings of every machine and model drift, against a real Mosquitto (started here on a free
//! loopback port, persistence off) with the real binaries: `retrocomp ship-recording` on the boxes'
//! side, `retrocomp fleet --collect-dir --models` on the shop's side.
//!
//! 1. Two boxes with the same model (a 50 ppm scale of X): box-a's recording follows it, box-b's
//!    has an extra thermal effect the model lacks (2.5 µm/K of a spindle temperature). box-b ships
//!    over MQTT (chunked), box-a into the collection directory. The fleet collects both, diagnoses
//!    each against its own model, and flags exactly box-b, with the thermal finding.
//! 2. A shipment cut short while the broker is down stays in its on-disk queue; the next run
//!    sends it, and the fleet writes the recording byte for byte.
//!
//! Every wait ends on an event (a line, a process exit, a file), with deadlines only a broken
//! implementation reaches.

use crate::mosquitto;
use crate::peers;
use crate::snapshot;

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use mosquitto::Broker;
use peers::free_port;
use snapshot::snapshot;

const PATIENCE: Duration = Duration::from_secs(300);

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_retrocomp"))
}

/// A `retrocomp fleet` child; returns once it said it is subscribed (its stderr). Also used by
/// `fleet_workers.rs`.
pub(crate) struct Fleet(Child);

impl Fleet {
    pub(crate) fn start(port: u16, extra: &[&str]) -> Fleet {
        let mut child = bin()
            .args(["fleet", "--broker", &format!("127.0.0.1:{port}")])
            .args(["--group", "shop", "--json", "--seconds", "900"])
            .args(extra)
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let mut err = BufReader::new(child.stderr.take().unwrap());
        let mut line = String::new();
        loop {
            line.clear();
            assert!(
                err.read_line(&mut line).unwrap() > 0,
                "fleet ended before subscribing"
            );
            if line.contains("subscribed") {
                break;
            }
        }
        // Keep draining stderr so the child never blocks on a full pipe.
        std::thread::spawn(move || for _ in err.lines() {});
        Fleet(child)
    }

    /// Wait for the fleet to stop by itself; its nodes (the last JSON line).
    pub(crate) fn json(mut self) -> serde_json::Value {
        let deadline = Instant::now() + PATIENCE;
        while self.0.try_wait().unwrap().is_none() {
            assert!(Instant::now() < deadline, "fleet did not finish");
            std::thread::sleep(Duration::from_millis(100));
        }
        let mut out = String::new();
        std::io::Read::read_to_string(self.0.stdout.as_mut().unwrap(), &mut out).unwrap();
        // One JSON object per update, one per line: the last is the final state.
        let last = out.lines().last().unwrap_or_default();
        let v: serde_json::Value =
            serde_json::from_str(last).unwrap_or_else(|e| panic!("{e}: {out}"));
        v["nodes"].clone()
    }
}

impl Drop for Fleet {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

pub(crate) const MODEL: &str = "schema = 1\n[machine]\nname = \"t\"\nchain = \"Z X\"\ntool_axis = \"+x\"\n\
    [axes.z]\ntravel_mm = [0.0, 10.0]\n[axes.x]\ntravel_mm = [0.0, 300.0]\n\
    [[tools]]\nname = \"t\"\noffset_mm = [0.0, 0.0, 0.0]\n\
    [[components]]\nname = \"EXX\"\npositions_mm = [0, 300]\nforward_mm = [0.0, 0.015]\n";

/// A recording per docs/recording-csv.md: X sweeps, a spindle temperature that rises and falls (not in step
/// with time or X), ex = 50 ppm of X + 0.2 µm noise (+ `um_per_k` × (T − 20 °C)).
pub(crate) fn recording(um_per_k: f64) -> String {
    let mut s = String::from("t_s,x_mm,z_mm,T_spindle_C,ex_um\n");
    let mut seed: u64 = 0x2545_f491_4f6c_dd1d;
    for i in 0..1200 {
        let t = f64::from(i) * 2.0;
        let x = f64::from((i * 37) % 300);
        let temp = 20.0
            + 3.0 * (t * std::f64::consts::TAU / 1500.0).sin()
            + 1.5 * (t * std::f64::consts::TAU / 470.0).sin();
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        let noise = ((seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 0.7;
        let ex = 0.05 * x + noise + um_per_k * (temp - 20.0);
        s.push_str(&format!("{t},{x},0,{temp:.4},{ex:.4}\n"));
    }
    s
}

fn ship(args: &[&str]) -> std::process::Output {
    bin().arg("ship-recording").args(args).output().unwrap()
}

#[test]
fn the_fleet_flags_exactly_the_machine_whose_model_drifted_with_the_finding() {
    let _turn = crate::turn::take(file!());
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let _broker = Broker::start(dir.path(), port);
    let (collect, models) = (dir.path().join("collect"), dir.path().join("models"));
    std::fs::create_dir_all(&models).unwrap();
    for m in ["box-a", "box-b"] {
        std::fs::write(models.join(format!("{m}.toml")), MODEL).unwrap();
    }
    let (a_csv, b_csv) = (dir.path().join("a.csv"), dir.path().join("b.csv"));
    std::fs::write(&a_csv, recording(0.0)).unwrap();
    std::fs::write(&b_csv, recording(2.5)).unwrap();
    let fleet = Fleet::start(
        port,
        &[
            "--collect-dir",
            collect.to_str().unwrap(),
            "--models",
            models.to_str().unwrap(),
            "--diagnose-every-s",
            "1",
            "--drift-um",
            "1.0",
            "--stop-after-diagnosed",
            "2",
        ],
    );
    let broker = format!("127.0.0.1:{port}");
    let b = ship(&[
        "--recording",
        b_csv.to_str().unwrap(),
        "--name",
        "week-48.csv",
        "--broker",
        &broker,
        "--group",
        "shop",
        "--edge-node",
        "box-b",
        "--rows-per-chunk",
        "100",
    ]);
    assert!(b.status.success(), "{}", String::from_utf8_lossy(&b.stderr));
    let r: serde_json::Value = serde_json::from_slice(&b.stdout).unwrap();
    assert_eq!(r["acked"], 12, "1200 rows in chunks of 100: {r}");
    let a = ship(&[
        "--recording",
        a_csv.to_str().unwrap(),
        "--name",
        "week-48.csv",
        "--group",
        "shop",
        "--edge-node",
        "box-a",
        "--to-dir",
        collect.to_str().unwrap(),
    ]);
    assert!(a.status.success(), "{}", String::from_utf8_lossy(&a.stderr));

    let j = fleet.json();
    let node = |n: &str| {
        j.as_array()
            .unwrap()
            .iter()
            .find(|v| v["edge_node"] == n)
            .unwrap_or_else(|| panic!("{n} not in {j}"))
            .clone()
    };
    let (a, b) = (node("box-a"), node("box-b"));
    assert_eq!(a["drift"]["state"], "ok", "{a}");
    assert!(a["drift"]["rms_um"].as_f64().unwrap() < 1.0, "{a}");
    assert_eq!(b["drift"]["state"], "drifted", "{b}");
    assert!(b["drift"]["rms_um"].as_f64().unwrap() > 3.0, "{b}");
    let f = &b["drift"]["finding"];
    assert_eq!(f["effect"], "thermal_drift", "{b}");
    assert_eq!(f["signal"], "ex_um");
    assert_eq!(f["params"]["sensor"], "T_spindle_C", "{f}");
    let k = f["params"]["um_per_K"].as_f64().unwrap();
    assert!((k - 2.5).abs() < 0.2, "um_per_K {k}: {f}");
    // The recording that went over MQTT is the one the box shipped, byte for byte.
    let got = std::fs::read_to_string(collect.join("shop/box-b/week-48.csv")).unwrap();
    assert_eq!(got, std::fs::read_to_string(&b_csv).unwrap());
}

#[test]
fn a_shipment_cut_short_by_a_dead_broker_resumes_from_its_disk_queue() {
    let _turn = crate::turn::take(file!());
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let queue = dir.path().join("queue");
    let csv = dir.path().join("r.csv");
    std::fs::write(&csv, recording(0.0)).unwrap();
    let broker = format!("127.0.0.1:{port}");
    let common = [
        "--broker",
        &broker,
        "--group",
        "shop",
        "--edge-node",
        "box-c",
        "--queue-dir",
        queue.to_str().unwrap(),
    ];
    // Nothing listens on the port: the shipment gives up, everything stays queued on disk.
    let mut args = vec![
        "--recording",
        csv.to_str().unwrap(),
        "--rows-per-chunk",
        "50",
    ];
    args.extend(["--timeout-s", "1"]);
    args.extend(common);
    let cut = ship(&args);
    assert!(!cut.status.success());
    let r: serde_json::Value = serde_json::from_slice(&cut.stdout).unwrap();
    assert_eq!(r["left"], 24, "{r}");
    assert_eq!(std::fs::read_dir(&queue).unwrap().count(), 24);

    let _broker = Broker::start(dir.path(), port);
    let collect = dir.path().join("collect");
    let _fleet = Fleet::start(port, &["--collect-dir", collect.to_str().unwrap()]);
    let done = ship(&common);
    assert!(
        done.status.success(),
        "{}",
        String::from_utf8_lossy(&done.stderr)
    );
    let r: serde_json::Value = serde_json::from_slice(&done.stdout).unwrap();
    assert_eq!(r["acked"], 24, "{r}");
    assert_eq!(std::fs::read_dir(&queue).unwrap().count(), 0);
    let out = collect.join("shop/box-c/r.csv");
    let deadline = Instant::now() + PATIENCE;
    while !out.is_file() {
        assert!(Instant::now() < deadline, "the fleet never completed r.csv");
        std::thread::sleep(Duration::from_millis(50));
    }
    assert_eq!(
        std::fs::read_to_string(&out).unwrap(),
        std::fs::read_to_string(&csv).unwrap()
    );
}

/// `Publisher::finish` (what the load bench relies on for its final counts): every record the
/// sampler produced is acknowledged before NDEATH, and the fleet host has each of them once.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn finish_sends_every_record_before_ndeath() {
    let _turn = crate::turn::take(file!());
    use retrocomp_fleet::FleetClient;
    use retrocomp_gateway::northbound::telemetry::{self, MqttConfig, PublisherInputs};
    use std::sync::Arc;
    let dir = tempfile::tempdir().unwrap();
    let port = free_port();
    let _broker = Broker::start(dir.path(), port);
    let broker = format!("127.0.0.1:{port}");
    let mut fleet = FleetClient::new(&broker, Some("shop")).unwrap();
    while !fleet.subscribed {
        let _ = tokio::time::timeout(PATIENCE, fleet.poll()).await;
    }
    let (tx, rx) = tokio::sync::watch::channel(None);
    let mut cfg = MqttConfig::new(&broker, "shop", "box-f");
    cfg.rate_hz = 50.0;
    let p = telemetry::spawn(
        cfg,
        PublisherInputs {
            status: rx,
            model_identity: "m".into(),
            declared: Default::default(),
        },
    )
    .unwrap();
    // Feed changes until a few hundred records were produced (whatever the machine's speed).
    let feeder = tokio::spawn({
        let st = p.status.clone();
        async move {
            let mut k = 0;
            while st.borrow().records_total < 200 {
                k += 1;
                tx.send_replace(Some(Arc::new(snapshot(k))));
                tokio::time::sleep(Duration::from_millis(10)).await;
            }
        }
    });
    // The fleet keeps reading meanwhile (each NDATA ends a poll; a poll is never cut short).
    let key = ("shop".to_string(), "box-f".to_string());
    while !feeder.is_finished() {
        let _ = fleet.poll().await;
    }
    let st = p.finish(PATIENCE).await;
    assert!(st.records_total >= 200, "{st:?}");
    assert_eq!(st.queued, 0, "{st:?}");
    assert_eq!(st.acked_total, st.records_total, "{st:?}");
    assert_eq!(st.dropped_total, 0, "{st:?}");
    let deadline = Instant::now() + PATIENCE;
    while fleet.view.nodes.get(&key).is_none_or(|n| n.alive) {
        assert!(Instant::now() < deadline, "no NDEATH after finish");
        let _ = tokio::time::timeout(PATIENCE, fleet.poll()).await;
    }
    let n = &fleet.view.nodes[&key];
    assert_eq!(
        n.ndata, st.records_total,
        "every record once, before NDEATH"
    );
    assert_eq!(n.seq_gaps, 0);
}
