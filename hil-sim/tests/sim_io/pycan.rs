//! A third-party CAN peer, python-can 4.6.1 (socketcand interface), receives the simulator's CiA 406
//! encoder TPDOs and CiA 404 temperatures through a socketcand hub. The peer is the bus layer's script
//! `tests/peers/pycan_socketcand.py`, run with `<repo>/.venv/bin/python`; a missing venv FAILS the
//! test: run scripts/setup-peers.sh.

use hil_sim::SimConfig;
use hil_sim::io::serve::start;
use retrocomp_bus::can::Hub;
use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::time::Duration;

struct Kill(std::process::Child);
impl Drop for Kill {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn python_can_receives_encoder_and_temperature_tpdos() {
    let repo = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let python = repo.join(".venv/bin/python");
    assert!(
        python.exists(),
        "{} is missing: run scripts/setup-peers.sh",
        python.display()
    );
    let hub = Hub::start_loopback().await.unwrap();
    let port = hub.local_addr().port();
    let n = 150;
    let mut child = Command::new(&python)
        .arg(repo.join("tests/peers/pycan_socketcand.py"))
        .args(["127.0.0.1", &port.to_string(), &n.to_string()])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("start python-can peer");
    let stdout = child.stdout.take().unwrap();
    let _peer = Kill(child);
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for l in BufReader::new(stdout).lines().map_while(Result::ok) {
            if tx.send(l).is_err() {
                break;
            }
        }
    });
    let ready = rx
        .recv_timeout(Duration::from_secs(20))
        .expect("python-can peer printed nothing");
    assert_eq!(ready, "READY");
    let toml = format!(
        r#"
[clock]
realtime = true
[program]
script = [{{ t_s = 0.0, x_mm = 50.0, y_mm = 20.0, z_mm = 1.0 }}, {{ t_s = 1.0, x_mm = 60.0, y_mm = 20.0, z_mm = 1.0 }}, {{ t_s = 3.0, x_mm = 60.0, y_mm = 20.0, z_mm = 1.0 }}]
[hidden.thermal]
ambient_C = 21.5
nodes = [{{ name = "spindle", tau_s = 100.0, start_C = 23.4 }}]
sensors = [{{ name = "spindle", node = "spindle" }}, {{ name = "room", node = "ambient" }}]
[io.can]
backend = "socketcand"
host = "127.0.0.1"
port = {port}
channel = "can0"
encoder_period_s = 0.01
temp_node = 10
temp_period_s = 0.05
"#
    );
    let running = start(SimConfig::from_toml_str(&toml, None).unwrap(), None, None)
        .await
        .unwrap();
    let lines = tokio::task::spawn_blocking(move || {
        let mut v = Vec::new();
        while let Ok(l) = rx.recv_timeout(Duration::from_secs(10)) {
            let done = l == "DONE";
            v.push(l);
            if done {
                break;
            }
        }
        v
    })
    .await
    .unwrap();
    running.abort();
    assert_eq!(lines.last().map(String::as_str), Some("DONE"), "{lines:?}");
    let data = |id: &str| -> Vec<String> {
        lines
            .iter()
            .filter_map(|l| l.strip_prefix(&format!("RX {id} 0 ")).map(String::from))
            .collect()
    };
    let xs: Vec<u32> = data("181")
        .iter()
        .map(|h| {
            u32::from_str_radix(
                &format!("{}{}{}{}", &h[6..8], &h[4..6], &h[2..4], &h[0..2]),
                16,
            )
            .unwrap()
        })
        .collect();
    assert!(xs.len() > 20, "x TPDOs: {lines:?}");
    assert!(
        xs.iter().all(|c| (49_990..=60_010).contains(c)),
        "x counts in mm·1000: {xs:?}"
    );
    assert!(xs.windows(2).any(|w| w[1] > w[0]), "x moves");
    assert!(
        data("182").iter().all(|h| h == "204e0000"),
        "y = 20 mm = 20000 counts, LE"
    );
    assert!(
        data("18A").iter().any(|h| h == "ea00d700"),
        "CiA 404 INT16 0.1 °C: 23.4, 21.5"
    );
}
