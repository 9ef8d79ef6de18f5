//! The quadrature sink's edge trace, counted by a counter the project did not write: the real
//! `retrocomp run` binary (CANopen encoders through the socketcand hub, the Studer S-36 model,
//! `[sink.quadrature]` on simulated pins with `[sink.quadrature.trace]`) writes what its injector
//! threads put on the A/B lines; the trace is replayed into LinuxCNC 2.9's HAL `encoder` component
//! (×4, counter mode off) by a Python HAL component (`tests/peers/hal_encoder_replay.py`), and
//! LinuxCNC's count must equal the box's intended count — the held counts it persisted plus the
//! simulated scale's native counts, sign included — on an injected-only axis (x) and a
//! native-plus-injected axis (z), both at the injection rate cap (the per-cycle cap asks for more
//! counts per cycle than the rate lets out). The trace itself must keep the configured minimum
//! edge gap and the rate interval between injected edges. Units: counts (A/B edges), ns.

use crate::linuxcnc_support;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use retrocomp_bus::can::{CanBus, Hub, SocketcandBus};

use crate::process;
use crate::studer_can;
use studer_can::encoder;

const MIN_EDGE_GAP_NS: u64 = 400;
const RATE_HZ: f64 = 2_000.0;
/// 1 / RATE_HZ: the closest two injected edges may be.
const INJECT_INTERVAL_NS: u64 = 500_000;
/// The simulated scale on z: up 300 counts, back 120.
const NATIVE_MOVES: [i64; 2] = [300, -120];

/// One row of the trace.
#[derive(Clone, Debug, PartialEq)]
struct Row {
    t_ns: u64,
    axis: String,
    a: bool,
    b: bool,
    source: String,
}

fn field(dir: &Path, hub_port: u16) -> String {
    let d = dir.display();
    format!(
        r#"
[gateway]
name = "edge-trace"
cycle_ms = 5
on_stop = "hold"
[safety]
max_correction_um = 60.0
max_change_um_per_cycle = 2.0
ramp_um_per_s = 400.0
stale_hold_s = 0.5
{machine}[sink.quadrature]
state_file = "{d}/held.toml"
[sink.quadrature.trace]
path = "{d}/trace.csv"
max_bytes = 1000000
{z}{x}"#,
        machine = studer_can::machine_on_can(hub_port),
        z = axis(
            "z",
            &format!(
                "simulated_native = {{ moves_counts = [{}, {}], rate_hz = 1000.0 }}\n",
                NATIVE_MOVES[0], NATIVE_MOVES[1]
            )
        ),
        x = axis("x", ""),
    )
}

/// One `[[sink.quadrature.axis]]`: 0.1 µm counts at the test's gap and rate cap, plus `extra`.
fn axis(name: &str, extra: &str) -> String {
    format!(
        "[[sink.quadrature.axis]]\naxis = \"{name}\"\nresolution_um = 0.1\ncount_sign = 1\n\
         min_edge_gap_ns = {MIN_EDGE_GAP_NS}\nmax_inject_rate_hz = {RATE_HZ}\n{extra}"
    )
}

fn read_held(path: &Path) -> BTreeMap<String, i64> {
    std::fs::read_to_string(path)
        .ok()
        .and_then(|t| toml::from_str(&t).ok())
        .unwrap_or_default()
}

fn read_trace(path: &Path) -> Vec<Row> {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let mut lines = text.lines();
    let header = lines.next();
    if header.is_none() {
        return Vec::new();
    }
    assert_eq!(header, Some("t_ns,axis,a,b,source"), "{}", path.display());
    lines
        .map(|l| {
            let f: Vec<&str> = l.split(',').collect();
            assert_eq!(f.len(), 5, "trace row {l:?}");
            Row {
                t_ns: f[0].parse().unwrap(),
                axis: f[1].into(),
                a: f[2] == "1",
                b: f[3] == "1",
                source: f[4].into(),
            }
        })
        .collect()
}

