//! The runtime's plant-facing servers, started once per run beside the cycle: the status
//! endpoint (HTTP: `/status`, `/metrics`, the page behind `web`, the token-guarded actions), the
//! OPC UA server (feature `opcua`) and the Sparkplug publisher (feature `mqtt`). Each reads the
//! status snapshots on its own tasks and can never slow the cycle. In a build without a feature
//! its server's type has no value, and a field file that configures it was refused at load.

use std::net::SocketAddr;
use std::sync::Arc;
#[cfg(not(feature = "mqtt"))]
use std::time::Duration;

use tokio::sync::{mpsc, oneshot, watch};

use crate::config::FieldConfig;
use crate::error::GatewayError;
use crate::northbound::http::{Api, Control, Limits, serve};
#[cfg(feature = "opcua")]
pub(crate) use crate::northbound::opcua::OpcUaServer;
#[cfg(feature = "mqtt")]
pub(crate) use crate::northbound::telemetry::Publisher;
use crate::status::{ModelIdentity, StatusSnapshot};

/// The status endpoint (GET /status, /metrics and the token-guarded actions, which reach the
/// cycle through `control_tx`) and, if configured, the OPC UA server; both read the status
/// snapshots on their own tasks (OPC UA names the model by `identity`). The bound status address
/// goes to `status_addr`.
pub(crate) async fn start_endpoints(
    cfg: &FieldConfig,
    status_rx: watch::Receiver<Option<Arc<StatusSnapshot>>>,
    control_tx: mpsc::Sender<Control>,
    #[cfg_attr(not(feature = "opcua"), allow(unused_variables))] identity: Option<ModelIdentity>,
    status_addr: Option<oneshot::Sender<SocketAddr>>,
) -> Result<(Option<OpcUaServer>, tokio::task::JoinHandle<()>), GatewayError> {
    let listen: SocketAddr = cfg
        .gateway
        .status_listen
        .parse()
        .map_err(|e| GatewayError::setup("gateway.status_listen", e))?;
    let api = Api {
        token: cfg.gateway.api_token.clone(),
        control_tx: Some(control_tx),
        models: Some(Arc::new(cfg.model_catalog())),
    };
    let opcua = match &cfg.opcua {
        #[cfg(feature = "opcua")]
        Some(o) => {
            let rx = status_rx.clone();
            let srv = crate::northbound::opcua::start(o, &cfg.gateway.name, rx, identity).await?;
            tracing::info!("OPC UA endpoint {} (read-only)", srv.endpoint);
            Some(srv)
        }
        // Refused at load already (`FieldConfig::validate`); kept so the match is total.
        #[cfg(not(feature = "opcua"))]
        Some(_) => return Err(GatewayError::Refused(NOT_BUILT_OPCUA.into())),
        None => None,
    };
    let limits = Limits {
        policy: cfg.gateway.listen_policy.clone(),
        ..Limits::default()
    };
    let (bound, http_task) = serve(listen, status_rx, api, limits)
        .await
        .map_err(|e| GatewayError::setup(format!("binding status endpoint {listen}"), e))?;
    tracing::info!(%bound, "status endpoint: GET /status, /metrics");
    if let Some(tx) = status_addr {
        let _ = tx.send(bound);
    }
    Ok((opcua, http_task))
}

/// What a build without the `opcua` / `mqtt` features answers for a section it cannot serve.
#[cfg(not(feature = "opcua"))]
const NOT_BUILT_OPCUA: &str = "[opcua]: this build has no OPC UA server (cargo feature `opcua`)";
#[cfg(not(feature = "mqtt"))]
const NOT_BUILT_MQTT: &str =
    "[telemetry.mqtt]: this build has no MQTT telemetry (cargo feature `mqtt`)";

/// Without the `opcua` feature no server exists: the type has no value.
#[cfg(not(feature = "opcua"))]
#[derive(Debug)]
pub(crate) enum OpcUaServer {}

#[cfg(not(feature = "opcua"))]
impl OpcUaServer {
    pub(crate) fn stop(self) {
        match self {}
    }
}

/// Without the `mqtt` feature no publisher exists: the type has no value.
#[cfg(not(feature = "mqtt"))]
#[derive(Debug)]
pub(crate) enum Publisher {}

#[cfg(not(feature = "mqtt"))]
impl Publisher {
    pub(crate) fn annotator(&self) -> crate::northbound::telemetry::annotate::TelemetryAnnotator {
        match *self {}
    }

    pub(crate) async fn stop(self, _grace: Duration) {
        match self {}
    }
}

#[cfg(not(feature = "mqtt"))]
pub(crate) fn start_telemetry(
    cfg: &FieldConfig,
    _status: watch::Receiver<Option<Arc<StatusSnapshot>>>,
    _model: Option<ModelIdentity>,
) -> Result<Option<Publisher>, GatewayError> {
    // Refused at load already (`FieldConfig::validate`).
    match cfg.telemetry.as_ref().and_then(|t| t.mqtt.as_ref()) {
        Some(_) => Err(GatewayError::Refused(NOT_BUILT_MQTT.into())),
        None => Ok(None),
    }
}

/// The Sparkplug publisher of the field config's `[telemetry.mqtt]`, if any.
#[cfg(feature = "mqtt")]
pub(crate) fn start_telemetry(
    cfg: &FieldConfig,
    status: watch::Receiver<Option<Arc<StatusSnapshot>>>,
    model_now: Option<ModelIdentity>,
) -> Result<Option<Publisher>, GatewayError> {
    use crate::northbound::telemetry::{Declaration, DeclaredAxis, DeclaredChannel};
    let Some(m) = cfg.telemetry.as_ref().and_then(|t| t.mqtt.clone()) else {
        return Ok(None);
    };
    // Everything the box can publish, so a session has one NBIRTH (docs/fleet.md).
    let mut channels: Vec<DeclaredChannel> = cfg
        .channels
        .iter()
        .map(|c| DeclaredChannel {
            name: c.name.clone(),
            range: Some((c.min, c.max)),
        })
        .collect();
    let unlimited = cfg
        .source_channels()
        .into_iter()
        .map(str::to_string)
        .chain(cfg.recoveries.iter().map(|r| r.target.clone()));
    for name in unlimited {
        if !channels.iter().any(|c| c.name == name) {
            channels.push(DeclaredChannel { name, range: None });
        }
    }
    let declared = Declaration {
        axes: cfg
            .axes
            .iter()
            .map(|a| DeclaredAxis {
                name: a.name.clone(),
                clamp_um: cfg.safety_for(&a.name).max_correction_um,
            })
            .collect(),
        channels,
        terms: model_now.map_or_else(Vec::new, |m| m.term_groups.into_keys().collect()),
        sink: cfg.sink.origin_shift.is_some()
            || cfg.sink.quadrature.is_some()
            || cfg.sink.origin_shift_server.is_some(),
    };
    let model = cfg
        .model
        .as_ref()
        .map_or_else(|| "inline".to_string(), |m| m.path.display().to_string());
    let model_identity = format!("{}:{model}", cfg.gateway.name);
    crate::northbound::telemetry::spawn(
        m,
        crate::northbound::telemetry::PublisherInputs {
            status,
            model_identity,
            declared,
        },
    )
    .map(Some)
    .map_err(GatewayError::from)
}
