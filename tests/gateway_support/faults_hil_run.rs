//! The two processes of the closed-loop fault tests (`gateway_faults_hil`, `gateway_faults_rtu_hil`):
//! `hil-sim serve` with its stderr kept (whole text, and each line with the wall time it was read,
//! to place hil-sim's fault edges on the test's clock) and its endpoints read from what it prints;
//! `retrocomp run` with its log in a file, stopped with SIGTERM. Each run gets a fresh folder under
//! the target dir, kept afterwards for a post-mortem.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex, mpsc};
use std::time::{Duration, Instant};

use retrocomp_bus::can::Hub;

/// A fresh, empty run folder `name` under the target dir's tmp.
pub(crate) fn run_dir(name: &str) -> PathBuf {
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    eprintln!("run folder: {}", dir.display());
    dir
}

/// The test's own runtime (one worker, for the /status client) and the socketcand hub on loopback
/// that hil-sim's CAN nodes and the gateway both connect to: the bus, on its own thread under
/// SCHED_FIFO 20 when allowed, like the machine and the gateway's real-time threads (issue 18.5).
pub(crate) fn loopback_hub() -> (tokio::runtime::Runtime, Hub) {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .unwrap();
    let hub = Hub::start_on_thread(([127, 0, 0, 1], 0).into(), Some(20)).unwrap();
    (rt, hub)
}

/// The demo mill's full model: hil-sim's hidden truth and the gateway's model in both tests.
pub(crate) fn demo_truth_model() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/demo/mill-full.toml")
}

/// A running `hil-sim serve`.
pub(crate) struct Sim {
    pub child: Child,
    log: Arc<Mutex<String>>,
    lines: mpsc::Receiver<(Instant, String)>,
}

impl Sim {
    pub(crate) fn spawn(hil_sim: &Path, config: &Path, out: &Path) -> Sim {
        let mut child = Command::new(hil_sim)
            .args(["serve", "--config"])
            .arg(config)
            .arg("--out")
            .arg(out)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("starting hil-sim");
        let log = Arc::new(Mutex::new(String::new()));
        let (tx, lines) = mpsc::channel();
        let stderr = child.stderr.take().unwrap();
        let text = log.clone();
        std::thread::spawn(move || {
            for l in BufReader::new(stderr).lines().map_while(Result::ok) {
                text.lock().unwrap().push_str(&(l.clone() + "\n"));
                let _ = tx.send((Instant::now(), l));
            }
        });
        Sim { child, log, lines }
    }

    /// Everything hil-sim printed so far.
    pub(crate) fn log_text(&self) -> String {
        self.log.lock().unwrap().clone()
    }

    /// Waits (≤ 20 s) until hil-sim has printed a line starting with each prefix, in any order;
    /// returns the rest of each line, trimmed, in the order of `prefixes`.
    pub(crate) fn wait_for(&self, prefixes: &[&str]) -> Vec<String> {
        let mut found: Vec<Option<String>> = vec![None; prefixes.len()];
        while found.iter().any(Option::is_none) {
            let (_, l) = self
                .lines
                .recv_timeout(Duration::from_secs(20))
                .unwrap_or_else(|_| panic!("hil-sim did not come up:\n{}", self.log_text()));
            for (p, f) in prefixes.iter().zip(&mut found) {
                if let Some(rest) = l.strip_prefix(p) {
                    *f = Some(rest.trim().to_string());
                }
            }
        }
        found.into_iter().map(Option::unwrap).collect()
    }

    /// Forget the lines printed so far (so a later [`Self::wait_for`] sees only what follows).
    pub(crate) fn drain(&self) {
        while self.lines.try_recv().is_ok() {}
    }

    /// Seconds after `t0` at which the test read hil-sim's first line starting with `prefix`,
    /// among the lines not yet consumed (so edges printed in order are found in order).
    pub(crate) fn printed_at(&self, prefix: &str, t0: Instant) -> f64 {
        self.lines
            .try_iter()
            .find(|(_, l)| l.starts_with(prefix))
            .map(|(at, _)| at.duration_since(t0).as_secs_f64())
            .unwrap_or_else(|| panic!("hil-sim never printed {prefix:?}:\n{}", self.log_text()))
    }
}

/// `retrocomp run --config field --model model`, info log into `dir/log_name`.
pub(crate) fn start_gateway(
    dir: &Path,
    log_name: &str,
    field: &Path,
    model: &Path,
) -> (Child, PathBuf) {
    start_gateway_with(dir, log_name, field, model, &[])
}

/// [`start_gateway`] with extra environment variables (e.g. its own `TMPDIR`).
pub(crate) fn start_gateway_with(
    dir: &Path,
    log_name: &str,
    field: &Path,
    model: &Path,
    env: &[(&str, &Path)],
) -> (Child, PathBuf) {
    let log = dir.join(log_name);
    let child = Command::new(env!("CARGO_BIN_EXE_retrocomp"))
        .envs(env.iter().copied())
        .arg("run")
        .arg("--config")
        .arg(field)
        .arg("--model")
        .arg(model)
        .env("RUST_LOG", "info")
        .env("NO_COLOR", "1")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        // A file, not a pipe: a pipe nobody drains would block the gateway's logging.
        .stderr(std::fs::File::create(&log).unwrap())
        .spawn()
        .expect("starting retrocomp run");
    (child, log)
}

pub(crate) fn signal(gw: &Child, sig: &str) {
    let st = Command::new("kill")
        .args([sig, &gw.id().to_string()])
        .status()
        .unwrap();
    assert!(st.success(), "kill {sig}");
}

/// SIGTERM, wait up to 5 s, assert a clean exit.
pub(crate) fn stop_gateway(gw: &mut Child, log: &Path) {
    signal(gw, "-TERM");
    let t = Instant::now();
    while t.elapsed() < Duration::from_secs(5) {
        if let Some(st) = gw.try_wait().unwrap() {
            assert!(
                st.success(),
                "gateway exit {st}:\n{}",
                std::fs::read_to_string(log).unwrap()
            );
            return;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let _ = gw.kill();
    panic!("the gateway did not stop on SIGTERM");
}
