//! A Mosquitto child for the MQTT tests: loopback only, anonymous, no persistence, started from a
//! generated config on a given port (never the system service), plain or TLS-only (a CA and a
//! server certificate made with openssl); killed on drop. Shared by
//! `telemetry_mqtt.rs` and `telemetry_fleet_drift.rs` (each includes it with `#[path]` beside
//! `mod peers;`).
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::peers::tool;

/// How long a starting broker may take to listen; only a broken install reaches it.
const LISTEN_PATIENCE: Duration = Duration::from_secs(120);

pub(crate) struct Broker(Child);

impl Broker {
    pub(crate) fn start(dir: &Path, port: u16) -> Broker {
        Self::with_listener(dir, port, "")
    }

    /// A broker whose listener speaks only TLS, with a certificate for IP 127.0.0.1 signed by a
    /// CA made here (openssl); returns the CA's PEM file for the clients. `extra`: more config
    /// lines (e.g. the fleet's `max_queued_messages`, docs/fleet.md).
    pub(crate) fn start_tls(dir: &Path, port: u16, extra: &str) -> (Broker, PathBuf) {
        let (ca, cert, key) = tls_files(dir);
        let tls = format!(
            "cafile {}\ncertfile {}\nkeyfile {}\n{}",
            ca.display(),
            cert.display(),
            key.display(),
            extra
        );
        (Self::with_listener(dir, port, &tls), ca)
    }

    /// `listener_opts`: lines for the listener (e.g. its TLS files).
    fn with_listener(dir: &Path, port: u16, listener_opts: &str) -> Broker {
        let conf = dir.join("mosquitto.conf");
        // `user root` only when run as root: mosquitto would otherwise drop to its own user, which
        // cannot read the key in a root-owned temporary directory.
        let user = if is_root() { "user root\n" } else { "" };
        std::fs::write(
            &conf,
            format!(
                "{user}listener {port} 127.0.0.1\n{listener_opts}allow_anonymous true\npersistence false\nlog_dest none\n"
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

    pub(crate) fn pid(&self) -> u32 {
        self.0.id()
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

fn is_root() -> bool {
    std::fs::read_to_string("/proc/self/status").is_ok_and(|s| {
        s.lines()
            .any(|l| l.starts_with("Uid:") && l.split_whitespace().nth(1) == Some("0"))
    })
}

/// A CA and a server certificate for IP 127.0.0.1 (P-256, valid 2 days) made with the openssl
/// command: (ca.pem, server.pem, server.key) in `dir`.
pub(crate) fn tls_files(dir: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let openssl = tool("openssl");
    let run = |args: &[&str]| {
        let out = Command::new(&openssl)
            .args(args)
            .current_dir(dir)
            .output()
            .expect("run openssl (scripts/setup-peers.sh installs it)");
        assert!(
            out.status.success(),
            "openssl {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
    };
    let ec = [
        "-newkey",
        "ec",
        "-pkeyopt",
        "ec_paramgen_curve:prime256v1",
        "-nodes",
    ];
    let mut ca = vec!["req", "-x509"];
    ca.extend(ec);
    ca.extend(["-keyout", "ca.key", "-out", "ca.pem", "-days", "2"]);
    ca.extend(["-subj", "/CN=retrocomp test CA"]);
    run(&ca);
    let mut csr = vec!["req"];
    csr.extend(ec);
    csr.extend(["-keyout", "server.key", "-out", "server.csr"]);
    csr.extend(["-subj", "/CN=127.0.0.1"]);
    run(&csr);
    std::fs::write(
        dir.join("server.ext"),
        "subjectAltName=IP:127.0.0.1\nbasicConstraints=CA:FALSE\nextendedKeyUsage=serverAuth\n",
    )
    .unwrap();
    run(&[
        "x509",
        "-req",
        "-in",
        "server.csr",
        "-CA",
        "ca.pem",
        "-CAkey",
        "ca.key",
        "-set_serial",
        "1",
        "-days",
        "2",
        "-extfile",
        "server.ext",
        "-out",
        "server.pem",
    ]);
    (
        dir.join("ca.pem"),
        dir.join("server.pem"),
        dir.join("server.key"),
    )
}
