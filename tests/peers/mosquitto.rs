//! A Mosquitto child for the MQTT tests: loopback only, anonymous, started from a generated config
//! on a given port (never the system service), plain or TLS-only (a CA and a server certificate
//! made with openssl); killed on drop. No persistence and no log unless the config given says
//! otherwise ([`Broker::start_conf`]: e.g. a bridge section, `persistence true`), and such a broker
//! can be stopped gracefully and started again on the same config and port (a restart). Included
//! by `real_peers` and by the `fleet_processes` bench, each using part of it.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::peers::tool;

/// How long a starting broker may take to listen, or a stopping one to exit; only a broken
/// install reaches it.
const LISTEN_PATIENCE: Duration = Duration::from_secs(120);

pub(crate) struct Broker {
    child: Child,
    conf: PathBuf,
    port: u16,
}

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
        Self::start_conf(
            dir,
            port,
            "persistence false\nlog_dest none\n",
            &format!("{listener_opts}allow_anonymous true\n"),
        )
    }

    /// A plain broker on `port` whose config (`dir/mosquitto.conf`) is `globals` (e.g.
    /// `persistence true`, `persistence_location`, `log_dest file …`), then the listener, then
    /// `tail` (its options, then e.g. a bridge section: `connection` starts one, and every line
    /// after it belongs to it). `tail` should say `allow_anonymous true` for the clients here.
    pub(crate) fn start_conf(dir: &Path, port: u16, globals: &str, tail: &str) -> Broker {
        let conf = dir.join("mosquitto.conf");
        // `user root` only when run as root: mosquitto would otherwise drop to its own user, which
        // cannot read the key in a root-owned temporary directory.
        let user = if is_root() { "user root\n" } else { "" };
        std::fs::write(
            &conf,
            format!("{user}{globals}listener {port} 127.0.0.1\n{tail}"),
        )
        .unwrap();
        let child = spawn(&conf, port);
        Broker { child, conf, port }
    }

    pub(crate) fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Stops the broker gracefully (SIGTERM: it closes its clients and bridges and, with
    /// `persistence true`, writes its sessions and queues) and waits for it to exit.
    pub(crate) fn stop(&mut self) {
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status();
        let deadline = Instant::now() + LISTEN_PATIENCE;
        while self.child.try_wait().unwrap().is_none() {
            assert!(
                Instant::now() < deadline,
                "mosquitto did not exit on SIGTERM"
            );
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Starts the broker again on the same config and port (after [`Broker::stop`]).
    pub(crate) fn restart(&mut self) {
        self.child = spawn(&self.conf, self.port);
    }

    /// Kills the broker now (a broker outage mid-run).
    pub(crate) fn kill(mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts mosquitto on `conf` and waits until it listens on `port`.
fn spawn(conf: &Path, port: u16) -> Child {
    // Debian installs it in /usr/sbin, which a user's PATH may lack.
    let exe = if Path::new("/usr/sbin/mosquitto").is_file() {
        "/usr/sbin/mosquitto".into()
    } else {
        tool("mosquitto")
    };
    let child = Command::new(exe)
        .arg("-c")
        .arg(conf)
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
    child
}

impl Drop for Broker {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
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
