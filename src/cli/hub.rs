//! `retrocomp hub --listen 127.0.0.1:29536`: a socketcand-protocol CAN hub on TCP (the one `retrocomp
//! demo` and the tests start in-process, `bus::can::hub`), as a command. Both `hil-sim serve` and
//! `retrocomp run` are socketcand *clients*, so a bench setup without CAN hardware needs this hub in
//! between (docs/walkthrough.md). python-can's `socketcand` interface joins it too.
//!
//! Prints `retrocomp hub: listening on ADDR` on stdout once bound (with `--listen 127.0.0.1:0` that is
//! the ephemeral port), then serves until SIGINT/SIGTERM and prints its frame counters.

use std::io::Write as _;
use std::net::SocketAddr;
use std::sync::atomic::Ordering;

use anyhow::Context;

use retrocomp_bus::can::{Hub, HubStats};

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// Address to listen on. Keep it on loopback: the socketcand protocol has no authentication.
    #[arg(long, default_value = "127.0.0.1:29536")]
    pub listen: SocketAddr,
}

fn counters(s: &HubStats) -> String {
    format!(
        "clients {}, frames in {}, out {}, dropped {}, bad messages {}",
        s.clients_connected.load(Ordering::Relaxed),
        s.frames_in.load(Ordering::Relaxed),
        s.frames_out.load(Ordering::Relaxed),
        s.frames_dropped.load(Ordering::Relaxed),
        s.bad_messages.load(Ordering::Relaxed),
    )
}

pub(crate) fn run(args: &Args) -> anyhow::Result<()> {
    super::term::init_tracing("info");
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    rt.block_on(async {
        let hub = Hub::start(args.listen)
            .await
            .with_context(|| format!("cannot listen on {}", args.listen))?;
        // stdout, flushed: scripts and tests read the bound address from this line.
        println!("retrocomp hub: listening on {}", hub.local_addr());
        std::io::stdout().flush()?;
        let mut term = tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate())?;
        tokio::select! {
            r = tokio::signal::ctrl_c() => r?,
            _ = term.recv() => {}
        }
        println!("retrocomp hub: stopped; {}", counters(hub.stats()));
        Ok(())
    })
}
