//! The origin-shift server (`[sink.origin_shift_server]`) against a third-party Modbus client, mbpoll,
//! over TCP on 127.0.0.1 and RTU on a socat pty pair:
//! - nothing is served until the controller wrote the held register (mbpoll gets an exception);
//! - after mbpoll writes held = 12.3 µm and a position (FC16), the server starts from 12.3 µm, the
//!   position arrives as an `x_mm` sample, and with the engine asking for 20 µm mbpoll reads 13.3 µm:
//!   one 1 µm cap from what the controller holds, however many updates pass;
//! - when the controller reports holding 13.3 µm, the next value is 14.3 µm; the heartbeat moves;
//! - writes outside the position/held registers are refused (exception), and the config validation
//!   refuses an unmapped corrected axis with the key.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, Instant};

use retrocomp_bus::{ChannelTable, Sample};
use retrocomp_gateway::SinkStatus;
use retrocomp_gateway::config::FieldConfig;
use retrocomp_gateway::sinks::guard::AxisLimits;
use retrocomp_gateway::sinks::origin_shift::{OriginShiftServer, ServerConfig, ServerTransport};
use tokio::sync::{mpsc, watch};

use crate::peers;

const MAP: &str = r#"
heartbeat_address = 1
axis = [ { axis = "x", address = 0, kind = "int16", lsb_um = 0.1, sign = 1 } ]
position = [ { channel = "x_mm", address = 10, kind = "int16", lsb_um = 10.0 } ]
held = [ { axis = "x", address = 11 } ]
"#;

fn guards() -> Vec<AxisLimits> {
    vec![AxisLimits {
        axis: "x".into(),
        max_correction_um: 50.0,
        max_change_um_per_write: 1.0,
    }]
}

fn config(transport: ServerTransport) -> ServerConfig {
    ServerConfig {
        transport,
        unit_id: 3,
        update_period_ms: 10,
        controller_timeout_ms: 1000,
        listen_policy: Default::default(),
        map: toml::from_str(MAP).unwrap(),
    }
}

/// Run mbpoll (blocking, on a thread); returns (success, stdout + stderr).
async fn mbpoll(args: Vec<String>) -> (bool, String) {
    let tool = peers::tool("mbpoll");
    tokio::task::spawn_blocking(move || {
        let o = std::process::Command::new(tool)
            .args(&args)
            .output()
            .unwrap();
        (
            o.status.success(),
            format!(
                "{}{}",
                String::from_utf8_lossy(&o.stdout),
                String::from_utf8_lossy(&o.stderr)
            ),
        )
    })
    .await
    .unwrap()
}

/// mbpoll's value for 1-based reference `reg` in its output.
fn value(out: &str, reg: u16) -> Option<i64> {
    out.lines()
        .find(|l| l.trim_start().starts_with(&format!("[{reg}]:")))
        .and_then(|l| l.split(':').nth(1))
        .and_then(|v| v.trim().parse().ok())
}

