//! Starting the gateway binary and stopping it the way systemd does, shared by the binary-level
//! gateway tests; a child process's descriptor limit and runtime, for the flood tests.

use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

/// `retrocomp run [flags] --config <cfg>` with WARN logging, stderr piped (for
/// [`stop_with_sigterm`]), stdout discarded.
pub(crate) fn start_run(flags: &[&str], cfg: &Path) -> Child {
    Command::new(env!("CARGO_BIN_EXE_retrocomp"))
        .arg("run")
        .args(flags)
        .arg("--config")
        .arg(cfg)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap()
}

/// Send SIGTERM, wait up to 5 s for a clean exit (killing it and failing otherwise), assert the exit
/// status is success, and return what the gateway wrote to stderr.
pub(crate) fn stop_with_sigterm(child: &mut Child) -> String {
    Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .unwrap();
    let mut code = None;
    for _ in 0..100 {
        if let Some(s) = child.try_wait().unwrap() {
            code = Some(s);
            break;
        }
        std::thread::sleep(Duration::from_millis(50));
    }
    let code = code.unwrap_or_else(|| {
        let _ = child.kill();
        panic!("gateway did not stop on SIGTERM")
    });
    let mut err = String::new();
    std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut err).unwrap();
    assert!(code.success(), "exit {code:?}: {err}");
    err
}

/// This process's descriptor limit (`RLIMIT_NOFILE`), as `prlimit --nofile=SOFT:HARD` would set
/// it; the flood tests' children call it between fork and exec (setrlimit is async-signal-safe).
pub(crate) fn set_nofile(soft: u64, hard: u64) -> std::io::Result<()> {
    let lim = libc::rlimit {
        rlim_cur: soft,
        rlim_max: hard,
    };
    // SAFETY: setrlimit reads only the struct we pass.
    if unsafe { libc::setrlimit(libc::RLIMIT_NOFILE, &lim) } == 0 {
        Ok(())
    } else {
        Err(std::io::Error::last_os_error())
    }
}

/// A flood test's child process: INFO logs to stderr (what the parent counts) and the two-worker
/// runtime its servers run on.
pub(crate) fn child_runtime() -> tokio::runtime::Runtime {
    tracing_subscriber::fmt()
        .with_writer(std::io::stderr)
        .with_max_level(tracing::Level::INFO)
        .with_ansi(false)
        .init();
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap()
}

/// This test binary run again as a flood test's child: only `test` (`--exact`), with `envs`, its
/// stdin and stdout piped, stderr into `log`, and its descriptor limit `nofile` (soft = hard, as
/// `LimitNOFILE=` would set it) from before it starts.
pub(crate) fn spawn_child(
    test: &str,
    envs: &[(&str, &str)],
    nofile: u64,
    log: std::fs::File,
) -> Child {
    let mut cmd = Command::new(std::env::current_exe().unwrap());
    cmd.args(["--exact", test, "--nocapture"])
        .envs(envs.iter().copied())
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(log);
    // SAFETY: only setrlimit (async-signal-safe) between fork and exec.
    unsafe {
        cmd.pre_exec(move || set_nofile(nofile, nofile));
    }
    cmd.spawn().unwrap()
}
