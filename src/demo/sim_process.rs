//! The `hil-sim` child process of the demo: locating the binary, filling the config template, and
//! waiting for its Modbus TCP address. hil-sim depends on retrocomp, so retrocomp cannot link it:
//! it runs as a separate binary, connected only through loopback transports.

use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::Stdio;

use super::error::{Context as _, DemoError};
use retrocomp_gateway::error::GatewayError;
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::{Child, Command};
use tokio::task::JoinHandle;

/// The sim config template (placeholders `@SEED@`, `@TRUTH_MODEL@`, `@HUB_PORT@`, `@WARMUP@`).
pub(crate) const SIM_TEMPLATE: &str = include_str!("../../deploy/demo/sim.toml");

/// `hil-sim` next to the current executable, else `$HIL_SIM_BIN`.
pub fn locate_hil_sim() -> Result<PathBuf, DemoError> {
    let exe = std::env::current_exe().context("current executable")?;
    let mut tried = Vec::new();
    if let Some(dir) = exe.parent() {
        // Test binaries live in target/<profile>/deps; the bins one level up.
        for d in [Some(dir), dir.parent()].into_iter().flatten() {
            let p = d.join("hil-sim");
            if p.is_file() {
                return Ok(p);
            }
            tried.push(p);
        }
    }
    if let Some(p) = std::env::var_os("HIL_SIM_BIN") {
        let p = PathBuf::from(p);
        if p.is_file() {
            return Ok(p);
        }
        return Err(DemoError::Failed(format!(
            "$HIL_SIM_BIN = {} is not a file",
            p.display()
        )));
    }
    Err(DemoError::Failed(format!(
        "the hil-sim binary was not found (tried {}; $HIL_SIM_BIN unset). Build it with \
         `cargo build --release --workspace` (the demo looks next to the retrocomp executable) \
         or set HIL_SIM_BIN",
        tried
            .iter()
            .map(|p| p.display().to_string())
            .collect::<Vec<_>>()
            .join(", ")
    )))
}

/// One X stroke pair (150 mm out and back at 60 mm/s, with acceleration) takes about this long.
const STROKE_PAIR_S: f64 = 5.0;

/// The warm-up G-code: X stroke pairs for about `warmup_s` seconds (at least one pair).
pub(crate) fn warmup_gcode(warmup_s: f64) -> String {
    let pairs = retrocomp_analysis::numeric::round_usize(warmup_s / STROKE_PAIR_S).max(1);
    "G1 X150\nG1 X0\n".repeat(pairs)
}

pub(crate) fn sim_config(
    seed: u64,
    truth_model: &Path,
    hub_port: u16,
    warmup_s: f64,
    pty_link: &Path,
) -> String {
    SIM_TEMPLATE
        .replace("@PTY_LINK@", &pty_link.display().to_string())
        .replace("@WARMUP@", &warmup_gcode(warmup_s))
        .replace("@SEED@", &seed.to_string())
        .replace("@TRUTH_MODEL@", &truth_model.display().to_string())
        .replace("@HUB_PORT@", &hub_port.to_string())
}

/// `sim_toml` (from [`sim_config`]) with the simulator's threads under `SCHED_FIFO` at `priority`
/// (`[clock] realtime_priority`): the simulated machine keeps its pace on a busy host, as a real
/// one does on its own hardware. `None`: unchanged.
pub(crate) fn with_realtime_priority(sim_toml: &str, priority: Option<u8>) -> String {
    match priority {
        Some(p) => sim_toml.replacen(
            "[clock]\n",
            &format!("[clock]\nrealtime_priority = {p}\n"),
            1,
        ),
        None => sim_toml.to_string(),
    }
}

