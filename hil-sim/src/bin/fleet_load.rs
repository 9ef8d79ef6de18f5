//! `fleet_load boxes|host`: the two processes of the multi-process fleet load test
//! (benches/fleet_processes.rs and its test in tests/real_peers/telemetry_fleet_host.rs), so boxes and the
//! fleet host run as separate OS processes with exactly the library code that ships.
//! - `boxes`: K simulated boxes in this process (crates/fleet/src/load.rs), each the real Sparkplug
//!   publisher over TCP or TLS; once all are connected and born one JSON line `{"connected": N}`
//!   (with `--wait-go`, then a line on stdin), then `--seconds` more; then every box finishes (queue acknowledged, NDEATH) and one JSON
//!   line reports `{"boxes", "produced", "dropped", "left"}`.
//! - `host`: the fleet host's MQTT client and view (crates/fleet/src/fleet_client.rs), printing its
//!   totals as one JSON line every `--every-ms` (`{"subscribed", "ndata", "gaps", "nodes",
//!   "offline", "births", "latency": {"n", "p50_ms", "p99_ms", "max_ms"}}`) until killed; a
//!   line `reset` on its stdin restarts the latency from records sampled from then on.
//!
//! Test-only: part of hil-sim (the world around the box, here a fleet of boxes), never of the
//! `retrocomp` package, so the Debian package does not ship it.

use std::path::PathBuf;
use std::time::Duration;

use retrocomp_fleet::FleetClient;
use retrocomp_fleet::load::{self, HostTotals};
use retrocomp_gateway::northbound::telemetry::MqttConfig;
use retrocomp_gateway::northbound::telemetry::TlsConfig;
use retrocomp_gateway::northbound::telemetry::now_ms;

#[derive(Debug, clap::Parser)]
#[command(
    name = "fleet_load",
    about = "The processes of the multi-process fleet load test"
)]
struct Args {
    #[command(subcommand)]
    role: Role,
}

#[derive(Debug, clap::Subcommand)]
enum Role {
    /// Simulated boxes publishing Sparkplug B; one JSON report line at the end.
    Boxes(BoxesArgs),
    /// The fleet host; one JSON line of totals every --every-ms.
    Host(HostArgs),
}

#[derive(Debug, clap::Args)]
struct Link {
    /// MQTT broker, HOST:PORT.
    #[arg(long)]
    broker: String,
    /// Sparkplug group.
    #[arg(long, default_value = "fleet")]
    group: String,
    /// PEM CA of the broker's certificate: connect over TLS.
    #[arg(long)]
    tls_ca_file: Option<PathBuf>,
}

impl Link {
    fn tls(&self) -> Option<TlsConfig> {
        self.tls_ca_file.clone().map(TlsConfig::with_ca)
    }
}

#[derive(Debug, clap::Args)]
struct BoxesArgs {
    #[command(flatten)]
    link: Link,
    /// Number of the first box (edge nodes `box-<first>` …).
    #[arg(long, default_value_t = 0)]
    first: usize,
    /// Boxes in this process.
    #[arg(long, default_value_t = 100)]
    count: usize,
    /// Telemetry rate of each box, Hz.
    #[arg(long, default_value_t = 10.0)]
    rate_hz: f64,
    /// How long the boxes publish, s (then they finish).
    #[arg(long, default_value_t = 60.0)]
    seconds: f64,
    /// After the `connected` line, wait for a line on stdin before the `--seconds` start.
    #[arg(long)]
    wait_go: bool,
    /// How long each box may take to connect, and to finish sending its queue, s.
    #[arg(long, default_value_t = 120.0)]
    finish_s: f64,
}

#[derive(Debug, clap::Args)]
struct HostArgs {
    #[command(flatten)]
    link: Link,
    /// Print the totals this often, ms.
    #[arg(long, default_value_t = 200)]
    every_ms: u64,
}

fn main() -> anyhow::Result<()> {
    let args = <Args as clap::Parser>::parse();
    // One thread per process: the load test runs many of these beside the broker.
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    match &args.role {
        Role::Boxes(a) => {
            anyhow::ensure!(
                a.rate_hz.is_finite() && a.rate_hz > 0.0,
                "--rate-hz must be > 0"
            );
            anyhow::ensure!(
                a.seconds.is_finite() && a.seconds >= 0.0,
                "--seconds must be >= 0"
            );
            let mut cfg = MqttConfig::new(&a.link.broker, &a.link.group, "box");
            cfg.rate_hz = a.rate_hz;
            cfg.tls = a.link.tls();
            let grace = Duration::from_secs_f64(a.finish_s.max(0.0));
            let wait_go = a.wait_go;
            let connected = |n: usize| async move {
                println!("{}", serde_json::json!({ "connected": n }));
                if wait_go {
                    // Off the runtime's only thread: the boxes keep publishing meanwhile.
                    let _ = tokio::task::spawn_blocking(|| {
                        std::io::stdin().read_line(&mut String::new())
                    })
                    .await;
                }
            };
            let r = rt.block_on(load::run_boxes(
                &cfg,
                (a.first, a.count),
                a.seconds,
                grace,
                connected,
            ))?;
            println!("{}", serde_json::to_string(&r)?);
            Ok(())
        }
        Role::Host(a) => rt.block_on(async {
            let tls = a.link.tls();
            let mut fc = FleetClient::with_tls(&a.link.broker, Some(&a.link.group), tls.as_ref())?;
            let mut every = tokio::time::interval(Duration::from_millis(a.every_ms.max(1)));
            // A line `reset` on stdin starts the latency histogram again (from records sampled
            // from now on): the driver sends it once every box is connected.
            let (reset_tx, mut reset) = tokio::sync::mpsc::unbounded_channel();
            std::thread::spawn(move || {
                for l in std::io::stdin().lines().map_while(Result::ok) {
                    if l.trim() == "reset" && reset_tx.send(()).is_err() {
                        break;
                    }
                }
            });
            loop {
                tokio::select! {
                    Some(()) = reset.recv() => fc.view.reset_latency(now_ms()),
                    r = fc.poll() => if let Err(e) = r { tracing::warn!(%e, "fleet-load host") },
                    _ = every.tick() => {
                        println!("{}", serde_json::to_string(&HostTotals::of(&fc.view, fc.subscribed))?);
                    }
                }
            }
        }),
    }
}
