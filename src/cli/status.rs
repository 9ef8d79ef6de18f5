//! `retrocomp status`: ask a running gateway (its read-only HTTP endpoint, 127.0.0.1:9184 by default)
//! for per-axis corrections, their breakdown by term, and sensor health.

use std::time::Duration;

use anyhow::{Context, bail};

use retrocomp_gateway::northbound::http::get;

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Address of the gateway's status endpoint (`[gateway] status_listen`).
    #[arg(long, default_value = "127.0.0.1:9184")]
    pub addr: String,
    /// Print the raw JSON snapshot.
    #[arg(long, conflicts_with = "metrics")]
    pub json: bool,
    /// Print the Prometheus metrics.
    #[arg(long)]
    pub metrics: bool,
}

pub(crate) fn run(args: &Args) -> anyhow::Result<()> {
    let path = if args.json {
        "/status"
    } else if args.metrics {
        "/metrics"
    } else {
        "/text"
    };
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let (code, body) = rt
        .block_on(get(&args.addr, path, Duration::from_secs(3)))
        .with_context(|| {
            format!(
                "no gateway answering on {} (is `retrocomp run` up?)",
                args.addr
            )
        })?;
    if code != 200 {
        bail!("gateway at {} answered {code}: {}", args.addr, body.trim());
    }
    print!("{body}");
    Ok(())
}
