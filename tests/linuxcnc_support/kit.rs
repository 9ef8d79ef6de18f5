//! Harness for the LinuxCNC kit's closed loop (tests/real_peers/linuxcnc_closed_loop.rs): a run folder with the
//! kit (deploy/linuxcnc) and its simulator config, the box (`retrocomp run`, the real binary) on
//! 127.0.0.1, LinuxCNC 2.9 as uid 65534 (rtapi_app refuses root) with the NML file's TCP=5005
//! removed (no port outside loopback), serialised by flock on /tmp/retrocomp-linuxcnc.lock, and the
//! pin logs drive.py writes (pause-K.jsonl while paused, trace.jsonl every 20 ms with wall-clock
//! time in s). Units: positions mm, eoffsets µm (converted from LinuxCNC's mm), counts of 0.1 µm.

use std::io::{BufRead, BufReader};
use std::os::unix::fs::{PermissionsExt, chown};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

pub(crate) const KIT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/deploy/linuxcnc");
pub(crate) const MODEL: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/deploy/field/vmc-geometry.toml"
);
const NOBODY: u32 = 65534;

use crate::linuxcnc_support::nobody;
pub(crate) const AXES: [&str; 3] = ["x", "y", "z"];

pub(crate) fn require_linuxcnc() {
    let ok = ["linuxcnc", "mb2hal", "halcmd", "setpriv", "flock"]
        .iter()
        .all(|p| {
            Command::new("sh")
                .args(["-c", &format!("command -v {p}")])
                .stdout(Stdio::null())
                .status()
                .is_ok_and(|s| s.success())
        })
        && Command::new("/usr/bin/python3")
            .args(["-c", "import linuxcnc, hal"])
            .status()
            .is_ok_and(|s| s.success());
    assert!(
        ok,
        "LinuxCNC 2.9 (linuxcnc, mb2hal, python3 linuxcnc module) or setpriv/flock not found: run scripts/setup-linuxcnc.sh"
    );
}

/// Wall-clock time in s since the epoch: the clock drive.py stamps its trace with.
pub(crate) fn now_s() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .unwrap()
        .as_secs_f64()
}

/// A run folder LinuxCNC (uid 65534) can write: cfg/ (the kit + sim config) and home/.
pub(crate) struct Run {
    pub(crate) dir: tempfile::TempDir,
    pub(crate) box_child: Option<Child>,
    pub(crate) lcnc: Option<Child>,
}

impl Run {
    pub(crate) fn cfg(&self) -> PathBuf {
        self.dir.path().join("cfg")
    }
}

impl Drop for Run {
    fn drop(&mut self) {
        // Make drive.py exit (LinuxCNC then shuts itself down), then stop the box.
        let _ = std::fs::write(self.cfg().join("abort"), "");
        if let Some(mut l) = self.lcnc.take() {
            let t0 = Instant::now();
            while t0.elapsed() < Duration::from_secs(60) {
                if let Ok(Some(_)) = l.try_wait() {
                    break;
                }
                std::thread::sleep(Duration::from_millis(200));
            }
        }
        if let Some(mut b) = self.box_child.take() {
            let _ = b.kill();
            let _ = b.wait();
        }
    }
}

pub(crate) fn setup() -> Run {
    let dir = tempfile::Builder::new()
        .prefix("retrocomp-lcnc-")
        .disable_cleanup(std::env::var_os("RETROCOMP_KEEP_TMP").is_some())
        .tempdir()
        .unwrap();
    let cfg = dir.path().join("cfg");
    std::fs::create_dir_all(&cfg).unwrap();
    std::fs::create_dir_all(dir.path().join("home")).unwrap();
    let kit = Path::new(KIT);
    for f in std::fs::read_dir(kit.join("sim")).unwrap() {
        let f = f.unwrap().path();
        std::fs::copy(&f, cfg.join(f.file_name().unwrap())).unwrap();
    }
    for f in ["retrocomp.hal", "mb2hal-retrocomp.ini", "mb2hal-watch.py"] {
        std::fs::copy(kit.join(f), cfg.join(f)).unwrap();
    }
    // Loopback only: without TCP=5005 linuxcncsvr opens no network port.
    let nml = std::fs::read_to_string("/usr/share/linuxcnc/linuxcnc.nml")
        .expect("LinuxCNC's linuxcnc.nml: run scripts/setup-linuxcnc.sh");
    std::fs::write(cfg.join("linuxcnc.nml"), nml.replace(" TCP=5005", "")).unwrap();
    let toml = std::fs::read_to_string(cfg.join("retrocomp-sim.toml")).unwrap();
    let toml = toml
        .replace("127.0.0.1:1502", "127.0.0.1:0")
        .replace("127.0.0.1:9184", "127.0.0.1:0")
        .replace("\"../../field/vmc-geometry.toml\"", &format!("\"{MODEL}\""));
    std::fs::write(cfg.join("retrocomp-sim.toml"), toml).unwrap();
    Run {
        dir,
        box_child: None,
        lcnc: None,
    }
}

