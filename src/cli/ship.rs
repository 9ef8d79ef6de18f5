//! `retrocomp ship-recording`: a box sends a recording (docs/recording-csv.md CSV) to the fleet — over MQTT
//! (chunked, ordered, resumable: crates/gateway/src/northbound/telemetry/shipper.rs) or into a directory in the collection
//! layout `<dir>/<group>/<edge node>/<name>` (crates/gateway/src/northbound/telemetry/recordings.rs). Broker, TLS,
//! credentials, group and edge node come from a field config's `[telemetry.mqtt]` (`--config`) or
//! from `--broker/--group/--edge-node`.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context as _;

use retrocomp_gateway::northbound::telemetry::MqttConfig;
use retrocomp_gateway::northbound::telemetry::recordings::{chunk_csv, ship_to_dir};
use retrocomp_gateway::northbound::telemetry::{Shipment, default_topic, ship};

#[derive(Debug, clap::Args)]
pub(crate) struct Args {
    /// The recording CSV to send. Without it, only what an interrupted shipment left in
    /// `--queue-dir` is sent.
    #[arg(long)]
    pub recording: Option<PathBuf>,
    /// Name under which the fleet stores it (default: the file's name).
    #[arg(long)]
    pub name: Option<String>,
    /// Field config whose `[telemetry.mqtt]` gives broker, TLS, credentials, group and edge node.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// MQTT broker HOST:PORT (instead of --config).
    #[arg(long)]
    pub broker: Option<String>,
    /// Sparkplug group of this box (instead of --config).
    #[arg(long)]
    pub group: Option<String>,
    /// Sparkplug edge node id of this box (instead of --config).
    #[arg(long)]
    pub edge_node: Option<String>,
    /// Topic (default `retrocomp/recordings/<group>/<edge node>`).
    #[arg(long)]
    pub topic: Option<String>,
    /// Store-and-forward queue directory: a shipment cut short resumes from it.
    #[arg(long)]
    pub queue_dir: Option<PathBuf>,
    /// Rows per chunk.
    #[arg(long, default_value_t = 500)]
    pub rows_per_chunk: usize,
    /// Give up after this long (what is left stays in --queue-dir), s.
    #[arg(long, default_value_t = 600.0)]
    pub timeout_s: f64,
    /// Write into this collection directory instead of MQTT.
    #[arg(long)]
    pub to_dir: Option<PathBuf>,
}

fn mqtt_config(a: &Args) -> anyhow::Result<MqttConfig> {
    let mut m = match &a.config {
        Some(p) => {
            let cfg = retrocomp_gateway::config::FieldConfig::load(p)
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            cfg.telemetry
                .and_then(|t| t.mqtt)
                .with_context(|| format!("{}: no [telemetry.mqtt]", p.display()))?
        }
        None => MqttConfig::new(
            a.broker.as_deref().unwrap_or_default(),
            a.group.as_deref().context("--group (or --config)")?,
            a.edge_node
                .as_deref()
                .context("--edge-node (or --config)")?,
        ),
    };
    if let Some(b) = &a.broker {
        m.broker = b.clone();
    }
    if let Some(g) = &a.group {
        m.group_id = g.clone();
    }
    if let Some(n) = &a.edge_node {
        m.edge_node_id = n.clone();
    }
    Ok(m)
}

pub(crate) fn run(a: &Args) -> anyhow::Result<()> {
    let m = mqtt_config(a)?;
    let rec = match &a.recording {
        Some(p) => {
            let text =
                std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
            let name = match &a.name {
                Some(n) => n.clone(),
                None => p
                    .file_name()
                    .and_then(|n| n.to_str())
                    .context("recording file name")?
                    .to_string(),
            };
            Some((name, text))
        }
        None => None,
    };
    if let Some(dir) = &a.to_dir {
        let (name, text) = rec.context("--to-dir needs --recording")?;
        let p = ship_to_dir(dir, &m.group_id, &m.edge_node_id, &name, &text)?;
        println!("{}", serde_json::json!({ "written": p }));
        return Ok(());
    }
    m.host_port()
        .map_err(|e| anyhow::anyhow!("--broker / telemetry.mqtt.broker: {e}"))?;
    let chunks = match &rec {
        Some((name, text)) => {
            chunk_csv(&m.group_id, &m.edge_node_id, name, text, a.rows_per_chunk)?
        }
        None => vec![],
    };
    let s = Shipment {
        topic: a
            .topic
            .clone()
            .unwrap_or_else(|| default_topic(&m.group_id, &m.edge_node_id)),
        queue_dir: a.queue_dir.clone(),
        mqtt: m,
    };
    anyhow::ensure!(
        a.timeout_s.is_finite() && a.timeout_s > 0.0,
        "--timeout-s must be > 0"
    );
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let r = rt.block_on(ship(&s, &chunks, Duration::from_secs_f64(a.timeout_s)))?;
    println!(
        "{}",
        serde_json::json!({ "acked": r.acked, "left": r.left, "connections": r.connections, "topic": s.topic })
    );
    anyhow::ensure!(
        r.left == 0,
        "{} chunks not acknowledged within {} s; they stay in --queue-dir (run again to resume)",
        r.left,
        a.timeout_s
    );
    Ok(())
}
