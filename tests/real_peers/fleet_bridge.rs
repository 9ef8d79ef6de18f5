//! The fleet past one broker: two Mosquitto brokers joined by Mosquitto's own bridge, boxes on
//! each, the fleet host on the central one, and the bridge link broken and restored mid-run.
//!
//! - Broker C (central) and broker H (hall), plain TCP on loopback. H carries the bridge to C,
//!   through a `socat` TCP proxy this test can cut (kill) and restore: H's boxes stay connected to
//!   H throughout, so what the outage exercises is the bridge's own queue on H (the bridge is a
//!   persistent client of H, `cleansession false`: H queues its records for it while the link is
//!   down and sends them, in order, once it is up).
//! - Box processes (`fleet_load boxes`, 10 Hz) on each broker, one Sparkplug group per broker so
//!   the host's figures say which side a record came from; one fleet host process per group, both
//!   on C (`fleet_load host`: the MQTT client and view of `retrocomp fleet`).
//! - After the boxes finish, each host has every record its boxes produced (a QoS 1 resend, seq
//!   equal to the one before, is counted apart as a duplicate), no seq gap, and every NDEATH.
//!   The outage is proved twice: C's retained bridge notification
//!   (`$SYS/broker/connection/<remote_clientid>/state`) went 1 → 0 → 1, and the host saw no NDATA
//!   from H's boxes for at least half the cut while records from C's boxes kept arriving.
//!
//! - Rebirth across the bridge (`fleet_bridge_rebirth.rs`, on the same brokers).
//!
//! Every wait ends on an event with a deadline only a broken path reaches. Times s and ms;
//! latency ms (host arrival − the NDATA's Sparkplug timestamp); CPU % of one core.

use crate::fleet_processes::{BoxProcs, HostProc, Load, cpu_ticks, machine_ticks};
use crate::hil_sim;
use crate::mosquitto::Broker;
use crate::peers::{free_port, tool};

use std::os::unix::process::CommandExt as _;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use retrocomp_fleet::load::{BoxesReport, HostTotals};

pub(crate) const PATIENCE: Duration = Duration::from_secs(180);
/// How long the bridge link is cut.
const CUT: Duration = Duration::from_secs(3);
/// The bridge's client id on C, hence its notification topic there.
const BRIDGE_ID: &str = "bridge-hall-1";

/// A `socat` TCP proxy 127.0.0.1:`listen` → 127.0.0.1:`to` (one process per connection, all in
/// one process group, so a cut ends every connection through it at once).
struct Proxy {
    child: Option<Child>,
    listen: u16,
    to: u16,
}

impl Proxy {
    fn start(listen: u16, to: u16) -> Proxy {
        let mut p = Proxy {
            child: None,
            listen,
            to,
        };
        p.restore();
        p
    }

    fn restore(&mut self) {
        let child = Command::new(tool("socat"))
            .arg(format!(
                "TCP-LISTEN:{},bind=127.0.0.1,reuseaddr,fork",
                self.listen
            ))
            .arg(format!("TCP:127.0.0.1:{}", self.to))
            .process_group(0)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start socat (scripts/setup-peers.sh installs it)");
        self.child = Some(child);
    }

    /// Kills the proxy's process group: the listener and every connection through it.
    fn cut(&mut self) {
        if let Some(mut c) = self.child.take() {
            let _ = Command::new("kill")
                .args(["-KILL", "--", &format!("-{}", c.id())])
                .status();
            let _ = c.wait();
        }
    }
}

impl Drop for Proxy {
    fn drop(&mut self) {
        self.cut();
    }
}

/// The bridge notifications C publishes (`$SYS/broker/connection/+/state`: "1" up, "0" down),
/// with when each arrived.
type Notes = Arc<Mutex<Vec<(Instant, String)>>>;

fn watch_bridge_state(port: u16) -> Notes {
    use rumqttc::{Client, Event, MqttOptions, Packet, QoS};
    let notes: Notes = Arc::default();
    let (client, mut conn) = Client::new(MqttOptions::new("bridge-watch", "127.0.0.1", port), 64);
    client
        .subscribe("$SYS/broker/connection/+/state", QoS::AtLeastOnce)
        .unwrap();
    let seen = notes.clone();
    std::thread::spawn(move || {
        let _client = client;
        for ev in conn.iter() {
            match ev {
                Ok(Event::Incoming(Packet::Publish(p))) => {
                    let s = String::from_utf8_lossy(&p.payload).to_string();
                    seen.lock().unwrap().push((Instant::now(), s));
                }
                Ok(_) => {}
                Err(_) => std::thread::sleep(Duration::from_millis(100)),
            }
        }
    });
    notes
}

