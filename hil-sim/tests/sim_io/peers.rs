//! The simulator's Modbus registers read by a third-party client, mbpoll (Debian package; install with
//! scripts/setup-peers.sh), over TCP and over RTU on the simulator's pty. A missing mbpoll FAILS.

use hil_sim::SimConfig;
use hil_sim::io::serve::start;
use std::process::Command;

fn config(io: &str) -> SimConfig {
    let toml = format!(
        r#"
[clock]
realtime = true
[program]
script = [{{ t_s = 0.0, x_mm = 0.0, y_mm = 0.0, z_mm = 0.0 }}, {{ t_s = 3.0, x_mm = 0.0, y_mm = 0.0, z_mm = 0.0 }}]
[hidden.thermal]
ambient_C = 19.5
nodes = [{{ name = "spindle", tau_s = 100.0, start_C = 24.7 }}]
sensors = [{{ name = "spindle", node = "spindle" }}, {{ name = "room", node = "ambient" }}]
{io}
"#
    );
    SimConfig::from_toml_str(&toml, None).unwrap()
}

async fn mbpoll(args: Vec<String>) -> String {
    let out = tokio::task::spawn_blocking(move || Command::new("mbpoll").args(&args).output())
        .await
        .unwrap()
        .unwrap_or_else(|e| panic!("mbpoll not runnable ({e}): run scripts/setup-peers.sh"));
    let stdout = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(
        out.status.success(),
        "mbpoll failed: {stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    stdout
}

fn assert_temps(stdout: &str) {
    // mbpoll -t 3 prints input registers as `[1]: 247` (1-based reference).
    assert!(
        stdout.contains("[1]: \t247") || stdout.contains("[1]: 247"),
        "{stdout}"
    );
    assert!(
        stdout.contains("[2]: \t195") || stdout.contains("[2]: 195"),
        "{stdout}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mbpoll_reads_pt100_registers_over_tcp() {
    let running = start(
        config("[io.modbus]\ntcp_bind = \"127.0.0.1:0\"\n"),
        None,
        None,
    )
    .await
    .unwrap();
    tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    let port = running.modbus_tcp.unwrap().port().to_string();
    let args = [
        "-m",
        "tcp",
        "-p",
        &port,
        "-a",
        "1",
        "-t",
        "3",
        "-r",
        "1",
        "-c",
        "2",
        "-1",
        "127.0.0.1",
    ];
    assert_temps(&mbpoll(args.iter().map(|s| s.to_string()).collect()).await);
    running.abort();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn mbpoll_reads_pt100_registers_over_rtu_on_the_pty() {
    let dir = tempfile::tempdir().unwrap();
    let io = format!(
        "[io.modbus]\nrtu_pty_link = \"{}\"\nrtu_slave = 3\n",
        dir.path().join("rtu").display()
    );
    let running = start(config(&io), None, None).await.unwrap();
    tokio::time::sleep(std::time::Duration::from_millis(200)).await;
    let dev = running.rtu_pty.clone().unwrap().display().to_string();
    let args = [
        "-m", "rtu", "-b", "19200", "-P", "none", "-a", "3", "-t", "3", "-r", "1", "-c", "2", "-1",
        &dev,
    ];
    assert_temps(&mbpoll(args.iter().map(|s| s.to_string()).collect()).await);
    running.abort();
}