fn give_to_nobody(p: &Path) {
    chown(p, Some(NOBODY), Some(NOBODY)).unwrap();
    std::fs::set_permissions(p, std::fs::Permissions::from_mode(0o775)).unwrap();
    if p.is_dir() {
        for e in std::fs::read_dir(p).unwrap() {
            give_to_nobody(&e.unwrap().path());
        }
    }
}

/// Start `retrocomp run` on `listen`; returns the bound Modbus port (from its log).
pub(crate) fn start_box(run: &mut Run, listen: &str, log_name: &str) -> u16 {
    let cfg_path = run.cfg().join("retrocomp-sim.toml");
    let text = std::fs::read_to_string(&cfg_path).unwrap();
    let key = "kind = \"tcp\", listen = \"";
    let start = text.find(key).unwrap() + key.len();
    let end = start + text[start..].find('"').unwrap();
    std::fs::write(
        &cfg_path,
        format!("{}{listen}{}", &text[..start], &text[end..]),
    )
    .unwrap();
    let log = run.dir.path().join(log_name);
    let child = Command::new(env!("CARGO_BIN_EXE_retrocomp"))
        .args(["run", "--config"])
        .arg(&cfg_path)
        .env("NO_COLOR", "1")
        .env("RUST_LOG", "info")
        .stderr(std::fs::File::create(&log).unwrap())
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    run.box_child = Some(child);
    let t0 = Instant::now();
    loop {
        let text = std::fs::read_to_string(&log).unwrap_or_default();
        if let Some(line) = text
            .lines()
            .find(|l| l.contains("origin-shift server listening"))
        {
            let at = line.rfind("127.0.0.1:").unwrap() + "127.0.0.1:".len();
            let digits: String = line[at..]
                .chars()
                .take_while(|c| c.is_ascii_digit())
                .collect();
            return digits.parse().unwrap();
        }
        if let Some(Ok(Some(st))) = run.box_child.as_mut().map(|c| c.try_wait()) {
            panic!("retrocomp run exited ({st}):\n{text}");
        }
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "retrocomp run did not start listening:\n{text}"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

pub(crate) fn start_linuxcnc(run: &mut Run, port: u16) {
    let cfg = run.cfg();
    let ini = cfg.join("mb2hal-retrocomp.ini");
    let text: String = std::fs::read_to_string(&ini)
        .unwrap()
        .lines()
        .map(|l| {
            if l.starts_with("TCP_PORT=") {
                format!("TCP_PORT={port}\n")
            } else {
                format!("{l}\n")
            }
        })
        .collect();
    std::fs::write(&ini, text).unwrap();
    give_to_nobody(run.dir.path());
    let home = run.dir.path().join("home");
    let out = std::fs::File::create(run.dir.path().join("linuxcnc.out")).unwrap();
    let child = nobody::one_at_a_time_as_nobody(&home)
        .arg("linuxcnc")
        .arg(cfg.join("retrocomp-sim.ini"))
        .current_dir(&cfg)
        // mb2hal's transaction errors and the HAL's messages, for a failure's diagnostics.
        .stdout(out.try_clone().unwrap())
        .stderr(out)
        .spawn()
        .unwrap();
    run.lcnc = Some(child);
    std::thread::spawn(prioritise_motion);
}

/// This host has no PREEMPT_RT kernel, so LinuxCNC runs its servo thread as an ordinary thread
/// ("Using POSIX non-realtime"), and with both cores busy it stalls for up to seconds and then
/// runs its missed periods back to back; its task then aborts programs ("USRMOT: ERROR: command
/// timeout"). On a machine the servo thread runs SCHED_FIFO: here every thread of `rtapi_app` gets
/// SCHED_FIFO priority 1 as it appears (the kernel's RT throttling still leaves 5 % to others), and
/// LinuxCNC's task (`milltask`) and the test's operator (`drive.py`) nice −10, for the first 60 s.
/// mb2hal, mb2hal-watch.py and the box keep ordinary priority: the kit's liveness bound is judged
/// against a loaded host.
fn prioritise_motion() {
    let mut done = std::collections::HashSet::new();
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(60) {
        for p in std::fs::read_dir("/proc").into_iter().flatten().flatten() {
            let comm = std::fs::read_to_string(p.path().join("comm")).unwrap_or_default();
            let how: &[&str] = match comm.trim() {
                "rtapi_app" => &["chrt", "-f", "-p", "1"],
                "milltask" | "drive.py" => &["renice", "-n", "-10", "-p"],
                _ => continue,
            };
            for t in std::fs::read_dir(p.path().join("task"))
                .into_iter()
                .flatten()
                .flatten()
            {
                let tid = t.file_name().to_string_lossy().into_owned();
                if done.insert(tid.clone()) {
                    let _ = Command::new(how[0])
                        .args(&how[1..])
                        .arg(&tid)
                        .stdout(Stdio::null())
                        .stderr(Stdio::null())
                        .status();
                }
            }
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// One line of drive.py's pin log.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Pins {
    /// Wall-clock s (trace.jsonl only; 0 in pause logs).
    pub(crate) t_s: f64,
    pub(crate) pos_mm: [f64; 3],
    pub(crate) eoffset_um: [f64; 3],
    pub(crate) step_max_counts: [f64; 3],
    pub(crate) alive: bool,
    pub(crate) trips: f64,
    pub(crate) restarts: f64,
    pub(crate) vel_mm_s: f64,
    /// The box watch's heartbeat age (wall-clock s; it changes at every servo period while the
    /// heartbeat is silent, so two equal values mean the servo thread did not run in between).
    pub(crate) hb_age_s: Option<f64>,
}

fn parse(line: &str) -> Option<Pins> {
    let v: serde_json::Value = serde_json::from_str(line).ok()?;
    let f = |k: &str| v.get(k).and_then(|x| x.as_f64());
    let per_axis = |fmt: &dyn Fn(&str) -> String, scale: f64| -> Option<[f64; 3]> {
        Some([
            f(&fmt("x"))? * scale,
            f(&fmt("y"))? * scale,
            f(&fmt("z"))? * scale,
        ])
    };
    Some(Pins {
        t_s: f("t").unwrap_or(0.0),
        pos_mm: per_axis(&|a| format!("axis.{a}.pos-cmd"), 1.0)?,
        eoffset_um: per_axis(&|a| format!("axis.{a}.eoffset"), 1000.0)?,
        step_max_counts: per_axis(&|a| format!("rc-{a}-step-max.max"), 1.0)?,
        alive: f("rc-alive")? > 0.5,
        trips: f("rc-trips.count")?,
        restarts: f("rc-watch.restarts")?,
        vel_mm_s: f("motion.current-vel")?,
        hb_age_s: f("rc-age-reset.out"),
    })
}

/// Every complete line of a pin log (a line being written is skipped).
pub(crate) fn lines_of(path: &Path) -> Vec<Pins> {
    let Ok(f) = std::fs::File::open(path) else {
        return Vec::new();
    };
    BufReader::new(f)
        .lines()
        .map_while(Result::ok)
        .filter_map(|l| parse(&l))
        .collect()
}

/// LinuxCNC's diagnostics for a failure message.
pub(crate) fn diagnostics(run: &Run) -> String {
    let read = |p: PathBuf| std::fs::read_to_string(&p).unwrap_or_default();
    let tail = |s: String| s.lines().rev().take(30).collect::<Vec<_>>().join("\n");
    format!(
        "drive.log:\n{}\nlinuxcnc output (reversed tail):\n{}\nlinuxcnc_print (reversed tail):\n{}\nlinuxcnc_debug (reversed tail):\n{}\nbox log (reversed tail):\n{}",
        read(run.cfg().join("drive.log")),
        tail(read(run.dir.path().join("linuxcnc.out"))),
        tail(read(run.dir.path().join("home/linuxcnc_print.txt"))),
        tail(read(run.dir.path().join("home/linuxcnc_debug.txt"))),
        tail(read(run.dir.path().join("box-1.log")) + &read(run.dir.path().join("box-2.log"))),
    )
}

/// Processes that keep both cores busy for as long as this lives (`sh -c 'while :; do :; done'`).
pub(crate) struct BusyCores(Vec<Child>);

impl BusyCores {
    pub(crate) fn start(n: usize) -> Self {
        BusyCores(
            (0..n)
                .map(|_| {
                    Command::new("sh")
                        .args(["-c", "while :; do :; done"])
                        .spawn()
                        .expect("spawn a busy loop")
                })
                .collect(),
        )
    }
}

impl Drop for BusyCores {
    fn drop(&mut self) {
        for c in &mut self.0 {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}
