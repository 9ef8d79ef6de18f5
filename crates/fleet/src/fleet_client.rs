//! The MQTT shell of a Sparkplug B host around the sans-IO [`FleetView`] (crates/fleet/src/fleet.rs):
//! one subscription to `spBv1.0/<group>/+/+` (QoS 1) over TCP or TLS, renewed on every reconnect, the view's
//! rebirth requests published as NCMD (QoS 0, not retained, as Sparkplug 3.0 says for NCMD), and
//! optionally the recordings topic fed to a [`Collector`] and the diagnose workers' topics fed to a
//! [`Dispatcher`] (crates/fleet/src/dispatch.rs; its jobs and grants published QoS 1). Used by `retrocomp fleet`, the MQTT tests and the
//! fleet bench. Units as in [`FleetView`].

use std::path::PathBuf;
use std::time::Duration;

use rumqttc::{AsyncClient, Event, MqttOptions, Packet, QoS};

use crate::dispatch::{self, Dispatcher};
use crate::fleet::FleetView;
use retrocomp_gateway::northbound::telemetry::TelemetryError;
use retrocomp_gateway::northbound::telemetry::now_ms;
use retrocomp_gateway::northbound::telemetry::recordings::{Collector, Took};
use retrocomp_gateway::northbound::telemetry::tls;
use retrocomp_gateway::northbound::telemetry::{TlsConfig, broker_host_port};

