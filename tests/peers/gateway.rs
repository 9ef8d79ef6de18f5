//! The real `retrocomp run` binary as a child process for the source-recovery and supervision tests:
//! its stderr collected line by line while it runs (so a chatty log never fills the pipe), its
//! `/status` and `/metrics` fetched over HTTP, waits that end on an event (with a generous deadline
//! that only a broken gateway reaches), and a kill on drop.

use std::io::{BufRead, BufReader, Read, Write};
use std::path::Path;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Deadline of every wait: far beyond what a loaded machine needs, reached only when it is broken.
pub(crate) const PATIENCE: Duration = Duration::from_secs(60);

/// A field config for `retrocomp run --dry-run`: axis z from a CiA 406 encoder (node 1, TPDO1,
/// 1000 counts/mm) over `can_section`, the Studer S-36 model, status on `status_port`.
pub(crate) fn field_toml(status_port: u16, can_section: &str) -> String {
    let root = env!("CARGO_MANIFEST_DIR");
    format!(
        r#"
[gateway]
name = "source-recovery"
cycle_ms = 10
status_listen = "127.0.0.1:{status_port}"
[safety]
max_correction_um = 60.0
max_change_um_per_cycle = 0.5
ramp_um_per_s = 200.0
stale_hold_s = 0.5
[direction]
deadband_mm = 0.005
switch_time_s = 0.05
[model]
path = "{root}/deploy/examples/studer-s36.toml"
[[axis]]
name = "z"
position_channel = "z_mm"
{can_section}
[canopen]
pdo_timeout_s = 0.5
encoder = [{{ channel = "z_mm", node_id = 1, counts_per_mm = 1000.0 }}]
"#
    )
}

pub(crate) struct Gateway {
    child: Child,
    log: Arc<Mutex<Vec<String>>>,
    pub status_port: u16,
}

impl Gateway {
    /// `retrocomp run --dry-run --config <cfg>` with `RUST_LOG=info` and `envs`.
    pub(crate) fn start(cfg: &Path, status_port: u16, envs: &[(&str, &str)]) -> Gateway {
        Self::start_args(&["run", "--dry-run", "--config"], cfg, status_port, envs)
    }

    /// `retrocomp <args> <cfg>` (e.g. `run --config`, the sink included) as [`Self::start`].
    pub(crate) fn start_args(
        args: &[&str],
        cfg: &Path,
        status_port: u16,
        envs: &[(&str, &str)],
    ) -> Gateway {
        let mut cmd = Command::new(env!("CARGO_BIN_EXE_retrocomp"));
        cmd.args(args).arg(cfg);
        for (k, v) in envs {
            cmd.env(k, v);
        }
        Self::spawn(cmd, status_port)
    }

    /// `retrocomp` as `cmd` says (its arguments and environment), with `RUST_LOG=info`, no
    /// service-manager socket and its stderr collected; its status endpoint on `status_port`.
    pub(crate) fn spawn(mut cmd: Command, status_port: u16) -> Gateway {
        // No service-manager socket of the test runner's own, unless the test gives one.
        if !cmd.get_envs().any(|(k, _)| k == "NOTIFY_SOCKET") {
            cmd.env_remove("NOTIFY_SOCKET");
        }
        cmd.env("RUST_LOG", "info")
            .stdout(Stdio::null())
            .stderr(Stdio::piped());
        let mut child = cmd.spawn().expect("start retrocomp run");
        let log = Arc::new(Mutex::new(Vec::new()));
        let (err, sink) = (child.stderr.take().unwrap(), log.clone());
        std::thread::spawn(move || {
            for l in BufReader::new(err).lines().map_while(Result::ok) {
                sink.lock().unwrap().push(strip_ansi(&l));
            }
        });
        Gateway {
            child,
            log,
            status_port,
        }
    }

    pub(crate) fn log(&self) -> Vec<String> {
        self.log.lock().unwrap().clone()
    }

    /// Lines of the log containing every one of `needles`.
    pub(crate) fn log_lines(&self, needles: &[&str]) -> Vec<String> {
        self.log()
            .into_iter()
            .filter(|l| needles.iter().all(|n| l.contains(n)))
            .collect()
    }

    /// `GET path` on the status endpoint; None while it is not up or when the answer is not 200.
    pub(crate) fn get(&self, path: &str) -> Option<String> {
        self.get_any(path)
            .and_then(|(code, body)| (code == 200).then_some(body))
    }

