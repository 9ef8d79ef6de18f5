//! pyserial 3.5 (a third-party writer) writes DRO and weighing-indicator lines into a socat pty pair;
//! retrocomp opens the other end with tokio-serial and parses them, counting and skipping noise.
//! Peer: tests/peers/pyserial_lines.py.

use crate::peers;

use retrocomp_bus::serial::{
    LineFormat, LineSource, SerialChannel, SerialCounters, SerialSourceConfig, open, run,
};
use retrocomp_bus::{ChannelTable, Health, Sample};
use std::time::Duration;

fn ch(name: &str, key: Option<&str>, scale: f64) -> SerialChannel {
    SerialChannel {
        name: name.into(),
        key: key.map(str::to_string),
        scale,
        offset: 0.0,
        min: None,
        max: None,
    }
}

/// Run the source on the pty until `want` non-stale samples arrived (≤ 15 s), then return them
/// with the table that names their channels.
async fn collect(
    cfg: SerialSourceConfig,
    kind: &str,
    want: usize,
) -> (Vec<Sample>, ChannelTable, SerialCounters, peers::Peer) {
    let dir = tempfile::tempdir().unwrap();
    let (socat, a, b) = peers::socat_pair(dir.path());
    let mut cfg = cfg;
    cfg.device = Some(b.to_string_lossy().into_owned());
    let port = open(&cfg).expect("open pty with tokio-serial");
    let mut table = ChannelTable::default();
    let src = LineSource::new(cfg, &mut table);
    let (tx, mut rx) = tokio::sync::mpsc::channel(64);
    let t0 = std::time::Instant::now();
    let task = tokio::spawn(run(port, src, move || t0.elapsed().as_secs_f64(), tx));
    let a = a.to_string_lossy().into_owned();
    let kind = kind.to_string();
    let writer = tokio::task::spawn_blocking(move || {
        peers::spawn_python("pyserial_lines.py", &[&a, "9600", &kind])
    })
    .await
    .unwrap();
    let mut got = Vec::new();
    let deadline = tokio::time::Instant::now() + Duration::from_secs(15);
    while got.len() < want {
        let batch = tokio::time::timeout_at(deadline, rx.recv())
            .await
            .unwrap_or_else(|_| panic!("only {} samples: {got:?}", got.len()))
            .expect("source ended early");
        got.extend(
            batch
                .into_iter()
                .filter(|s: &Sample| s.health != Health::Stale),
        );
    }
    // Closing the receiver makes `run` return its counters at the next batch; the pty then closes.
    drop(rx);
    drop(socat);
    let counters = tokio::time::timeout(Duration::from_secs(5), task)
        .await
        .expect("serial source did not stop")
        .unwrap()
        .unwrap_or_else(|e| panic!("serial source failed: {e}"));
    drop(dir);
    (got, table, counters, writer)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn parses_heidenhain_dro_lines_from_pyserial() {
    let _turn = crate::turn::take(file!());
    let cfg = SerialSourceConfig {
        name: "dro".into(),
        device: None,
        baud: 9600,
        format: LineFormat::Heidenhain { decimals: 4 },
        request: None,
        period_s: 0.05,
        timeout_s: 30.0,
        max_line: 64,
        channel: vec![
            ch("x_mm", None, 1.0),
            ch("y_mm", None, 1.0),
            ch("z_mm", None, 1.0),
        ],
    };
    let (got, table, counters, _w) = collect(cfg, "dro", 6).await;
    let v: Vec<(&str, f64)> = got
        .iter()
        .map(|s| (table.name(s.channel), s.value))
        .collect();
    assert_eq!(
        v,
        vec![
            ("x_mm", 123.45),
            ("y_mm", -0.01),
            ("z_mm", 1.0),
            ("x_mm", 0.0001),
            ("y_mm", 0.0002),
            ("z_mm", 0.0003)
        ]
    );
    assert!(
        counters.garbage_lines >= 2,
        "noise and the cut line are counted: {counters:?}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn parses_weighing_indicator_lines_from_pyserial() {
    let _turn = crate::turn::take(file!());
    const G: f64 = 9.80665;
    let cfg = SerialSourceConfig {
        name: "scale".into(),
        device: None,
        baud: 9600,
        format: LineFormat::Weighing {
            unit: Some("kg".into()),
            accept_unstable: false,
        },
        request: None,
        period_s: 0.05,
        timeout_s: 30.0,
        max_line: 64,
        channel: vec![ch("F_gross_N", Some("GS"), G), ch("F_net_N", Some("NT"), G)],
    };
    let (got, table, counters, _w) = collect(cfg, "weighing", 4).await;
    assert_eq!(counters.unstable_skipped, 1, "{counters:?}");
    assert!(
        counters.garbage_lines >= 1,
        "`#####` is counted: {counters:?}"
    );
    let v: Vec<(&str, Health)> = got
        .iter()
        .map(|s| (table.name(s.channel), s.health))
        .collect();
    assert_eq!(
        v,
        vec![
            ("F_gross_N", Health::Ok),
            ("F_net_N", Health::Ok),
            ("F_gross_N", Health::OutOfRange),
            ("F_gross_N", Health::Ok)
        ]
    );
    assert!((got[0].value - 10.25 * G).abs() < 1e-9);
    assert!((got[3].value - 10.5 * G).abs() < 1e-9);
}
