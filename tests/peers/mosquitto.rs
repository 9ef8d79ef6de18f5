//! A Mosquitto child for the MQTT tests: loopback only, anonymous, no persistence, started from a
//! generated config on a given port (never the system service); killed on drop. Shared by
//! `telemetry_mqtt.rs` and `telemetry_fleet_drift.rs` (each includes it with `#[path]` beside
//! `mod peers;`).
#![allow(dead_code)]

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::peers::tool;

/// How long a starting broker may take to listen; only a broken install reaches it.
const LISTEN_PATIENCE: Duration = Duration::from_secs(120);

pub(crate) struct Broker(Child);

impl Broker {
    pub(crate) fn start(dir: &Path, port: u16) -> Broker {
        let conf = dir.join("mosquitto.conf");
        std::fs::write(
            &conf,
            format!(
                "listener {port} 127.0.0.1\nallow_anonymous true\npersistence false\nlog_dest none\n"
            ),
        )
        .unwrap();
        // Debian installs it in /usr/sbin, which a user's PATH may lack.
        let exe = if Path::new("/usr/sbin/mosquitto").is_file() {
            "/usr/sbin/mosquitto".into()
        } else {
            tool("mosquitto")
        };
        let child = Command::new(exe)
            .arg("-c")
            .arg(&conf)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start mosquitto (scripts/setup-peers.sh installs it)");
        let deadline = Instant::now() + LISTEN_PATIENCE;
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(
                Instant::now() < deadline,
                "mosquitto did not listen on {port}"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
        Broker(child)
    }

    /// Kills the broker now (a broker outage mid-run).
    pub(crate) fn kill(mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

impl Drop for Broker {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}