    /// `GET path` on the status endpoint: the status code and the body; None while it is not up.
    pub(crate) fn get_any(&self, path: &str) -> Option<(u16, String)> {
        let mut s = std::net::TcpStream::connect(("127.0.0.1", self.status_port)).ok()?;
        s.set_read_timeout(Some(Duration::from_secs(10))).ok()?;
        write!(
            s,
            "GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
        )
        .ok()?;
        let mut body = String::new();
        s.read_to_string(&mut body).ok()?;
        let (head, body) = body.split_once("\r\n\r\n")?;
        let code = head.strip_prefix("HTTP/1.1 ")?.get(..3)?.parse().ok()?;
        Some((code, body.to_string()))
    }

    /// Whether the process has exited (its status then).
    pub(crate) fn exited(&mut self) -> Option<ExitStatus> {
        self.child.try_wait().unwrap()
    }

    pub(crate) fn status(&self) -> Option<serde_json::Value> {
        serde_json::from_str(&self.get("/status")?).ok()
    }

    /// Poll `/status` until `pred` holds; panics (with the last status and the log) at [`PATIENCE`].
    pub(crate) fn wait_status(
        &mut self,
        what: &str,
        pred: impl Fn(&serde_json::Value) -> bool,
    ) -> serde_json::Value {
        let t0 = Instant::now();
        let mut last = serde_json::Value::Null;
        while t0.elapsed() < PATIENCE {
            if let Ok(Some(st)) = self.child.try_wait() {
                panic!(
                    "gateway exited ({st}) while waiting for {what}:\n{}",
                    self.log().join("\n")
                );
            }
            if let Some(s) = self.status() {
                if pred(&s) {
                    return s;
                }
                last = s;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        panic!(
            "no status with {what} within {PATIENCE:?}; last: {last:#}\nlog:\n{}",
            self.log().join("\n")
        );
    }

    /// Wait for the process to exit by itself (≤ [`PATIENCE`]).
    pub(crate) fn wait_exit(&mut self) -> ExitStatus {
        let t0 = Instant::now();
        while t0.elapsed() < PATIENCE {
            if let Some(st) = self.child.try_wait().unwrap() {
                // Let the reader thread take the last lines.
                std::thread::sleep(Duration::from_millis(200));
                return st;
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        panic!(
            "gateway still running after {PATIENCE:?}:\n{}",
            self.log().join("\n")
        );
    }

    /// SIGTERM and wait for the exit.
    pub(crate) fn stop(&mut self) -> ExitStatus {
        Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status()
            .unwrap();
        self.wait_exit()
    }
}

impl Drop for Gateway {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The log line without terminal colour codes (`ESC [ … m`).
fn strip_ansi(l: &str) -> String {
    let mut out = String::with_capacity(l.len());
    let mut chars = l.chars();
    while let Some(c) = chars.next() {
        if c == '\u{1b}' {
            for c in chars.by_ref() {
                if c.is_ascii_alphabetic() {
                    break;
                }
            }
        } else {
            out.push(c);
        }
    }
    out
}

/// The source named `name` in a status JSON.
pub(crate) fn source<'a>(st: &'a serde_json::Value, name: &str) -> &'a serde_json::Value {
    st["sources"]
        .as_array()
        .and_then(|a| a.iter().find(|s| s["name"] == name))
        .unwrap_or(&serde_json::Value::Null)
}

/// Whether `source` has the fault `kind` active (in its own list and in `active_faults`).
pub(crate) fn has_fault(st: &serde_json::Value, source_name: &str, kind: &str) -> bool {
    let own = source(st, source_name)["faults"]
        .as_array()
        .is_some_and(|f| f.iter().any(|f| f[0] == kind));
    let global = st["active_faults"]
        .as_array()
        .is_some_and(|f| f.iter().any(|f| f[0] == source_name && f[1] == kind));
    assert_eq!(
        own, global,
        "source faults and active_faults disagree: {st:#}"
    );
    own
}

/// A metric's value for `series` (e.g. `retrocomp_can_bus_state{source="can"}`).
pub(crate) fn metric(text: &str, series: &str) -> Option<f64> {
    text.lines()
        .find_map(|l| l.strip_prefix(series)?.trim().parse().ok())
}
