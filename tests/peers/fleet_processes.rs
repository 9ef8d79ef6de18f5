//! The fleet as separate OS processes (benches/fleet_processes.rs, and its small test in
//! tests/real_peers/telemetry_mqtt.rs): one fleet host process (`fleet_load host`, a test program of hil-sim: the fleet
//! host's MQTT client and view) and P box processes of K boxes each (`fleet_load boxes`:
//! the real Sparkplug publisher per box), all against one broker, over TLS when a CA is given.
//! The window starts once every box is connected and born (the host's latency restarts there); after it every box finishes (its queue acknowledged, then NDEATH) and reports what it
//! produced; then the host must have every record and every NDEATH. CPU shares are % of one core
//! from /proc (utime + stime); latencies ms (host arrival − the NDATA's Sparkplug timestamp).
#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, ChildStdout, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use retrocomp_fleet::LatencySummary;
use retrocomp_fleet::load::{BoxesReport, HostTotals};

/// How long the host may take to subscribe, and to see every record after the boxes finished:
/// only a broken path reaches it.
pub(crate) const PATIENCE: Duration = Duration::from_secs(180);

/// utime + stime of a process (/proc/<pid>/stat fields 14 and 15), clock ticks (1/100 s).
pub(crate) fn cpu_ticks(pid: u32) -> u64 {
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .ok()
        .and_then(|s| {
            let rest = s.rsplit_once(')')?.1;
            let f: Vec<&str> = rest.split_whitespace().collect();
            Some(f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?)
        })
        .unwrap_or(0)
}

/// (busy, total) clock ticks of the whole machine (/proc/stat, all cores): how loaded it was.
pub(crate) fn machine_ticks() -> (u64, u64) {
    let s = std::fs::read_to_string("/proc/stat").unwrap_or_default();
    let f: Vec<u64> = s
        .lines()
        .next()
        .unwrap_or_default()
        .split_whitespace()
        .skip(1)
        .filter_map(|x| x.parse().ok())
        .collect();
    let total: u64 = f.iter().sum();
    // idle + iowait are not busy.
    let idle = f.get(3).copied().unwrap_or(0) + f.get(4).copied().unwrap_or(0);
    (total - idle, total)
}

/// One load: `procs` processes of `boxes_per_proc` boxes at `rate_hz` for `seconds`.
#[derive(Clone, Debug)]
pub(crate) struct Load {
    pub procs: usize,
    pub boxes_per_proc: usize,
    pub rate_hz: f64,
    pub seconds: f64,
    /// Sparkplug group (a new one per load, so loads on one broker do not mix).
    pub group: String,
    /// Niceness of the box processes (`nice -n`): they stand for boxes on machines of their own,
    /// so they yield to the broker and the host under test on this shared machine.
    pub boxes_nice: u8,
}

#[derive(Clone, Debug)]
pub(crate) struct Outcome {
    pub boxes: usize,
    /// Boxes connected and born before the window, and how long that took from the spawn, s.
    pub connected: usize,
    pub connect_s: f64,
    /// Summed over the box processes.
    pub sent: BoxesReport,
    /// What the host had seen at the end.
    pub seen: HostTotals,
    pub window_s: f64,
    /// Broker and host CPU over the window, % of one core.
    pub broker_cpu_pct: f64,
    pub host_cpu_pct: f64,
    /// All box processes together over the window, % of one core.
    pub boxes_cpu_pct: f64,
    /// The whole machine over the window, % of all its cores (this load and anything else).
    pub machine_busy_pct: f64,
    /// From the end of the window until the boxes finished and the host had everything (or
    /// gave up).
    pub drain_s: f64,
}

impl Outcome {
    /// Produced − received, a duplicate (a QoS 1 resend) not counted as received.
    pub(crate) fn lost(&self) -> i64 {
        self.sent.produced as i64 - (self.seen.ndata - self.seen.duplicates) as i64
    }

    pub(crate) fn latency(&self) -> LatencySummary {
        self.seen.latency
    }
}

/// A child killed on drop (a failed assertion leaves no process behind).
struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn link_args(broker: &str, group: &str, ca: Option<&Path>) -> Vec<std::ffi::OsString> {
    let mut a: Vec<std::ffi::OsString> = vec![
        "--broker".into(),
        broker.into(),
        "--group".into(),
        group.into(),
    ];
    if let Some(ca) = ca {
        a.push("--tls-ca-file".into());
        a.push(ca.into());
    }
    a
}

