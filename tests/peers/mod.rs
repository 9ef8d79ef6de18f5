//! Helpers for the integration tests that talk to real third-party peers (python-can, pymodbus,
//! pyserial, socat, mbpoll). A missing peer FAILS the test with the command that installs it.
//! Included by `real_peers` and by the `fleet_processes` bench, each using part of it.
#![allow(dead_code)]

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

pub(crate) const INSTALL: &str = "run scripts/setup-peers.sh";

pub(crate) fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// `<repo>/.venv/bin/python`, or a panic that says how to create it.
pub(crate) fn python() -> PathBuf {
    let p = repo().join(".venv/bin/python");
    assert!(p.exists(), "{} is missing: {INSTALL}", p.display());
    p
}

/// A program on PATH, or a panic that says how to install it.
pub(crate) fn tool(name: &str) -> PathBuf {
    std::env::var_os("PATH")
        .and_then(|paths| {
            std::env::split_paths(&paths)
                .map(|d| d.join(name))
                .find(|p| p.is_file())
        })
        .unwrap_or_else(|| panic!("`{name}` is not installed: {INSTALL}"))
}

/// A child process killed on drop.
pub(crate) struct Peer {
    pub child: Child,
    pub name: String,
    /// stdout lines printed after `READY`.
    pub lines: Option<std::sync::mpsc::Receiver<String>>,
}

impl Peer {
    /// Next stdout line, waiting up to `secs`.
    pub(crate) fn line(&self, secs: u64) -> String {
        let rx = self.lines.as_ref().expect("peer has no stdout");
        rx.recv_timeout(Duration::from_secs(secs))
            .unwrap_or_else(|_| panic!("{}: no output line within {secs} s", self.name))
    }
}

impl Peer {
    /// Write one command line to the peer's stdin.
    pub(crate) fn send(&mut self, line: &str) {
        use std::io::Write;
        let stdin = self.child.stdin.as_mut().expect("peer has no stdin");
        writeln!(stdin, "{line}")
            .and_then(|()| stdin.flush())
            .unwrap_or_else(|e| panic!("{}: cannot write {line:?}: {e}", self.name));
    }

    /// Read lines until one equals `want` (≤ `secs` each); returns the lines skipped on the way.
    pub(crate) fn expect(&self, want: &str, secs: u64) -> Vec<String> {
        let mut skipped = Vec::new();
        loop {
            let l = self.line(secs);
            if l.trim() == want {
                return skipped;
            }
            skipped.push(l);
        }
    }
}

impl Drop for Peer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Start `tests/peers/<script>` with the venv python and wait (≤ 20 s) for it to print `READY`.
pub(crate) fn spawn_python(script: &str, args: &[&str]) -> Peer {
    let mut child = Command::new(python())
        .arg(repo().join("tests/peers").join(script))
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap_or_else(|e| panic!("cannot start {script}: {e}"));
    let stdout = child.stdout.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            let _ = tx.send(line);
        }
    });
    let mut peer = Peer {
        child,
        name: script.to_string(),
        lines: None,
    };
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        match rx.recv_timeout(Duration::from_millis(100)) {
            Ok(l) if l.trim() == "READY" => {
                peer.lines = Some(rx);
                return peer;
            }
            Ok(_) => {}
            Err(_) => {
                if let Ok(Some(st)) = peer.child.try_wait() {
                    let mut err = String::new();
                    if let Some(mut e) = peer.child.stderr.take() {
                        let _ = std::io::Read::read_to_string(&mut e, &mut err);
                    }
                    panic!("{script} exited ({st}) before READY:\n{err}\n({INSTALL}?)");
                }
                assert!(
                    Instant::now() < deadline,
                    "{script} did not print READY in 20 s"
                );
            }
        }
    }
}

/// An unused loopback TCP port (bound and released; the peer binds it right after).
pub(crate) fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// A socat pty pair `dir/ttyA` ↔ `dir/ttyB` (raw, no echo), waiting for both links.
pub(crate) fn socat_pair(dir: &Path) -> (Peer, PathBuf, PathBuf) {
    let (a, b) = (dir.join("ttyA"), dir.join("ttyB"));
    let child = Command::new(tool("socat"))
        .arg(format!("pty,raw,echo=0,link={}", a.display()))
        .arg(format!("pty,raw,echo=0,link={}", b.display()))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("start socat");
    let peer = Peer {
        child,
        name: "socat".into(),
        lines: None,
    };
    let deadline = Instant::now() + Duration::from_secs(10);
    while !(a.exists() && b.exists()) {
        assert!(
            Instant::now() < deadline,
            "socat did not create the pty links"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    (peer, a, b)
}
