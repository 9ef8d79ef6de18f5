//! `retrocomp fleet-worker --broker HOST:PORT --collect-dir D --models M --id W`: one of N processes
//! that share the fleet's diagnoses (`retrocomp fleet --workers`) through an MQTT 5 shared
//! subscription; each job is diagnosed only after the fleet host granted it to this worker
//! (crates/fleet/src/dispatch.rs, crates/fleet/src/worker.rs). Prints one JSON line per job it
//! finished (`{"job", "worker", "group", "edge_node", "recording", "state", "rms_um", "took_ms"}`);
//! says on stderr when it is subscribed and which job it was granted. Runs until interrupted.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context as _;

use retrocomp_fleet::worker::{self, WorkerConfig, WorkerEvent};

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// MQTT broker (MQTT 5), HOST:PORT.
    #[arg(long)]
    pub broker: String,
    /// The directory the fleet collects recordings into (the same files: a share).
    #[arg(long)]
    pub collect_dir: PathBuf,
    /// Machine models, DIR/EDGE_NODE.toml.
    #[arg(long)]
    pub models: PathBuf,
    /// This worker's name, unique among the workers.
    #[arg(long)]
    pub id: String,
    /// Claim a job again when the fleet host answered nothing within this long, s.
    #[arg(long, default_value_t = 10.0)]
    pub claim_retry_s: f64,
    /// Wait this long after a grant before diagnosing, ms (tests kill a worker holding a job).
    #[arg(long, default_value_t = 0, hide = true)]
    pub hold_after_grant_ms: u64,
}

pub(crate) fn run(args: &Args) -> anyhow::Result<()> {
    let claim_retry = Duration::try_from_secs_f64(args.claim_retry_s)
        .ok()
        .filter(|d| !d.is_zero())
        .context("--claim-retry-s must be > 0")?;
    anyhow::ensure!(
        !args.id.is_empty() && !args.id.contains(['/', '+', '#']),
        "--id must be a non-empty MQTT topic level (no '/', '+', '#')"
    );
    let cfg = WorkerConfig {
        broker: args.broker.clone(),
        id: args.id.clone(),
        collect_dir: args.collect_dir.clone(),
        models: args.models.clone(),
        hold_after_grant: Duration::from_millis(args.hold_after_grant_ms),
        claim_retry,
    };
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let (broker, id) = (args.broker.clone(), args.id.clone());
    let mut warned = false;
    rt.block_on(worker::run(cfg, |ev| match ev {
        WorkerEvent::Subscribed => {
            warned = false;
            eprintln!("retrocomp fleet-worker {id}: subscribed at {broker}");
        }
        WorkerEvent::Granted(j) => {
            eprintln!(
                "retrocomp fleet-worker {id}: granted job {} ({}/{})",
                j.job, j.group, j.edge_node
            );
        }
        WorkerEvent::Done(d) => match serde_json::to_string(d) {
            Ok(line) => println!("{line}"),
            Err(e) => eprintln!("retrocomp fleet-worker {id}: {e}"),
        },
        WorkerEvent::Link(e) => {
            if !warned {
                eprintln!("retrocomp fleet-worker {id}: {broker}: {e}; retrying");
                warned = true;
            }
        }
    }))?;
    Ok(())
}
