//! `[telemetry.mqtt]` of the field config: where a box publishes Sparkplug B and how it queues
//! while the broker is away. Checked at start ([`MqttConfig::check`] returns the key and what was
//! expected; the field config adds file and line). Units in the names (ms, s, Hz, bytes).

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// What the store-and-forward queue gives up when it is full.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum DropPolicy {
    /// Keep the newest telemetry (what an operator looks at first).
    #[default]
    DropOldest,
    /// Keep the start of the outage (what explains it).
    DropNewest,
}

/// `[telemetry]`: only MQTT today.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct TelemetrySection {
    #[serde(default)]
    pub mqtt: Option<MqttConfig>,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MqttConfig {
    /// `host:port` of the broker (1883 plain, 8883 TLS by convention).
    pub broker: String,
    /// MQTT client id; defaults to `<group>.<edge_node>` (unique per box, as the broker requires).
    #[serde(default)]
    pub client_id: Option<String>,
    /// Sparkplug group id (a shop, a line).
    pub group_id: String,
    /// Sparkplug edge node id (this box; unique within the group).
    pub edge_node_id: String,
    /// NDATA sampling rate, Hz: values that changed are sent at most this often; state changes
    /// (enable, faults, modes, health, sink link) are sent at once.
    #[serde(default = "default_rate_hz")]
    pub rate_hz: f64,
    /// Sparkplug 3.0 primary host id: when set, NBIRTH waits until `spBv1.0/STATE/<id>` says the
    /// host is online, and the node re-births when the host comes back (spec §5.x, "Primary Host").
    #[serde(default)]
    pub primary_host_id: Option<String>,
    /// MQTT keep-alive, s.
    #[serde(default = "default_keep_alive_s")]
    pub keep_alive_s: u64,
    /// Reconnect back-off, ms (doubles from min to max).
    #[serde(default = "default_reconnect_min_ms")]
    pub reconnect_min_ms: u64,
    #[serde(default = "default_reconnect_max_ms")]
    pub reconnect_max_ms: u64,
    #[serde(default)]
    pub username: Option<String>,
    /// File holding the password (first line); never the password itself in the config.
    #[serde(default)]
    pub password_file: Option<PathBuf>,
    #[serde(default)]
    pub tls: Option<TlsConfig>,
    #[serde(default)]
    pub queue: QueueConfig,
    /// MQTT QoS of NDATA. 1 (default): the broker acknowledges each record and only then is it
    /// removed from the queue (nothing lost across a broker or network outage). Sparkplug 3.0
    /// asks for 0 (`payloads-ndata-qos`): choose 0 for strict conformance, at the price that a
    /// record in flight when the link breaks is lost.
    #[serde(default = "one")]
    pub ndata_qos: u8,
    /// NCMD `Node Control/Rebirth` requests are answered with at most one NBIRTH per this many
    /// seconds (a request inside the interval is answered at its end), so a host's rebirth storm
    /// cannot flood the broker with births.
    #[serde(default = "default_rebirth_min_interval_s")]
    pub rebirth_min_interval_s: f64,
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TlsConfig {
    /// PEM file with the CA certificate(s) that signed the broker's certificate.
    pub ca_file: PathBuf,
    /// PEM client certificate chain and key, for brokers that authenticate clients by certificate.
    #[serde(default)]
    pub client_cert_file: Option<PathBuf>,
    #[serde(default)]
    pub client_key_file: Option<PathBuf>,
}

impl TlsConfig {
    /// TLS that checks the broker against `ca_file`, without a client certificate.
    pub fn with_ca(ca_file: PathBuf) -> Self {
        TlsConfig {
            ca_file,
            client_cert_file: None,
            client_key_file: None,
        }
    }
}

#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QueueConfig {
    /// Directory of the on-disk queue (one file per record); absent = memory only (lost on a
    /// gateway restart during an outage).
    #[serde(default)]
    pub dir: Option<PathBuf>,
    #[serde(default = "default_max_records")]
    pub max_records: usize,
    #[serde(default = "default_max_bytes")]
    pub max_bytes: u64,
    #[serde(default)]
    pub drop_policy: DropPolicy,
}

impl Default for QueueConfig {
    fn default() -> Self {
        QueueConfig {
            dir: None,
            max_records: default_max_records(),
            max_bytes: default_max_bytes(),
            drop_policy: DropPolicy::default(),
        }
    }
}

fn default_rate_hz() -> f64 {
    10.0
}
fn default_keep_alive_s() -> u64 {
    10
}
fn default_reconnect_min_ms() -> u64 {
    200
}
fn default_reconnect_max_ms() -> u64 {
    10_000
}
/// A day at 1 Hz, or 2.4 h at 10 Hz.
fn default_max_records() -> usize {
    86_400
}
/// 256 MiB.
fn default_max_bytes() -> u64 {
    256 << 20
}
fn default_rebirth_min_interval_s() -> f64 {
    1.0
}
fn one() -> u8 {
    1
}

/// Sparkplug ids are topic levels: no `/`, `+`, `#`, and not empty.
fn check_id(key: &str, v: &str) -> Result<(), (String, String)> {
    if v.is_empty() || v.contains(['/', '+', '#']) {
        return Err((
            key.to_string(),
            format!("expected a non-empty Sparkplug id without '/', '+' or '#', got {v:?}"),
        ));
    }
    Ok(())
}

/// The `[telemetry]` of one `retrocomp demo` run: group `retrocomp-demo`, edge node
/// `mill-<run>`, memory queue, 10 Hz.
pub fn demo_section(broker: &str, run: &str) -> TelemetrySection {
    TelemetrySection {
        mqtt: Some(MqttConfig::new(
            broker,
            "retrocomp-demo",
            &format!("mill-{run}"),
        )),
    }
}