pub(crate) fn wait_until(what: &str, f: impl Fn() -> bool) {
    let deadline = Instant::now() + PATIENCE;
    while !f() {
        assert!(Instant::now() < deadline, "{what}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// H's config after its listener: the bridge to C through `proxy`. Box data goes out to C; the
/// host's NCMD rebirth requests (and a primary host's STATE) come in from C, so a box on H
/// answers a host on C. Direction per topic rather than `both`, so C's own boxes' data does not
/// travel to H and back.
fn bridge_section(proxy: u16) -> String {
    format!(
        "allow_anonymous true\n\
         connection hall-to-central\n\
         address 127.0.0.1:{proxy}\n\
         remote_clientid {BRIDGE_ID}\n\
         cleansession false\n\
         restart_timeout 1\n\
         topic spBv1.0/+/NBIRTH/# out 1\n\
         topic spBv1.0/+/NDATA/# out 1\n\
         topic spBv1.0/+/NDEATH/# out 1\n\
         topic spBv1.0/+/NCMD/# in 1\n\
         topic spBv1.0/STATE/# in 1\n"
    )
}

/// What the link does mid-run.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Outage {
    None,
    /// The proxy is killed and started again `CUT` later.
    CutLink,
    /// As `CutLink`, and broker H is stopped gracefully (SIGTERM) and started again while the
    /// link is cut: what its bridge queued so far must survive in its persistence file.
    CutLinkAndRestartHall,
}

/// One side's figures: what its boxes sent and what its host saw.
#[derive(Debug)]
struct Side {
    sent: BoxesReport,
    connected: usize,
    seen: HostTotals,
    history: Vec<(Instant, HostTotals)>,
    host_cpu_pct: f64,
    broker_cpu_pct: f64,
}

impl Side {
    fn received(&self) -> u64 {
        self.seen.ndata - self.seen.duplicates
    }
}

#[derive(Debug)]
struct Run {
    c: Side,
    h: Side,
    window_s: f64,
    machine_busy_pct: f64,
    /// When the link was cut and restored.
    cut: Option<(Instant, Instant)>,
    notes: Vec<(Instant, String)>,
}

/// Brokers C and H, the proxy between H's bridge and C, and C's bridge notifications.
pub(crate) struct Brokers {
    c: Broker,
    h: Broker,
    proxy: Proxy,
    notes: Notes,
    /// Client ports of C and H.
    pub(crate) ports: (u16, u16),
    h_log: std::path::PathBuf,
    _dir: tempfile::TempDir,
}

impl Brokers {
    /// Starts C, the proxy and H, and waits until C says the bridge is up.
    pub(crate) fn start() -> Brokers {
        let dir = tempfile::tempdir().unwrap();
        let (dc, dh) = (dir.path().join("c"), dir.path().join("h"));
        std::fs::create_dir_all(&dc).unwrap();
        std::fs::create_dir_all(&dh).unwrap();
        let (pc, ph, pp) = (free_port(), free_port(), free_port());
        let c = Broker::start_conf(
            &dc,
            pc,
            "persistence false\nlog_dest none\nmax_queued_messages 1000000\n",
            "allow_anonymous true\n",
        );
        let proxy = Proxy::start(pp, pc);
        let notes = watch_bridge_state(pc);
        let h_log = dh.join("mosquitto.log");
        // NBIRTH is QoS 0 (Sparkplug): queued for the bridge during an outage only with
        // queue_qos0_messages. One message in flight per client (H's only busy outgoing client
        // is the bridge): with Mosquitto's default 20 the resends after a reconnect once
        // overtook a queued NDATA of the same box (3 seq gaps, nothing lost); 1 is what its
        // manual names for in-order delivery, which Sparkplug's seq needs.
        let h = Broker::start_conf(
            &dh,
            ph,
            &format!(
                "persistence true\npersistence_location {}/\nlog_dest file {}\n\
                 log_type error\nlog_type warning\nlog_type notice\nlog_type information\n\
                 max_queued_messages 1000000\nqueue_qos0_messages true\n\
                 max_inflight_messages 1\n",
                dh.display(),
                h_log.display()
            ),
            &bridge_section(pp),
        );
        let up = |n: &Notes| n.lock().unwrap().last().is_some_and(|l| l.1 == "1");
        wait_until("the bridge never came up", || up(&notes));
        Brokers {
            c,
            h,
            proxy,
            notes,
            ports: (pc, ph),
            h_log,
            _dir: dir,
        }
    }

    /// Cuts the link for `CUT` (restarting H meanwhile if asked); returns when it was cut and
    /// restored.
    fn outage(&mut self, outage: Outage) -> (Instant, Instant) {
        let down = Instant::now();
        self.proxy.cut();
        if outage == Outage::CutLinkAndRestartHall {
            std::thread::sleep(CUT / 3);
            self.h.stop();
            self.h.restart();
            eprintln!(
                "broker H restarted {:.2} s after the cut",
                down.elapsed().as_secs_f64()
            );
        }
        std::thread::sleep(CUT.saturating_sub(down.elapsed()));
        self.proxy.restore();
        (down, Instant::now())
    }

    /// H's log lines about its bridge.
    fn print_bridge_log(&self) {
        if let Ok(log) = std::fs::read_to_string(&self.h_log) {
            for l in log
                .lines()
                .filter(|l| l.contains("Connecting bridge") || l.contains("local.bridge-hall-1"))
            {
                eprintln!("broker H: {l}");
            }
        }
    }
}

/// Runs `load` on each broker (groups `<group>-c` and `<group>-h`) with `outage` a third into
/// the window.
fn run(load: &Load, outage: Outage) -> Run {
    let exe = hil_sim::fleet_load_next_to_retrocomp();
    let mut b = Brokers::start();
    let (bc, bh) = (
        format!("127.0.0.1:{}", b.ports.0),
        format!("127.0.0.1:{}", b.ports.1),
    );
    let (gc, gh) = (format!("{}-c", load.group), format!("{}-h", load.group));
    let mut host_c = HostProc::start(&exe, &bc, &gc, None, 50);
    let mut host_h = HostProc::start(&exe, &bc, &gh, None, 50);
    let lc = Load {
        group: gc,
        ..load.clone()
    };
    let lh = Load {
        group: gh,
        ..load.clone()
    };
    let mut boxes_c = BoxProcs::spawn(&exe, &bc, None, &lc, 0);
    let mut boxes_h = BoxProcs::spawn(&exe, &bh, None, &lh, 10_000);
    host_c.reset_latency();
    host_h.reset_latency();
    // Broker H's CPU is of its first process (only the run without an outage reports it).
    let (c_pid, h_pid) = (b.c.pid(), b.h.pid());
    let ticks = || {
        (
            cpu_ticks(c_pid),
            cpu_ticks(h_pid),
            cpu_ticks(host_c.pid()),
            cpu_ticks(host_h.pid()),
            machine_ticks(),
        )
    };
    let t0s = ticks();
    boxes_c.go();
    boxes_h.go();
    let t0 = Instant::now();
    let window = Duration::from_secs_f64(load.seconds);
    let mut cut = None;
    if outage != Outage::None {
        std::thread::sleep(window / 3);
        cut = Some(b.outage(outage));
    }
    std::thread::sleep(window.saturating_sub(t0.elapsed()));
    let window_s = t0.elapsed().as_secs_f64();
    let t1s = ticks();
    let (connected_c, connected_h) = (boxes_c.connected, boxes_h.connected);
    let (sent_c, sent_h) = (boxes_c.finish(), boxes_h.finish());
    let n = load.procs * load.boxes_per_proc;
    host_c.wait_for(sent_c.produced, n);
    host_h.wait_for(sent_h.produced, n);
    b.print_bridge_log();
    // Clock ticks are 1/100 s: ticks / window_s is % of one core.
    let pct = |a: u64, b: u64| (b - a) as f64 / window_s;
    let side = |sent, connected, host: &HostProc, host_cpu, broker_cpu| Side {
        sent,
        connected,
        seen: host.seen(),
        history: host.history(),
        host_cpu_pct: host_cpu,
        broker_cpu_pct: broker_cpu,
    };
    Run {
        c: side(
            sent_c,
            connected_c,
            &host_c,
            pct(t0s.2, t1s.2),
            pct(t0s.0, t1s.0),
        ),
        h: side(
            sent_h,
            connected_h,
            &host_h,
            pct(t0s.3, t1s.3),
            pct(t0s.1, t1s.1),
        ),
        window_s,
        machine_busy_pct: 100.0 * (t1s.4.0 - t0s.4.0) as f64 / (t1s.4.1 - t0s.4.1).max(1) as f64,
        cut,
        notes: b.notes.lock().unwrap().clone(),
    }
}

/// The longest stretch in `history` with no new NDATA, inside `[from, to]`: (start, end).
fn longest_stall(
    history: &[(Instant, HostTotals)],
    from: Instant,
    to: Instant,
) -> (Instant, Instant) {
    let mut best = (from, from);
    let mut since = None::<(Instant, u64)>;
    for &(t, tot) in history.iter().filter(|(t, _)| *t >= from && *t <= to) {
        match since {
            Some((s, n)) if tot.ndata == n => {
                if t - s > best.1 - best.0 {
                    best = (s, t);
                }
            }
            _ => since = Some((t, tot.ndata)),
        }
    }
    best
}

fn ndata_at(history: &[(Instant, HostTotals)], t: Instant) -> u64 {
    history
        .iter()
        .take_while(|(at, _)| *at <= t)
        .last()
        .map_or(0, |l| l.1.ndata)
}

fn assert_everything_arrived(s: &Side, boxes: usize) {
    assert_eq!((s.sent.boxes, s.connected), (boxes, boxes), "{s:?}");
    assert!(s.sent.produced >= boxes as u64, "{:?}", s.sent);
    // Not `gaps == 0`: a bridge's resend after its reconnect can overtake a queued record of the
    // same box even with one message in flight (seen once in a loaded run: seq 5, 7, 6, 8). That
    // record is reordered, not lost, as a Sparkplug host with a reorder timeout takes it; a seq
    // never seen is lost.
    assert_eq!(
        (s.received(), s.sent.dropped, s.sent.left, s.seen.lost),
        (s.sent.produced, 0, 0, 0),
        "produced, dropped, left, lost seqs: {:?} {:?}",
        s.sent,
        s.seen
    );
    assert_eq!(
        (s.seen.nodes, s.seen.offline),
        (boxes, boxes),
        "{:?}",
        s.seen
    );
}

#[test]
fn boxes_on_two_bridged_brokers_lose_nothing_through_a_bridge_link_cut() {
    let _turn = crate::turn::take(file!());
    through_an_outage("bridge-cut", Outage::CutLink);
}

/// Fails with Mosquitto 2.0.11 (Debian 12): with its default `max_inflight_messages 20`, after
/// broker H's restart from its persistence file, 10 of the records its bridge had queued (one per box) never crossed the bridge — in a run
/// with H's `log_type all`, the bridge sent message ids 413–432 after the restart, then 443
/// onwards: ids 433–442 appear nowhere in the log. With `max_inflight_messages 1` (the config
/// here) the bridge reconnected after the restart but nothing more of H's boxes reached the host
/// (432 of 1210 records, no NDEATH) within the patience. Kept to rerun against
/// another broker version; docs/fleet.md says what this means for a hall broker's restart.
#[test]
#[ignore = "Mosquitto 2.0.11 loses or stalls a bridge's restored queue (docs/fleet.md): cargo test --test real_peers fleet_bridge:: -- --ignored"]
fn boxes_on_two_bridged_brokers_lose_nothing_when_the_hall_broker_restarts_during_a_cut() {
    let _turn = crate::turn::take(file!());
    through_an_outage("bridge-restart", Outage::CutLinkAndRestartHall);
}

/// Runs 2 × 5 boxes per broker through `outage` and checks that everything arrived, and that
/// the outage happened.
fn through_an_outage(group: &str, outage: Outage) {
    let load = Load {
        procs: 2,
        boxes_per_proc: 5,
        rate_hz: 10.0,
        seconds: 12.0,
        group: group.into(),
        boxes_nice: 0,
    };
    let r = run(&load, outage);
    for (name, s) in [("C", &r.c), ("H", &r.h)] {
        eprintln!(
            "{name}: sent {:?}, host saw {} NDATA ({} duplicates), {} gaps ({} reordered, {} lost), {}/{} NDEATHs, latency {:?}",
            s.sent,
            s.seen.ndata,
            s.seen.duplicates,
            s.seen.gaps,
            s.seen.reordered,
            s.seen.lost,
            s.seen.offline,
            s.seen.nodes,
            s.seen.latency
        );
    }
    let boxes = load.procs * load.boxes_per_proc;
    assert_everything_arrived(&r.c, boxes);
    assert_everything_arrived(&r.h, boxes);

    // The outage, as Mosquitto says it: the bridge's notification on C went to 0 after the cut
    // and back to 1 after the restore.
    let (down, restored) = r.cut.unwrap();
    let states: Vec<(f64, &str)> = r
        .notes
        .iter()
        .map(|(t, s)| (t.saturating_duration_since(down).as_secs_f64(), s.as_str()))
        .collect();
    eprintln!("bridge state on C (s after the cut, state): {states:?}");
    let zero = r.notes.iter().position(|(t, s)| *t >= down && s == "0");
    let zero = zero.expect("C never said the bridge was down");
    assert!(
        r.notes[zero..]
            .iter()
            .any(|(t, s)| *t >= restored && s == "1"),
        "C never said the bridge was up again: {states:?}"
    );
    // And as the host saw it: no NDATA from H's boxes for at least half the cut, while records
    // from C's boxes kept arriving meanwhile.
    let end = restored + PATIENCE;
    let (s0, s1) = longest_stall(&r.h.history, down - CUT / 2, end);
    eprintln!(
        "host: no NDATA from H's boxes for {:.2} s, from {:.2} s after the cut; {} from C's meanwhile",
        (s1 - s0).as_secs_f64(),
        s0.saturating_duration_since(down).as_secs_f64(),
        ndata_at(&r.c.history, s1) - ndata_at(&r.c.history, s0)
    );
    assert!(s1 - s0 >= CUT / 2, "the host's view of H never stalled");
    assert!(
        ndata_at(&r.c.history, s1) > ndata_at(&r.c.history, s0),
        "C's records stopped too"
    );
    // Records sampled during the cut were held (by the bridge) and arrived late, not dropped.
    assert!(
        r.h.seen.latency.max_ms >= Some(CUT.as_millis() as u64 / 2),
        "{:?}",
        r.h.seen.latency
    );
}

/// The figures of a bigger load through the bridge with no outage (not a pass/fail test):
/// `FLEET_BRIDGE_LOAD=PxK` per broker (default 2x100), `FLEET_BRIDGE_SECONDS` (default 30),
/// box processes at nice 10 as in benches/fleet_processes.rs.
#[test]
#[ignore = "a measurement: cargo test --test real_peers fleet_bridge::figures -- --ignored --nocapture"]
fn figures_of_boxes_on_two_bridged_brokers() {
    let _turn = crate::turn::take(file!());
    let pk = std::env::var("FLEET_BRIDGE_LOAD").unwrap_or_else(|_| "2x100".into());
    let (p, k) = pk.split_once('x').expect("FLEET_BRIDGE_LOAD=PxK");
    let seconds = std::env::var("FLEET_BRIDGE_SECONDS").map_or(30.0, |s| s.parse().unwrap());
    let load = Load {
        procs: p.parse().unwrap(),
        boxes_per_proc: k.parse().unwrap(),
        rate_hz: 10.0,
        seconds,
        group: "bridge-load".into(),
        boxes_nice: 10,
    };
    let r = run(&load, Outage::None);
    println!(
        "{pk} per broker at 10 Hz, {:.1} s window, machine {:.0} % busy",
        r.window_s, r.machine_busy_pct
    );
    for (name, s) in [("C (direct)", &r.c), ("H (bridged)", &r.h)] {
        println!(
            "{name}: produced {} ({:.0}/s), received {}, duplicates {}, dropped {}, left {}, gaps {}, NDEATHs {}/{}, latency p50/p99/max {:?}/{:?}/{:?} ms, broker {:.0} %, host {:.0} %",
            s.sent.produced,
            s.sent.produced as f64 / r.window_s,
            s.received(),
            s.seen.duplicates,
            s.sent.dropped,
            s.sent.left,
            s.seen.gaps,
            s.seen.offline,
            s.seen.nodes,
            s.seen.latency.p50_ms,
            s.seen.latency.p99_ms,
            s.seen.latency.max_ms,
            s.broker_cpu_pct,
            s.host_cpu_pct,
        );
    }
}