/// Runs the box until z has played its native moves and the held counts of both axes have stopped
/// changing, stops it with SIGTERM (`on_stop = "hold"`: the counts stay), and returns the held
/// counts it persisted and its trace.
async fn run_box(dir: &Path) -> (BTreeMap<String, i64>, Vec<Row>) {
    let hub = Hub::start_loopback().await.unwrap();
    let cfg_path = dir.join("field.toml");
    std::fs::write(&cfg_path, field(dir, hub.local_addr().port())).unwrap();
    let mut child = process::start_run(&[], &cfg_path);
    // The machine: z drives 400 → 510 mm, x stands at 50 mm; TPDOs every 2 ms.
    let mut can = SocketcandBus::connect(hub.local_addr(), "can0")
        .await
        .unwrap();
    let (ez, ex) = (encoder("z_mm", 1), encoder("x_mm", 2));
    let native_edges: u64 = NATIVE_MOVES.iter().map(|m| m.unsigned_abs()).sum();
    let t0 = Instant::now();
    let mut last = (BTreeMap::new(), Instant::now());
    let settled = loop {
        let z = (400.0 + 200.0 * t0.elapsed().as_secs_f64()).min(510.0);
        can.send(&ez.encode_position(z).unwrap()).await.unwrap();
        can.send(&ex.encode_position(50.0).unwrap()).await.unwrap();
        tokio::time::sleep(Duration::from_millis(2)).await;
        if t0.elapsed() > Duration::from_secs(60) {
            break false;
        }
        let held = read_held(&dir.join("held.toml"));
        if held != last.0 {
            last = (held, Instant::now());
            continue;
        }
        let native = read_trace(&dir.join("trace.csv"))
            .iter()
            .filter(|r| r.source == "native")
            .count() as u64;
        // Held counts unchanged for 1 s at 510 mm: the engine's correction is steady.
        if z >= 510.0
            && native == native_edges
            && last.0.len() == 2
            && last.1.elapsed() > Duration::from_secs(1)
        {
            break true;
        }
    };
    let err = process::stop_with_sigterm(&mut child);
    assert!(settled, "the box did not settle within 60 s: {err}");
    assert!(
        !err.contains("sink.quadrature.trace"),
        "trace fault (entries lost or write failed): {err}"
    );
    assert!(
        !dir.join("trace.csv.1").exists(),
        "1 MB is enough: no rotation"
    );
    (
        read_held(&dir.join("held.toml")),
        read_trace(&dir.join("trace.csv")),
    )
}

/// The trace's own checks per axis: one `start` row first, then edges in time order at least the
/// configured gap apart, injected edges at least the rate interval apart.
fn check_gaps(rows: &[Row], axis: &str) -> (usize, usize) {
    let mine: Vec<&Row> = rows.iter().filter(|r| r.axis == axis).collect();
    assert_eq!(mine.first().map(|r| r.source.as_str()), Some("start"));
    assert_eq!(mine.iter().filter(|r| r.source == "start").count(), 1);
    let edges = &mine[1..];
    for w in edges.windows(2) {
        let gap = w[1]
            .t_ns
            .checked_sub(w[0].t_ns)
            .expect("rows in time order");
        assert!(
            gap >= MIN_EDGE_GAP_NS,
            "{axis}: edges {gap} ns apart at {} ns",
            w[1].t_ns
        );
    }
    let injected: Vec<u64> = edges
        .iter()
        .filter(|r| r.source == "injected")
        .map(|r| r.t_ns)
        .collect();
    for w in injected.windows(2) {
        assert!(
            w[1] - w[0] >= INJECT_INTERVAL_NS,
            "{axis}: injected edges {} ns apart",
            w[1] - w[0]
        );
    }
    let native = edges.iter().filter(|r| r.source == "native").count();
    (native, injected.len())
}

/// Replays the trace into LinuxCNC's `encoder` (one channel per axis) as uid 65534 (rtapi_app
/// refuses root), serialised with the other LinuxCNC tests; returns per axis the replay's JSON.
fn replay_into_linuxcnc(dir: &Path, axes: &[&str]) -> serde_json::Value {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/peers/hal_encoder_replay.py");
    let d = dir.display();
    let mut hal = format!(
        "loadrt threads name1=fast period1=200000\nloadrt encoder num_chan={n}\n\
addf encoder.update-counters fast\naddf encoder.capture-position fast\n\
loadusr -Wn replay /usr/bin/python3 {s} {d}/trace.csv {list} {d}/replay.json\n",
        n = axes.len(),
        s = script.display(),
        list = axes.join(",")
    );
    for k in 0..axes.len() {
        hal.push_str(&format!(
            "setp encoder.{k}.x4-mode 1\nsetp encoder.{k}.counter-mode 0\n\
net a{k} replay.a{k} => encoder.{k}.phase-A\nnet b{k} replay.b{k} => encoder.{k}.phase-B\n\
net reset{k} replay.reset{k} => encoder.{k}.reset\n\
net raw{k} encoder.{k}.rawcounts => replay.raw{k}\nnet counts{k} encoder.{k}.counts => replay.counts{k}\n"
        ));
    }
    hal.push_str("start\nsetp replay.go 1\nwaitusr replay\n");
    std::fs::write(dir.join("replay.hal"), hal).unwrap();
    Command::new("chmod")
        .args(["-R", "a+rwX"])
        .arg(dir)
        .status()
        .unwrap();
    let out = linuxcnc_support::nobody::one_at_a_time_as_nobody(dir)
        .args(["halrun", "-f"])
        .arg(dir.join("replay.hal"))
        .current_dir(dir)
        .output()
        .unwrap();
    let log = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let json = std::fs::read_to_string(dir.join("replay.json"))
        .unwrap_or_else(|e| panic!("halrun wrote no replay.json ({e}): {log}"));
    serde_json::from_str(&json).unwrap()
}