/// Read registers 0–1 (correction, heartbeat) until `pred` holds on the correction (≤ 60 s).
async fn read_until(link: &[String], pred: impl Fn(i64) -> bool) -> (i64, i64) {
    let t0 = Instant::now();
    loop {
        let mut a = link.to_vec();
        a.extend(["-t", "4", "-r", "1", "-c", "2", "-1"].map(String::from));
        a.push(link_target(link));
        let (ok, out) = mbpoll(strip_target(a)).await;
        if ok
            && let (Some(c), Some(h)) = (value(&out, 1), value(&out, 2))
            && pred(c)
        {
            return (c, h);
        }
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "last mbpoll output:\n{out}"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

// The link arguments end with the target (host or device); request options go before it.
fn link_target(link: &[String]) -> String {
    link.last().unwrap().clone()
}
fn strip_target(mut a: Vec<String>) -> Vec<String> {
    let target = a.pop().unwrap();
    let at = a.iter().rposition(|s| *s == target).unwrap();
    a.remove(at);
    a.push(target);
    a
}

/// mbpoll writes `values` with FC16 from 0-based `address`.
async fn write(link: &[String], address: u16, values: &[u16]) -> (bool, String) {
    let mut a: Vec<String> = link[..link.len() - 1].to_vec();
    a.extend(["-t", "4", "-r"].map(String::from));
    a.push((address + 1).to_string());
    a.push(link_target(link));
    a.extend(values.iter().map(|v| v.to_string()));
    mbpoll(a).await
}

async fn exercise(link: Vec<String>, transport: ServerTransport) {
    let epoch = Instant::now();
    let clock = move || epoch.elapsed().as_secs_f64();
    let mut table = ChannelTable::default();
    let mut server = OriginShiftServer::start(config(transport), &guards(), &mut table, clock())
        .await
        .unwrap();
    let link = match server.local_addr() {
        Some(addr) => {
            let mut l = link;
            l.splice(2..2, ["-p".to_string(), addr.port().to_string()]);
            l
        }
        None => link,
    };
    let (samples_tx, mut samples_rx) = mpsc::channel::<Sample>(64);

    // Not seeded: the correction register does not exist yet.
    let mut a = link[..link.len() - 1].to_vec();
    a.extend(["-t", "4", "-r", "1", "-c", "1", "-1"].map(String::from));
    a.push(link_target(&link));
    let (ok, out) = mbpoll(a).await;
    assert!(
        !ok,
        "served before the controller reported what it holds:\n{out}"
    );

    // The controller writes position 150.00 mm (15000 counts) and held 12.3 µm (123) in one FC16.
    let seed = tokio::spawn(async move {
        let held = server.wait_seeded(&samples_tx, &clock).await;
        (server, held, samples_tx)
    });
    let (ok, out) = write(&link, 10, &[15000, 123]).await;
    assert!(ok, "mbpoll FC16:\n{out}");
    let (server, held, samples_tx) = tokio::time::timeout(Duration::from_secs(60), seed)
        .await
        .expect("seeded")
        .unwrap();
    assert_eq!(held, BTreeMap::from([("x".to_string(), 12.3)]));
    let s = samples_rx.recv().await.unwrap();
    assert_eq!((table.name(s.channel), s.value), ("x_mm", 150.0));

    // The engine wants 20 µm; the controller still reports 12.3 µm: at most 13.3 µm is served.
    let (out_tx, out_rx) = watch::channel(vec![(retrocomp_model::Axis::X, 20.0)]);
    let (status_tx, status_rx) = watch::channel(SinkStatus::default());
    let (_stop_tx, stop_rx) = watch::channel(None);
    let task = tokio::spawn(server.run(out_rx, samples_tx, status_tx, stop_rx, clock));
    let (c1, h1) = read_until(&link, |c| c == 133).await;
    // Many updates later it has not run ahead of what the controller holds.
    let (c2, h2) = read_until(&link, |_| true).await;
    assert_eq!((c1, c2), (133, 133));
    assert_ne!(h1, h2, "heartbeat did not move");
    assert!(status_rx.borrow().writes_ok > 0);
    // The controller now holds 13.3 µm: the box moves one more cap.
    let (ok, out) = write(&link, 11, &[133]).await;
    assert!(ok, "{out}");
    let (c3, _) = read_until(&link, |c| c != 133).await;
    assert_eq!(c3, 143);
    // The correction and heartbeat registers are the box's: a write there is refused.
    let (ok, out) = write(&link, 0, &[999]).await;
    assert!(!ok, "write to the correction register accepted:\n{out}");
    let (c4, _) = read_until(&link, |_| true).await;
    assert!(c4 == 143, "{c4}");
    drop(out_tx);
    task.abort();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mbpoll_reads_the_served_correction_over_tcp() {
    let _turn = crate::turn::take(file!());
    let link: Vec<String> = ["-m", "tcp", "-a", "3", "127.0.0.1"]
        .map(String::from)
        .to_vec();
    exercise(
        link,
        ServerTransport::Tcp {
            listen: "127.0.0.1:0".into(),
        },
    )
    .await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mbpoll_reads_the_served_correction_over_rtu() {
    let _turn = crate::turn::take(file!());
    let dir = tempfile::tempdir().unwrap();
    let (_socat, a, b) = peers::socat_pair(dir.path());
    let link: Vec<String> = ["-m", "rtu", "-b", "19200", "-P", "none", "-a", "3"]
        .map(String::from)
        .into_iter()
        .chain([b.to_string_lossy().into_owned()])
        .collect();
    exercise(
        link,
        ServerTransport::Rtu {
            path: a.to_string_lossy().into_owned(),
            baud: 19200,
        },
    )
    .await;
}

#[test]
fn an_unmapped_corrected_axis_is_refused_with_its_key() {
    let _turn = crate::turn::take(file!());
    let base = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/deploy/linuxcnc/sim/retrocomp-sim.toml"
    ))
    .unwrap();
    FieldConfig::parse(&base, Path::new("sim.toml")).unwrap();
    // The kit's field config is valid too.
    FieldConfig::load(Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/deploy/linuxcnc/retrocomp-linuxcnc.toml"
    )))
    .unwrap();
    let z_unmapped = base.replace(
        "  { axis = \"z\", address = 2, kind = \"int16\", lsb_um = 0.1, sign = 1 },\n",
        "",
    );
    assert_ne!(z_unmapped, base);
    let e = FieldConfig::parse(&z_unmapped, Path::new("sim.toml"))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("sim.toml")
            && e.contains("sink.origin_shift_server.map.axis")
            && e.contains("z"),
        "{e}"
    );
    let overlap = base.replace("address = 13 }", "address = 10 }");
    let e = FieldConfig::parse(&overlap, Path::new("sim.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("held[0]") && e.contains("position[0]"), "{e}");
    let coarse = base.replace("lsb_um = 0.1, sign = 1", "lsb_um = 2.0, sign = 1");
    let e = FieldConfig::parse(&coarse, Path::new("sim.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("axis[0].lsb_um"), "{e}");
}