/// A fleet host process (`fleet_load host`) on one broker and group, its latest totals, and
/// every totals line it printed with when it was read.
pub(crate) struct HostProc {
    child: Killed,
    latest: Arc<Mutex<Vec<(Instant, HostTotals)>>>,
}

impl HostProc {
    /// Starts the host on `broker` (HOST:PORT) for `group`, printing its totals every
    /// `every_ms`, and waits until it is subscribed.
    pub(crate) fn start(
        exe: &Path,
        broker: &str,
        group: &str,
        ca: Option<&Path>,
        every_ms: u64,
    ) -> HostProc {
        let mut child = Killed(
            Command::new(exe)
                .args(["host", "--every-ms", &every_ms.to_string()])
                .args(link_args(broker, group, ca))
                .stdin(Stdio::piped())
                .stdout(Stdio::piped())
                .spawn()
                .expect("start the fleet-load host"),
        );
        let latest: Arc<Mutex<Vec<(Instant, HostTotals)>>> = Arc::default();
        let out = child.0.stdout.take().expect("piped");
        let lines = latest.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(out).lines().map_while(Result::ok) {
                let t: HostTotals = serde_json::from_str(&line).expect("a host totals line");
                lines.lock().unwrap().push((Instant::now(), t));
            }
        });
        let mut h = HostProc { child, latest };
        let start = Instant::now();
        while !h.seen().subscribed {
            assert!(
                h.child.0.try_wait().unwrap().is_none(),
                "the fleet-load host exited"
            );
            assert!(start.elapsed() < PATIENCE, "the host did not subscribe");
            std::thread::sleep(Duration::from_millis(50));
        }
        h
    }

    pub(crate) fn pid(&self) -> u32 {
        self.child.0.id()
    }

    /// The latest totals.
    pub(crate) fn seen(&self) -> HostTotals {
        self.latest
            .lock()
            .unwrap()
            .last()
            .map(|l| l.1)
            .unwrap_or_default()
    }

    /// Every totals line so far, with when it was read.
    pub(crate) fn history(&self) -> Vec<(Instant, HostTotals)> {
        self.latest.lock().unwrap().clone()
    }

    /// Restarts the host's latency from records sampled from now on.
    pub(crate) fn reset_latency(&mut self) {
        let stdin = self.child.0.stdin.as_mut().expect("piped");
        std::io::Write::write_all(stdin, b"reset\n").unwrap();
    }

    /// Waits until the host has `produced` distinct NDATA and `offline` NDEATHs (or PATIENCE);
    /// returns when it had them (or gave up).
    pub(crate) fn wait_for(&self, produced: u64, offline: usize) -> Instant {
        let done = Instant::now();
        while !(self.seen().ndata - self.seen().duplicates >= produced
            && self.seen().offline == offline)
            && done.elapsed() < PATIENCE
        {
            std::thread::sleep(Duration::from_millis(50));
        }
        let had = Instant::now();
        // One more totals line after the last record, so the latency counts every NDATA.
        std::thread::sleep(Duration::from_millis(400));
        had
    }
}

/// The box processes of one load on one broker, connected and born, waiting for `go`.
pub(crate) struct BoxProcs {
    procs: Vec<(Killed, BufReader<ChildStdout>)>,
    pub connected: usize,
}