fn require_linuxcnc_hal() {
    for p in ["halrun", "halcmd", "setpriv", "flock"] {
        linuxcnc_support::require(p);
    }
    let hal = Command::new("/usr/bin/python3")
        .args(["-c", "import hal"])
        .status()
        .is_ok_and(|s| s.success());
    assert!(
        hal,
        "/usr/bin/python3 cannot import LinuxCNC's `hal` module. {}",
        linuxcnc_support::INSTALL_HINT
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn linuxcnc_encoder_counts_what_the_box_traced() {
    let _turn = crate::turn::take(file!());
    require_linuxcnc_hal();
    let dir = tempfile::tempdir().unwrap();
    let (held, rows) = run_box(dir.path()).await;
    let native_net: i64 = NATIVE_MOVES.iter().sum();
    // The box's intended count per axis: what it persisted ahead of its edges (it started from 0)
    // plus, on z, the simulated scale's moves. Correction + → counts − (count_sign 1).
    let intended = BTreeMap::from([("z", held["z"] + native_net), ("x", held["x"])]);
    assert!(
        held["z"] < 0 && held["x"] != 0,
        "both axes injected (z: EZZ +9.6 µm → −96 counts): {held:?}"
    );

    let (z_native, z_injected) = check_gaps(&rows, "z");
    let (x_native, x_injected) = check_gaps(&rows, "x");
    let native_edges: u64 = NATIVE_MOVES.iter().map(|m| m.unsigned_abs()).sum();
    assert_eq!(z_native as u64, native_edges, "every native edge on z");
    assert_eq!(x_native, 0, "x is injected-only");
    assert!(
        z_injected as u64 >= held["z"].unsigned_abs()
            && x_injected as u64 >= held["x"].unsigned_abs(),
        "injected edges z {z_injected}, x {x_injected} for held {held:?}"
    );

    let counted = replay_into_linuxcnc(dir.path(), &["z", "x"]);
    eprintln!(
        "held {held:?}; trace: z {z_native} native + {z_injected} injected edges, x {x_injected} \
         injected; intended {intended:?}; LinuxCNC encoder: {counted}"
    );
    for (axis, want) in &intended {
        let got = &counted[axis];
        assert_eq!(
            got["counts"].as_i64(),
            Some(*want),
            "{axis}: LinuxCNC encoder counted {got}, the box intended {want} (held {held:?})"
        );
        assert_eq!(got["unseen"], 0, "{axis}: {got}");
    }
}

/// A trace the box could not keep bounded or buffered is refused at start with file, line and key.
#[test]
fn trace_limits_are_checked_with_file_line_and_key() {
    let _turn = crate::turn::take(file!());
    let dir = tempfile::tempdir().unwrap();
    let text = field(dir.path(), 29536);
    let path: PathBuf = dir.path().join("field.toml");
    let line = text
        .lines()
        .position(|l| l.starts_with("max_bytes"))
        .unwrap()
        + 1;
    for (bad, key) in [
        ("max_bytes = 10", "sink.quadrature.trace.max_bytes"),
        (
            "max_bytes = 1000000\nbuffer_edges = 1",
            "sink.quadrature.trace.buffer_edges",
        ),
    ] {
        let t = text.replacen("max_bytes = 1000000", bad, 1);
        let e = retrocomp_gateway::config::FieldConfig::parse(&t, &path)
            .unwrap_err()
            .to_string();
        assert!(e.contains(key) && e.contains("field.toml"), "{e}");
        if key.ends_with("max_bytes") {
            assert!(e.contains(&format!(":{line}")), "line {line}: {e}");
        }
    }
    let gpio = text.replacen(
        "simulated_native",
        "gpio = { chip = \"/dev/gpiochip0\", line_a = 1, line_b = 2 }\nsimulated_native",
        1,
    );
    let e = retrocomp_gateway::config::FieldConfig::parse(&gpio, &path)
        .unwrap_err()
        .to_string();
    assert!(e.contains("simulated_native"), "{e}");
}