/// Why the fleet client could not be built or lost its link.
#[derive(Debug, thiserror::Error)]
pub enum FleetClientError {
    /// The broker address is not HOST:PORT (a non-empty host, a port 1..=65535).
    #[error("--broker {0}: expected HOST:PORT")]
    Broker(String),
    /// The subscription request could not be queued.
    #[error(transparent)]
    Subscribe(#[from] rumqttc::ClientError),
    /// The TLS files cannot be used (which file, and why).
    #[error(transparent)]
    Tls(#[from] TelemetryError),
    /// The link to the broker failed (the next poll reconnects).
    #[error(transparent)]
    Connection(#[from] Box<rumqttc::ConnectionError>),
}

/// The MQTT shell around [`FleetView`]: one subscription to `spBv1.0/<group>/+/+` (QoS 1),
/// renewed on every reconnect.
pub struct FleetClient {
    client: AsyncClient,
    events: rumqttc::EventLoop,
    topic: String,
    pub view: FleetView,
    /// Recordings collected from `recordings_topic`, when collecting.
    pub collector: Option<(Collector, String)>,
    /// Diagnose jobs shared out to workers, when dispatching.
    pub dispatch: Option<Dispatcher>,
    /// The broker acknowledged the subscription (messages from now on are seen).
    pub subscribed: bool,
    subacks: u32,
}

// By hand: rumqttc's event loop has no Debug.
impl std::fmt::Debug for FleetClient {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FleetClient")
            .field("topic", &self.topic)
            .field("subscribed", &self.subscribed)
            .finish_non_exhaustive()
    }
}

impl FleetClient {
    /// `broker` is HOST:PORT; `group` None watches every group.
    pub fn new(broker: &str, group: Option<&str>) -> Result<Self, FleetClientError> {
        Self::with_tls(broker, group, None)
    }

    /// As [`FleetClient::new`], over TLS when `tls` is given (the same files and checks as a
    /// box's `[telemetry.mqtt.tls]`).
    pub fn with_tls(
        broker: &str,
        group: Option<&str>,
        tls: Option<&TlsConfig>,
    ) -> Result<Self, FleetClientError> {
        let (host, port) =
            host_port(broker).ok_or_else(|| FleetClientError::Broker(broker.to_string()))?;
        let id = format!("retrocomp-fleet-{}-{port}", std::process::id());
        let mut o = MqttOptions::new(id, host, port);
        o.set_keep_alive(Duration::from_secs(10));
        o.set_max_packet_size(1 << 20, 1 << 20);
        if let Some(t) = tls {
            o.set_transport(rumqttc::Transport::tls_with_config(
                rumqttc::TlsConfiguration::Rustls(std::sync::Arc::new(tls::client_config(t)?)),
            ));
        }
        let (client, events) = AsyncClient::new(o, 64);
        Ok(FleetClient {
            client,
            events,
            topic: format!("spBv1.0/{}/+/+", group.unwrap_or("+")),
            view: FleetView::default(),
            collector: None,
            dispatch: None,
            subscribed: false,
            subacks: 0,
        })
    }

    /// Also collect recordings published on `topic` (a filter) into `dir`.
    pub fn collect(&mut self, dir: PathBuf, topic: &str) {
        self.collector = Some((Collector::new(dir), topic.to_string()));
    }

    /// Wait for the next event (or a deferred rebirth request falling due); true when a
    /// Sparkplug message changed the view. A link error is returned after a 500 ms pause (the
    /// next call reconnects).
    pub async fn poll(&mut self) -> Result<bool, FleetClientError> {
        let due = match (self.view.poll_timeout(), self.dispatch.as_ref()) {
            (v, Some(d)) => v.into_iter().chain(d.poll_timeout()).min(),
            (v, None) => v,
        };
        let wait = due.map(|due| Duration::from_millis(due.saturating_sub(now_ms())));
        let ev = tokio::select! {
            ev = self.events.poll() => ev,
            _ = tokio::time::sleep(wait.unwrap_or_default()), if wait.is_some() => {
                self.send_pending()?;
                return Ok(false);
            }
        };
        let r = self.handle(ev).await;
        self.send_pending()?;
        r
    }

    /// Publish the view's pending NCMDs, and the dispatcher's jobs and grants (a full request
    /// queue leaves those for the next poll).
    pub fn send_pending(&mut self) -> Result<(), FleetClientError> {
        while let Some((topic, payload)) = self.view.poll_transmit(now_ms()) {
            tracing::debug!(topic, "fleet: rebirth requested");
            self.client
                .try_publish(topic, QoS::AtMostOnce, false, payload)?;
        }
        if let Some(d) = &mut self.dispatch {
            while let Some((topic, payload)) = d.poll_transmit(now_ms()) {
                let msg = (topic.clone(), payload.clone());
                if self
                    .client
                    .try_publish(topic, QoS::AtLeastOnce, false, payload)
                    .is_err()
                {
                    d.unsend(msg);
                    break;
                }
            }
        }
        Ok(())
    }

    async fn handle(
        &mut self,
        ev: Result<Event, rumqttc::ConnectionError>,
    ) -> Result<bool, FleetClientError> {
        match ev {
            Ok(Event::Incoming(Packet::ConnAck(_))) => {
                self.subscribed = false;
                self.subacks = 0;
                self.client
                    .try_subscribe(self.topic.clone(), QoS::AtLeastOnce)?;
                if let Some((_, t)) = &self.collector {
                    self.client.try_subscribe(t.clone(), QoS::AtLeastOnce)?;
                }
                if self.dispatch.is_some() {
                    self.client.try_subscribe_many(
                        dispatch::host_filters()
                            .map(|f| rumqttc::SubscribeFilter::new(f, QoS::AtLeastOnce)),
                    )?;
                }
                Ok(false)
            }
            Ok(Event::Incoming(Packet::SubAck(_))) => {
                // Subscribed once every SUBACK is in (one to three subscribe requests).
                self.subacks += 1;
                let want =
                    1 + u32::from(self.collector.is_some()) + u32::from(self.dispatch.is_some());
                self.subscribed = self.subacks >= want;
                Ok(false)
            }
            Ok(Event::Incoming(Packet::Publish(p)))
                if p.topic.starts_with("retrocomp/diagnose/") =>
            {
                if let Some(d) = &mut self.dispatch {
                    d.handle_message(&p.topic, &p.payload, now_ms());
                }
                Ok(false)
            }
            Ok(Event::Incoming(Packet::Publish(p))) if p.topic.starts_with("spBv1.0/") => {
                Ok(self.view.handle_message(&p.topic, &p.payload, now_ms()))
            }
            Ok(Event::Incoming(Packet::Publish(p))) => {
                if let Some((c, _)) = &mut self.collector {
                    match c.handle_payload(&p.payload) {
                        Ok(Took::Written(Some(path))) => {
                            tracing::info!(path = %path.display(), "fleet: recording collected");
                        }
                        Ok(Took::Refused(why)) => {
                            tracing::warn!(topic = p.topic, why, "fleet: recording chunk refused");
                        }
                        Ok(_) => {}
                        Err(e) => tracing::error!(%e, "fleet: cannot write a recording"),
                    }
                }
                Ok(false)
            }
            Ok(_) => Ok(false),
            Err(e) => {
                tokio::time::sleep(Duration::from_millis(500)).await;
                Err(Box::new(e).into())
            }
        }
    }
}

/// `HOST:PORT` of a broker given on the command line (the host's and the workers' `--broker`),
/// by the box's rule for its broker (a non-empty host, a port 1..=65535, `[v6]:port`).
pub(crate) fn host_port(broker: &str) -> Option<(String, u16)> {
    broker_host_port(broker).ok()
}

#[cfg(test)]
mod tests {
    use super::host_port;

    #[test]
    fn a_broker_is_a_host_and_a_port_1_to_65535_by_the_boxs_rule() {
        assert_eq!(host_port("broker:1883"), Some(("broker".into(), 1883)));
        assert_eq!(host_port("[::1]:8883"), Some(("::1".into(), 8883)));
        for bad in ["broker", ":1883", "broker:0", "broker:65536", "broker:x"] {
            assert_eq!(host_port(bad), None, "{bad}");
        }
    }
}
