//! Fleet load with every box in a separate OS process, over TLS (not criterion: a capacity
//! search). One Mosquitto on loopback with a TLS-only listener (a CA and server certificate made
//! with openssl), one fleet host process (hil-sim's `fleet_load host`: the MQTT client and view of
//! `retrocomp fleet`), and P box processes of K boxes each (`fleet_load boxes`: the real
//! Sparkplug publisher per box, QoS 1, each box's own TLS session), at R Hz for S seconds.
//! The path and the counting are tests/peers/fleet_processes.rs (also run, tiny, by
//! tests/real_peers/telemetry_fleet_host.rs).
//!
//! Per step, reported: records/s, produced, received, lost (produced − received), dropped (by the
//! boxes' full queues), left (unsent at the end), seq gaps, nodes, NDEATHs seen, end-to-end
//! latency p50/p99/max (ms: host arrival − the NDATA's Sparkplug timestamp, i.e. from when the box
//! sampled the record; ±1 ms), broker, host and all box processes' CPU (% of one core,
//! /proc/PID/stat over the window), the whole machine's busy share (% of all cores: this load plus anything else running)
//! the drain time (window end → every box finished and the host had everything) and the connect
//! time (spawn → every box connected and born: the window and the latency start there, so the
//! connect storm of P × K TLS handshakes is not counted as steady state; its records still count
//! for loss and gaps).
//!
//! **Saturated** (the broker, or this machine, cannot carry the step) when any of: a box not
//! connected within 120 s, a record lost,
//! dropped or left, a seq gap; the broker ≥ 90 % of a core (Mosquitto is single-threaded); latency
//! p99 ≥ 1,000 ms (ten sampling periods at 10 Hz: records queue faster than they leave).
//! With `--until-saturated` the box count keeps growing by `--step-procs` processes after the
//! given steps until a step is saturated.
//!
//! Run: `cargo bench --profile test --bench fleet_processes -- 20x100 --seconds 60`
//! (`PxK`: P processes of K boxes; `--rate-hz R`, default 10; `--exe PATH`: another build of
//! hil-sim's `fleet_load`, e.g. target/release/fleet_load; `--max-queued N|default`: the broker's
//! `max_queued_messages`, default 1000000 as docs/fleet.md advises for a fleet; `--max-inflight
//! N|default`: its `max_inflight_messages`, default Mosquitto's 20; `--boxes-nice N`:
//! the box processes' niceness, default 10 — they stand for boxes on machines of their own, so on
//! this shared machine they yield to the broker and the host under test). Needs mosquitto and openssl: scripts/setup-peers.sh.

#[path = "../tests/peers/fleet_processes.rs"]
mod fleet_processes;
#[path = "../tests/gateway_support/hil_sim.rs"]
mod hil_sim;
#[path = "../tests/peers/mosquitto.rs"]
mod mosquitto;
#[path = "../tests/peers/mod.rs"]
mod peers;

use std::path::PathBuf;

use fleet_processes::{Load, Outcome};

/// Why a step is saturated, or None.
fn saturated(o: &Outcome) -> Option<String> {
    let mut why = Vec::new();
    if o.connected < o.boxes {
        why.push(format!("{} of {} boxes connected", o.connected, o.boxes));
    }
    if o.lost() != 0 || o.sent.dropped > 0 || o.sent.left > 0 || o.seen.gaps > 0 {
        why.push("records lost".to_string());
    }
    if o.broker_cpu_pct >= 90.0 {
        why.push(format!("broker {:.0} % of a core", o.broker_cpu_pct));
    }
    if o.latency().p99_ms.is_none_or(|p| p >= 1000) {
        why.push("p99 ≥ 1 s".to_string());
    }
    (!why.is_empty()).then(|| why.join(", "))
}

fn ms(v: Option<u64>) -> String {
    v.map_or("-".into(), |v| v.to_string())
}

fn print_row(load: &Load, o: &Outcome) {
    println!(
        "{:>5} {:>5} {:>6} {:>7.1} {:>9.0} {:>9} {:>9} {:>5} {:>7} {:>5} {:>5} {:>5} {:>6} {:>6} {:>6} {:>6} {:>8.0}% {:>6.0}% {:>6.0}% {:>7.0}% {:>7.1} {:>9.1}  {}",
        load.procs,
        load.boxes_per_proc,
        o.boxes,
        load.rate_hz,
        o.sent.produced as f64 / o.window_s,
        o.sent.produced,
        o.seen.ndata,
        o.lost(),
        o.sent.dropped,
        o.sent.left,
        o.seen.gaps,
        o.seen.nodes,
        o.seen.offline,
        ms(o.latency().p50_ms),
        ms(o.latency().p99_ms),
        ms(o.latency().max_ms),
        o.broker_cpu_pct,
        o.host_cpu_pct,
        o.boxes_cpu_pct,
        o.machine_busy_pct,
        o.drain_s,
        o.connect_s,
        saturated(o).map_or("ok".to_string(), |w| format!("SATURATED: {w}")),
    );
}