/// `sim_toml` (from [`sim_config`]) running its program `passes` times in one simulator: the dwell
/// that lets the gateway connect once, then the warm-up and the part again and again, then `M30`.
/// For `demo --serve`: one machine and one gateway for all the passes, so the page's history,
/// the OPC UA subscriptions and the Sparkplug session run on without a restart between passes.
/// The simulated-time budget grows with the passes; the recording is thinned to 0.5 s (nobody
/// scores the live run, and an hour at 100 Hz is a large file).
pub(crate) fn repeated(sim_toml: &str, passes: usize) -> String {
    let (head, rest) = sim_toml
        .split_once("gcode = \"\"\"\n")
        .expect("the template has a gcode block");
    let (gcode, tail) = rest.split_once("\"\"\"").expect("closed gcode block");
    let lines: Vec<&str> = gcode.lines().collect();
    let dwell = lines
        .iter()
        .position(|l| l.trim_start().starts_with("G4"))
        .expect("the program starts with a dwell");
    let end = lines
        .iter()
        .rposition(|l| l.trim_start().starts_with("M30"))
        .expect("the program ends with M30");
    let pass = lines[dwell + 1..end].join("\n") + "\n";
    let program = lines[..=dwell].join("\n") + "\n" + &pass.repeat(passes.max(1)) + "M30\n";
    let max_s = format!("max_duration_s = {:.1}", 200.0 * passes.max(1) as f64);
    (format!("{head}gcode = \"\"\"\n{program}\"\"\"{tail}"))
        .replacen("max_duration_s = 200.0", &max_s, 1)
        .replacen("every_s = 0.01", "every_s = 0.5", 1)
}

/// A running `hil-sim serve`.
#[derive(Debug)]
pub(crate) struct Sim {
    pub child: Child,
    pub modbus: SocketAddr,
    /// Device of the pty carrying the weighing lines (the cutting force).
    pub weighing_pty: PathBuf,
    /// Everything hil-sim wrote to stderr (for error messages).
    pub log: JoinHandle<String>,
}

/// Start `hil-sim serve --config CONFIG --out OUT` and wait for its Modbus TCP address and the
/// weighing pty (hil-sim prints both before the program starts).
pub(crate) async fn start(bin: &Path, config: &Path, out: &Path) -> Result<Sim, DemoError> {
    let mut child = Command::new(bin)
        .arg("serve")
        .arg("--config")
        .arg(config)
        .arg("--out")
        .arg(out)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .with_context(|| format!("starting {}", bin.display()))?;
    let mut lines = BufReader::new(child.stderr.take().context("hil-sim stderr")?).lines();
    let mut log = String::new();
    let mut modbus = None;
    let weighing_pty = loop {
        let line = tokio::time::timeout(std::time::Duration::from_secs(20), lines.next_line())
            .await
            .context("hil-sim did not report its Modbus address and pty within 20 s")??;
        let Some(line) = line else {
            let status = child.wait().await?;
            return Err(DemoError::Failed(format!(
                "hil-sim exited ({status}) before serving:\n{log}"
            )));
        };
        log.push_str(&line);
        log.push('\n');
        if let Some(a) = line.strip_prefix("hil-sim: modbus tcp on ") {
            let a = a.trim();
            modbus = Some(
                a.parse::<SocketAddr>()
                    .with_context(|| format!("hil-sim address `{a}`"))?,
            );
        }
        if let Some(p) = line.strip_prefix("hil-sim: weighing lines on ") {
            break PathBuf::from(p.trim());
        }
    };
    let modbus = modbus.context("hil-sim reported its weighing pty but no Modbus TCP address")?;
    let log = tokio::spawn(async move {
        while let Ok(Some(l)) = lines.next_line().await {
            log.push_str(&l);
            log.push('\n');
        }
        log
    });
    Ok(Sim {
        child,
        modbus,
        weighing_pty,
        log,
    })
}

