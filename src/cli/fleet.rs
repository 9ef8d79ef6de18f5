//! `retrocomp fleet --broker HOST:PORT [--group G] [--every-s S] [--seconds N] [--json]`: a
//! Sparkplug B host that shows every box's health (alive, compensating, degraded, idle) from its
//! NBIRTH/NDATA/NDEATH (src/telemetry/fleet.rs). Prints the table every `--every-s`; with
//! `--seconds` it stops after that long (with `--json`: one JSON array of the nodes on stdout).

use std::time::Duration;

use anyhow::Context as _;
use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};

use crate::telemetry::fleet::FleetView;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// MQTT broker, HOST:PORT.
    #[arg(long)]
    pub broker: String,
    /// Sparkplug group to watch (default: every group).
    #[arg(long)]
    pub group: Option<String>,
    /// Print the table this often, s.
    #[arg(long, default_value_t = 5.0)]
    pub every_s: f64,
    /// Stop after this many seconds (default: run until interrupted).
    #[arg(long)]
    pub seconds: Option<f64>,
    /// At the end, print the nodes as one JSON array instead of the table.
    #[arg(long)]
    pub json: bool,
}

/// The MQTT shell around [`FleetView`]: one subscription to `spBv1.0/<group>/+/+` (QoS 1),
/// renewed on every reconnect.
pub struct FleetClient {
    client: AsyncClient,
    events: rumqttc::EventLoop,
    topic: String,
    pub view: FleetView,
    /// The broker acknowledged the subscription (messages from now on are seen).
    pub subscribed: bool,
}

impl FleetClient {
    /// `broker` is HOST:PORT; `group` None watches every group.
    pub fn new(broker: &str, group: Option<&str>) -> anyhow::Result<Self> {
        let (host, port) = broker
            .rsplit_once(':')
            .and_then(|(h, p)| Some((h.to_string(), p.parse::<u16>().ok()?)))
            .with_context(|| format!("--broker {broker}: expected HOST:PORT"))?;
        let id = format!("retrocomp-fleet-{}-{port}", std::process::id());
        let mut o = MqttOptions::new(id, host, port);
        o.set_keep_alive(Duration::from_secs(10));
        o.set_max_packet_size(1 << 20, 1 << 20);
        let (client, events) = AsyncClient::new(o, 64);
        Ok(FleetClient {
            client,
            events,
            topic: format!("spBv1.0/{}/+/+", group.unwrap_or("+")),
            view: FleetView::default(),
            subscribed: false,
        })
    }

    /// Wait for the next event; true when a Sparkplug message changed the view. A link error
    /// is returned after a 500 ms pause (the next call reconnects).
    pub async fn poll(&mut self) -> anyhow::Result<bool> {
        match self.events.poll().await {
            Ok(Event::Incoming(Packet::ConnAck(_))) => {
                self.subscribed = false;
                self.client
                    .try_subscribe(self.topic.clone(), QoS::AtLeastOnce)?;
                Ok(false)
            }
            Ok(Event::Incoming(Packet::SubAck(_))) => {
                self.subscribed = true;
                Ok(false)
            }
            Ok(Event::Incoming(Packet::Publish(p))) => {
                self.view.ingest(&p.topic, &p.payload);
                Ok(true)
            }
            Ok(_) => Ok(false),
            Err(e) => {
                tokio::time::sleep(Duration::from_millis(500)).await;
                Err(e.into())
            }
        }
    }
}

pub fn run(args: &Args) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.every_s.is_finite() && args.every_s > 0.0,
        "--every-s must be > 0"
    );
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    rt.block_on(async {
        let mut fc = FleetClient::new(&args.broker, args.group.as_deref())?;
        let mut every = tokio::time::interval(Duration::from_secs_f64(args.every_s));
        let end = tokio::time::sleep(Duration::from_secs_f64(args.seconds.unwrap_or(1e9)));
        tokio::pin!(end);
        let mut warned = false;
        loop {
            tokio::select! {
                _ = &mut end => break,
                _ = every.tick() => if !args.json { print!("{}", fc.view.table()) },
                r = fc.poll() => match r {
                    Ok(_) => warned = false,
                    Err(e) => {
                        if !warned {
                            eprintln!("retrocomp fleet: {}: {e}; retrying", args.broker);
                            warned = true;
                        }
                    }
                },
            }
        }
        if args.json {
            let mut nodes = Vec::new();
            for n in fc.view.nodes.values() {
                let mut v = serde_json::to_value(n)?;
                v["verdict"] = serde_json::to_value(n.verdict())?;
                nodes.push(v);
            }
            println!("{}", serde_json::Value::Array(nodes));
        } else {
            print!("{}", fc.view.table());
        }
        Ok(())
    })
}