fn main() {
    let mut steps: Vec<(usize, usize)> = Vec::new();
    let (mut seconds, mut rate_hz) = (60.0, 10.0);
    let mut exe: Option<PathBuf> = None;
    let (mut until_saturated, mut step_procs) = (false, 10);
    // Box processes stand for boxes on machines of their own: they yield to the broker and host.
    let mut boxes_nice = 10;
    // The fleet setting of docs/fleet.md ("Broker setting for a fleet"): room for the host's
    // backlog, instead of Mosquitto's default 1000 per client.
    let mut max_queued: Option<u64> = Some(1_000_000);
    // QoS 1 messages in flight to one client (Mosquitto's default 20): the broker → host leg waits
    // for the host's PUBACK every 20 messages, a wake-up of both processes on a busy machine.
    let mut max_inflight: Option<u64> = None;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        let mut value = |name: &str| {
            args.next()
                .unwrap_or_else(|| panic!("{name} needs a value"))
        };
        match a.as_str() {
            "--seconds" => seconds = value("--seconds").parse().expect("--seconds S"),
            "--rate-hz" => rate_hz = value("--rate-hz").parse().expect("--rate-hz R"),
            "--exe" => exe = Some(value("--exe").into()),
            "--until-saturated" => until_saturated = true,
            "--boxes-nice" => {
                boxes_nice = value("--boxes-nice").parse().expect("--boxes-nice 0..19");
            }
            "--max-inflight" => {
                let v = value("--max-inflight");
                max_inflight =
                    (v != "default").then(|| v.parse().expect("--max-inflight N|default"));
            }
            "--max-queued" => {
                let v = value("--max-queued");
                max_queued = (v != "default").then(|| v.parse().expect("--max-queued N|default"));
            }
            "--step-procs" => step_procs = value("--step-procs").parse().expect("--step-procs N"),
            _ => {
                if let Some((p, k)) = a.split_once('x')
                    && let (Ok(p), Ok(k)) = (p.parse(), k.parse())
                {
                    steps.push((p, k));
                }
                // Other arguments (`--bench` from cargo) are ignored.
            }
        }
    }
    if steps.is_empty() {
        steps = vec![(20, 100)];
    }
    let exe = exe.unwrap_or_else(hil_sim::fleet_load_next_to_retrocomp);
    let dir = tempfile::tempdir().unwrap();
    let port = peers::free_port();
    let (broker, ca) = mosquitto::Broker::start_tls(
        dir.path(),
        port,
        &format!(
            "{}{}",
            max_queued.map_or(String::new(), |n| format!("max_queued_messages {n}\n")),
            max_inflight.map_or(String::new(), |n| format!("max_inflight_messages {n}\n"))
        ),
    );
    let addr = format!("127.0.0.1:{port}");
    println!(
        "fleet_processes: one mosquitto (TLS listener, max_queued_messages {}, max_inflight_messages {}), one host process, {seconds} s per step, {} ({} cores)",
        max_queued.map_or("default".to_string(), |n| n.to_string()),
        max_inflight.map_or("default".to_string(), |n| n.to_string()),
        exe.display(),
        std::thread::available_parallelism().map_or(0, usize::from)
    );
    println!(
        "{:>5} {:>5} {:>6} {:>7} {:>9} {:>9} {:>9} {:>5} {:>7} {:>5} {:>5} {:>5} {:>6} {:>6} {:>6} {:>6} {:>9} {:>7} {:>7} {:>8} {:>7} {:>9}  verdict",
        "procs",
        "boxes",
        "total",
        "rate_Hz",
        "records/s",
        "produced",
        "received",
        "lost",
        "dropped",
        "left",
        "gaps",
        "nodes",
        "deaths",
        "p50_ms",
        "p99_ms",
        "max_ms",
        "broker",
        "host",
        "boxes",
        "machine",
        "drain_s",
        "connect_s"
    );
    let mut n = 0;
    let mut run = |procs: usize, k: usize| {
        n += 1;
        let load = Load {
            procs,
            boxes_per_proc: k,
            rate_hz,
            seconds,
            group: format!("load-{n}"),
            boxes_nice,
        };
        let o = fleet_processes::run(&exe, &addr, broker.pid(), Some(&ca), &load);
        print_row(&load, &o);
        saturated(&o).is_some()
    };
    let mut last = (0, 100);
    let mut sat = false;
    for (p, k) in steps {
        sat = run(p, k);
        last = (p, k);
    }
    while until_saturated && !sat {
        last.0 += step_procs;
        sat = run(last.0, last.1);
    }
}