/// Wait for hil-sim's exit while its gateway runs. The gateway runs until told to stop, so one that
/// ends first (a port it could not bind, a sink or source that died) is this run's error, reported
/// now and not when the machine's program ends (a live run's program lasts an hour, and its page
/// would never come up). The caller stops hil-sim then.
pub(crate) async fn until_exit_or_gateway_end<S>(
    sim_exit: impl Future<Output = S>,
    gateway: &mut JoinHandle<Result<retrocomp_gateway::run::RunSummary, GatewayError>>,
    run: &str,
) -> Result<S, DemoError> {
    tokio::select! {
        biased;
        status = sim_exit => Ok(status),
        ended = gateway => {
            let summary = ended
                .context("gateway task")?
                .with_context(|| format!("gateway ({run})"))?;
            Err(DemoError::Failed(format!(
                "gateway ({run}) stopped after {} cycles, before hil-sim ended its program",
                summary.cycles
            )))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn a_gateway_that_ends_before_the_machine_ends_the_run_with_its_error() {
        let mut failed = tokio::spawn(async {
            Err(GatewayError::Stopped(
                "binding 127.0.0.1:1: address in use".into(),
            ))
        });
        let e = until_exit_or_gateway_end(std::future::pending::<()>(), &mut failed, "live")
            .await
            .unwrap_err();
        let chain = format!("{e}: {}", std::error::Error::source(&e).unwrap());
        assert!(chain.starts_with("gateway (live): "), "{chain}");
        assert!(chain.contains("address in use"), "{chain}");
        // A gateway that returns without being told to stop is an error too, not a finished run.
        let mut returned = tokio::spawn(async {
            Ok(retrocomp_gateway::run::RunSummary {
                cycles: 7,
                ..Default::default()
            })
        });
        let e = until_exit_or_gateway_end(std::future::pending::<()>(), &mut returned, "full")
            .await
            .unwrap_err();
        assert!(
            e.to_string().contains("(full) stopped after 7 cycles"),
            "{e}"
        );
        // The machine's exit first: its status, the gateway left running for the caller to stop.
        let mut running = tokio::spawn(std::future::pending());
        let ended = until_exit_or_gateway_end(async { 3 }, &mut running, "full").await;
        assert_eq!(ended.unwrap(), 3);
        assert!(!running.is_finished());
        running.abort();
    }

    #[test]
    fn template_is_filled_completely() {
        let s = sim_config(3, Path::new("/m/t.toml"), 4242, 20.0, Path::new("/o/pty"));
        assert_eq!(s.matches("G1 X150\nG1 X0\n").count(), 4, "{s}");
        assert_eq!(warmup_gcode(0.0).lines().count(), 2);
        assert!(!s.contains('@'), "unfilled placeholder");
        assert!(s.contains("port = 4242") && s.contains("model_path = \"/m/t.toml\""));
        let v: toml::Table = toml::from_str(&s).unwrap();
        assert_eq!(v["seed"].as_integer(), Some(3));
        let rt: toml::Table = toml::from_str(&with_realtime_priority(&s, Some(20))).unwrap();
        assert_eq!(rt["clock"]["realtime_priority"].as_integer(), Some(20));
        assert_eq!(with_realtime_priority(&s, None), s);
    }

    #[test]
    fn repeated_runs_the_pass_n_times_after_one_dwell() {
        let one = sim_config(3, Path::new("/m/t.toml"), 4242, 10.0, Path::new("/o/pty"));
        let three = repeated(&one, 3);
        let v: toml::Table = toml::from_str(&three).unwrap();
        let g = v["program"]["gcode"].as_str().unwrap();
        assert_eq!(g.matches("G4 P1.0").count(), 1, "{g}");
        assert_eq!(g.matches("M30").count(), 1);
        assert!(g.trim_end().ends_with("M30"));
        assert_eq!(g.matches("(the part:").count(), 3);
        assert_eq!(
            g.matches("G1 X150\nG1 X0\n").count(),
            3 * 2,
            "two warm-up pairs a pass"
        );
        assert_eq!(v["clock"]["max_duration_s"].as_float(), Some(600.0));
        assert_eq!(v["record"]["every_s"].as_float(), Some(0.5));
    }
}