impl BoxProcs {
    /// Spawns `load`'s box processes against `broker`, boxes numbered from `first`: one process
    /// at a time, each once the one before is connected and born (a plant's boxes do not all
    /// open their sessions in the same millisecond).
    pub(crate) fn spawn(
        exe: &Path,
        broker: &str,
        ca: Option<&Path>,
        load: &Load,
        first: usize,
    ) -> BoxProcs {
        let mut procs = Vec::with_capacity(load.procs);
        let mut connected = 0;
        for p in 0..load.procs {
            let first = (first + p * load.boxes_per_proc).to_string();
            let count = load.boxes_per_proc.to_string();
            let rate = load.rate_hz.to_string();
            let secs = load.seconds.to_string();
            let nice = load.boxes_nice.to_string();
            let mut c = Killed(
                Command::new("nice")
                    .args(["-n", &nice])
                    .arg(exe)
                    .args(["boxes", "--wait-go", "--first", &first])
                    .args(["--count", &count, "--rate-hz", &rate, "--seconds", &secs])
                    .args(link_args(broker, &load.group, ca))
                    .stdin(Stdio::piped())
                    .stdout(Stdio::piped())
                    .spawn()
                    .expect("start a fleet-load boxes process"),
            );
            let mut out = BufReader::new(c.0.stdout.take().expect("piped"));
            let mut line = String::new();
            out.read_line(&mut line).unwrap();
            let v: serde_json::Value = serde_json::from_str(&line).expect("a connected line");
            connected += v["connected"].as_u64().expect("connected: N") as usize;
            procs.push((c, out));
        }
        BoxProcs { procs, connected }
    }

    /// CPU of every box process together, clock ticks.
    pub(crate) fn ticks(&self) -> u64 {
        self.procs.iter().map(|(b, _)| cpu_ticks(b.0.id())).sum()
    }

    /// Starts every process's `--seconds`.
    pub(crate) fn go(&mut self) {
        for (b, _) in &mut self.procs {
            let go = b.0.stdin.as_mut().expect("piped");
            std::io::Write::write_all(go, b"go\n").unwrap();
        }
    }

    /// Waits for every process's report (after its window, every box finished) and sums them.
    pub(crate) fn finish(mut self) -> BoxesReport {
        let mut sent = BoxesReport::default();
        for (b, o) in &mut self.procs {
            let mut out = String::new();
            std::io::Read::read_to_string(o, &mut out).unwrap();
            let st = b.0.wait().unwrap();
            assert!(st.success(), "a fleet-load boxes process failed ({st})");
            let r: BoxesReport = serde_json::from_str(out.trim()).expect("a boxes report line");
            sent.boxes += r.boxes;
            sent.produced += r.produced;
            sent.dropped += r.dropped;
            sent.left += r.left;
        }
        sent
    }
}

/// Runs `load` with `exe` (hil-sim's `fleet_load` binary) against the broker at `broker` (HOST:PORT,
/// process `broker_pid`), over TLS with `ca`.
pub(crate) fn run(
    exe: &Path,
    broker: &str,
    broker_pid: u32,
    ca: Option<&Path>,
    load: &Load,
) -> Outcome {
    let mut host = HostProc::start(exe, broker, &load.group, ca, 200);
    // The window starts once every box is connected and born (the connect storm is not the
    // steady state; its records still count for loss and gaps).
    let spawned = Instant::now();
    let mut boxes = BoxProcs::spawn(exe, broker, ca, load, 0);
    let connect_s = spawned.elapsed().as_secs_f64();
    host.reset_latency();
    let (cpu0, host0, boxes0, m0) = (
        cpu_ticks(broker_pid),
        cpu_ticks(host.pid()),
        boxes.ticks(),
        machine_ticks(),
    );
    boxes.go();
    let t0 = Instant::now();
    std::thread::sleep(Duration::from_secs_f64(load.seconds));
    let window_s = t0.elapsed().as_secs_f64();
    // Read before the box processes exit (they finish right after their own window).
    let (cpu1, host1, boxes1, m1) = (
        cpu_ticks(broker_pid),
        cpu_ticks(host.pid()),
        boxes.ticks(),
        machine_ticks(),
    );
    let connected = boxes.connected;
    let sent = boxes.finish();
    let total = load.procs * load.boxes_per_proc;
    let had = host.wait_for(sent.produced, total);
    let drain_s = (had - t0).as_secs_f64() - window_s;
    let pct = |a: u64, b: u64| 100.0 * (b - a) as f64 / 100.0 / window_s;
    Outcome {
        boxes: total,
        sent,
        seen: host.seen(),
        window_s,
        broker_cpu_pct: pct(cpu0, cpu1),
        host_cpu_pct: pct(host0, host1),
        boxes_cpu_pct: pct(boxes0, boxes1),
        connected,
        connect_s,
        machine_busy_pct: 100.0 * (m1.0 - m0.0) as f64 / (m1.1 - m0.1).max(1) as f64,
        drain_s,
    }
}