impl MqttConfig {
    /// A config for `host:port` with defaults (the demo and the load bench).
    pub fn new(broker: &str, group_id: &str, edge_node_id: &str) -> Self {
        MqttConfig {
            broker: broker.into(),
            client_id: None,
            group_id: group_id.into(),
            edge_node_id: edge_node_id.into(),
            rate_hz: default_rate_hz(),
            primary_host_id: None,
            keep_alive_s: default_keep_alive_s(),
            reconnect_min_ms: default_reconnect_min_ms(),
            reconnect_max_ms: default_reconnect_max_ms(),
            username: None,
            password_file: None,
            tls: None,
            queue: QueueConfig::default(),
            ndata_qos: 1,
            rebirth_min_interval_s: default_rebirth_min_interval_s(),
        }
    }

    pub fn client_id(&self) -> String {
        self.client_id
            .clone()
            .unwrap_or_else(|| format!("{}.{}", self.group_id, self.edge_node_id))
    }

    /// (host, port) of `broker`.
    pub fn host_port(&self) -> Result<(String, u16), String> {
        broker_host_port(&self.broker)
    }

    /// Start-time checks: (key below `telemetry.mqtt`, what was expected). Files named by the
    /// config must be readable now (a box that cannot authenticate would queue forever).
    pub fn check(&self) -> Result<(), (String, String)> {
        let k = |s: &str| format!("telemetry.mqtt.{s}");
        self.host_port().map_err(|e| (k("broker"), e))?;
        check_id(&k("group_id"), &self.group_id)?;
        check_id(&k("edge_node_id"), &self.edge_node_id)?;
        if let Some(h) = &self.primary_host_id {
            check_id(&k("primary_host_id"), h)?;
        }
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0 && self.rate_hz <= 100.0) {
            return Err((
                k("rate_hz"),
                format!("expected 0 < rate_hz <= 100, got {}", self.rate_hz),
            ));
        }
        if !(1..=3600).contains(&self.keep_alive_s) {
            return Err((
                k("keep_alive_s"),
                format!("expected 1..=3600 s, got {}", self.keep_alive_s),
            ));
        }
        if self.reconnect_min_ms == 0 || self.reconnect_min_ms > self.reconnect_max_ms {
            return Err((
                k("reconnect_min_ms"),
                format!(
                    "expected 0 < reconnect_min_ms <= reconnect_max_ms ({}), got {}",
                    self.reconnect_max_ms, self.reconnect_min_ms
                ),
            ));
        }
        if self.ndata_qos > 1 {
            return Err((
                k("ndata_qos"),
                format!("expected 0 or 1, got {}", self.ndata_qos),
            ));
        }
        let r = self.rebirth_min_interval_s;
        if !(r.is_finite() && (0.0..=3600.0).contains(&r)) {
            return Err((
                k("rebirth_min_interval_s"),
                format!("expected 0..=3600 s, got {r}"),
            ));
        }
        if self.password_file.is_some() && self.username.is_none() {
            return Err((
                k("password_file"),
                "expected telemetry.mqtt.username with a password".into(),
            ));
        }
        let readable = |key: String, p: &PathBuf| {
            std::fs::metadata(p)
                .map(|_| ())
                .map_err(|e| (key, format!("cannot read {}: {e}", p.display())))
        };
        if let Some(p) = &self.password_file {
            readable(k("password_file"), p)?;
        }
        if let Some(t) = &self.tls {
            readable(k("tls.ca_file"), &t.ca_file)?;
            match (&t.client_cert_file, &t.client_key_file) {
                (Some(c), Some(key)) => {
                    readable(k("tls.client_cert_file"), c)?;
                    readable(k("tls.client_key_file"), key)?;
                }
                (None, None) => {}
                (Some(_), None) => {
                    return Err((
                        k("tls.client_key_file"),
                        "expected with tls.client_cert_file".into(),
                    ));
                }
                (None, Some(_)) => {
                    return Err((
                        k("tls.client_cert_file"),
                        "expected with tls.client_key_file".into(),
                    ));
                }
            }
        }
        let q = &self.queue;
        if q.max_records == 0 || q.max_bytes < 4096 {
            return Err((
                k("queue.max_records"),
                format!(
                    "expected max_records >= 1 and max_bytes >= 4096, got {} and {}",
                    q.max_records, q.max_bytes
                ),
            ));
        }
        Ok(())
    }

    /// `dir`, `password_file` and TLS files relative to the config file's directory.
    pub fn resolve_paths(&mut self, base: &std::path::Path) {
        let fix = |p: &mut PathBuf| {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        };
        if let Some(p) = &mut self.password_file {
            fix(p);
        }
        if let Some(p) = &mut self.queue.dir {
            fix(p);
        }
        if let Some(t) = &mut self.tls {
            fix(&mut t.ca_file);
            if let Some(p) = &mut t.client_cert_file {
                fix(p);
            }
            if let Some(p) = &mut t.client_key_file {
                fix(p);
            }
        }
    }
}

/// A broker's `host:port` (`[v6]:port` too): a non-empty host and a port 1..=65535. The one rule
/// for every broker address the project reads (the box's `[telemetry.mqtt] broker`, the fleet
/// host's and the workers' `--broker`).
pub fn broker_host_port(broker: &str) -> Result<(String, u16), String> {
    let (h, p) = broker
        .rsplit_once(':')
        .ok_or_else(|| format!("expected host:port, got {broker:?}"))?;
    let port = p
        .parse::<u16>()
        .map_err(|_| format!("expected host:port with a port 1..=65535, got {broker:?}"))?;
    if h.is_empty() || port == 0 {
        return Err(format!("expected host:port, got {broker:?}"));
    }
    Ok((h.trim_matches(['[', ']']).to_string(), port))
}
