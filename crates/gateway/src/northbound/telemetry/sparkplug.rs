//! Eclipse Sparkplug 3.0 (Sparkplug B) on the wire: the protobuf messages of `sparkplug_b.proto`
//! that an edge node needs (Payload, Metric, DataType; field numbers as in the spec's .proto, checked
//! against a third-party decoder in `tests/real_peers/telemetry_mqtt.rs`), the topic namespace
//! `spBv1.0/<group>/<NBIRTH|NDATA|NDEATH|NCMD>/<edge node>`, and the edge node's session state
//! (bdSeq, seq) as a sans-IO machine. Timestamps are ms since the Unix epoch (UTC), as the spec says.
//!
//! Sequence rules (spec §6.4.18–6.4.25, tck-ids in the comments):
//! - bdSeq (0–255, wraps) advances on every MQTT CONNECT after one the broker accepted (a refused
//!   or unanswered attempt registered no will, so its number is reused); the NDEATH registered as
//!   the CONNECT's will and the NBIRTH that follows carry the same value
//!   (`payloads-nbirth-bdseq-repeat`).
//! - seq (0–255, wraps): the NBIRTH carries 0, each NDATA one more than the previous message.
//! - NDEATH carries no seq; NCMD `Node Control/Rebirth` = true asks for a new NBIRTH (same bdSeq,
//!   seq back to 0).
//!
//! Metadata: the NBIRTH gives every metric its alias, datatype and a PropertySet (spec §6.4.7,
//! `engUnit` and, where the box knows them, `engLow`/`engHigh`: the keys SCADA hosts read for a
//! tag's unit and range). "No value" is `is_null = true` with the metric's datatype and no value
//! field (`payloads-metric-is-null`); inside the box it is a `Double(NaN)`.

use prost::Message;

/// `Payload.Metric.value` (the oneof). Only the scalar kinds this edge node publishes.
#[derive(Clone, PartialEq, prost::Oneof)]
pub enum Value {
    #[prost(uint32, tag = "10")]
    Int(u32),
    #[prost(uint64, tag = "11")]
    Long(u64),
    #[prost(float, tag = "12")]
    Float(f32),
    #[prost(double, tag = "13")]
    Double(f64),
    #[prost(bool, tag = "14")]
    Boolean(bool),
    #[prost(string, tag = "15")]
    String(String),
}

/// `Payload.Metric`.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Metric {
    #[prost(string, optional, tag = "1")]
    pub name: Option<String>,
    #[prost(uint64, optional, tag = "2")]
    pub alias: Option<u64>,
    /// ms since the Unix epoch.
    #[prost(uint64, optional, tag = "3")]
    pub timestamp: Option<u64>,
    /// A [`DataType`] value.
    #[prost(uint32, optional, tag = "4")]
    pub datatype: Option<u32>,
    /// Store-and-forward: set on values sent from the queue after a reconnect, so a host does
    /// not take them for the current value.
    #[prost(bool, optional, tag = "5")]
    pub is_historical: Option<bool>,
    #[prost(bool, optional, tag = "6")]
    pub is_transient: Option<bool>,
    #[prost(bool, optional, tag = "7")]
    pub is_null: Option<bool>,
    /// Units and range, sent in the NBIRTH only.
    #[prost(message, optional, tag = "9")]
    pub properties: Option<PropertySet>,
    #[prost(oneof = "Value", tags = "10, 11, 12, 13, 14, 15")]
    pub value: Option<Value>,
}

/// `Payload.PropertyValue.value` (the oneof): the kinds our properties use.
#[derive(Clone, PartialEq, prost::Oneof)]
pub enum PropertyKind {
    #[prost(double, tag = "6")]
    Double(f64),
    #[prost(string, tag = "8")]
    String(String),
}

/// `Payload.PropertyValue`.
#[derive(Clone, PartialEq, prost::Message)]
pub struct PropertyValue {
    /// A [`DataType`] value.
    #[prost(uint32, optional, tag = "1")]
    pub r#type: Option<u32>,
    #[prost(bool, optional, tag = "2")]
    pub is_null: Option<bool>,
    #[prost(oneof = "PropertyKind", tags = "6, 8")]
    pub value: Option<PropertyKind>,
}

/// `Payload.PropertySet`: `keys[i]` names `values[i]`.
#[derive(Clone, PartialEq, prost::Message)]
pub struct PropertySet {
    #[prost(string, repeated, tag = "1")]
    pub keys: Vec<String>,
    #[prost(message, repeated, tag = "2")]
    pub values: Vec<PropertyValue>,
}

impl PropertySet {
    /// The string value of `key`, if present (tests and hosts read `engUnit` this way).
    pub fn string(&self, key: &str) -> Option<&str> {
        let i = self.keys.iter().position(|k| k == key)?;
        match &self.values.get(i)?.value {
            Some(PropertyKind::String(s)) => Some(s),
            _ => None,
        }
    }

    /// The number value of `key`, if present.
    pub fn double(&self, key: &str) -> Option<f64> {
        let i = self.keys.iter().position(|k| k == key)?;
        match self.values.get(i)?.value {
            Some(PropertyKind::Double(x)) => Some(x),
            _ => None,
        }
    }
}

/// `Payload` (template, dataset, property set and extension fields are not used here).
#[derive(Clone, PartialEq, prost::Message)]
pub struct Payload {
    /// ms since the Unix epoch.
    #[prost(uint64, optional, tag = "1")]
    pub timestamp: Option<u64>,
    #[prost(message, repeated, tag = "2")]
    pub metrics: Vec<Metric>,
    #[prost(uint64, optional, tag = "3")]
    pub seq: Option<u64>,
    #[prost(string, optional, tag = "4")]
    pub uuid: Option<String>,
    #[prost(bytes = "vec", optional, tag = "5")]
    pub body: Option<Vec<u8>>,
}

/// `DataType` (the values the spec fixes; only those used here).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[repr(u32)]
pub enum DataType {
    Int64 = 4,
    UInt32 = 7,
    UInt64 = 8,
    Double = 10,
    Boolean = 11,
    String = 12,
}

impl Value {
    pub fn datatype(&self) -> DataType {
        match self {
            Value::Int(_) => DataType::UInt32,
            Value::Long(_) => DataType::UInt64,
            Value::Float(_) | Value::Double(_) => DataType::Double,
            Value::Boolean(_) => DataType::Boolean,
            Value::String(_) => DataType::String,
        }
    }
}

/// What an NBIRTH declares about one metric besides its value: name (alias = position in the
/// table + 1), datatype, and for numbers the unit (`engUnit`) and range (`engLow`/`engHigh`).
#[derive(Clone, Debug, PartialEq)]
pub struct MetricSpec {
    pub name: String,
    pub datatype: DataType,
    pub unit: Option<String>,
    pub low: Option<f64>,
    pub high: Option<f64>,
}

impl MetricSpec {
    /// A metric without unit or range (text, flags).
    pub fn plain(name: impl Into<String>, datatype: DataType) -> Self {
        MetricSpec {
            name: name.into(),
            datatype,
            unit: None,
            low: None,
            high: None,
        }
    }

    /// A number in `unit`.
    pub fn numeric(name: impl Into<String>, datatype: DataType, unit: &str) -> Self {
        MetricSpec {
            unit: Some(unit.to_string()),
            ..MetricSpec::plain(name, datatype)
        }
    }

    /// With its range (`engLow`, `engHigh`).
    pub fn range(mut self, low: f64, high: f64) -> Self {
        self.low = Some(low);
        self.high = Some(high);
        self
    }

    fn properties(&self) -> Option<PropertySet> {
        let mut set = PropertySet::default();
        let mut add = |key: &str, t: DataType, v: PropertyKind| {
            set.keys.push(key.to_string());
            set.values.push(PropertyValue {
                r#type: Some(t as u32),
                is_null: None,
                value: Some(v),
            });
        };
        if let Some(u) = &self.unit {
            add("engUnit", DataType::String, PropertyKind::String(u.clone()));
        }
        if let Some(x) = self.low {
            add("engLow", DataType::Double, PropertyKind::Double(x));
        }
        if let Some(x) = self.high {
            add("engHigh", DataType::Double, PropertyKind::Double(x));
        }
        (!set.keys.is_empty()).then_some(set)
    }
}

/// A metric carrying `v` at `t_ms`: a NaN double ("no value") goes as `is_null` with no value.
fn metric_of(v: &Value, datatype: DataType, t_ms: u64) -> Metric {
    let null = matches!(v, Value::Double(x) if x.is_nan());
    Metric {
        timestamp: Some(t_ms),
        datatype: Some(datatype as u32),
        is_null: null.then_some(true),
        value: (!null).then(|| v.clone()),
        ..Default::default()
    }
}

/// The metric NCMD sets to ask for a rebirth and every NBIRTH carries (false).
pub const REBIRTH: &str = "Node Control/Rebirth";
/// The birth/death sequence metric of NBIRTH and NDEATH.
pub const BD_SEQ: &str = "bdSeq";

/// Message types of an edge node's topics.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    NBirth,
    NData,
    NDeath,
    NCmd,
}

impl Kind {
    pub fn as_str(self) -> &'static str {
        match self {
            Kind::NBirth => "NBIRTH",
            Kind::NData => "NDATA",
            Kind::NDeath => "NDEATH",
            Kind::NCmd => "NCMD",
        }
    }
}

/// `spBv1.0/<group>/<kind>/<edge node>`.
pub fn topic(group: &str, kind: Kind, edge_node: &str) -> String {
    format!("spBv1.0/{group}/{}/{edge_node}", kind.as_str())
}

/// `spBv1.0/STATE/<host id>`: a Sparkplug 3.0 primary host's online/offline state (JSON, retained).
pub fn state_topic(host_id: &str) -> String {
    format!("spBv1.0/STATE/{host_id}")
}

/// Whether a STATE message says the host is online (`{"online": true, ...}`); None if it is not
/// a STATE payload.
pub fn host_online(payload: &[u8]) -> Option<bool> {
    let v: serde_json::Value = serde_json::from_slice(payload).ok()?;
    v.get("online")?.as_bool()
}

/// True when an NCMD payload asks for a rebirth (`Node Control/Rebirth` = true, by name; an NCMD
/// may not use aliases for it since it is not in our alias table's data part).
pub fn is_rebirth_request(payload: &[u8]) -> bool {
    Payload::decode(payload).is_ok_and(|p| {
        p.metrics
            .iter()
            .any(|m| m.name.as_deref() == Some(REBIRTH) && m.value == Some(Value::Boolean(true)))
    })
}

/// One metric of a data record: its name (its alias comes from the birth's table) and value.
pub type NamedValue = (String, Value);

/// The edge node's session numbers and alias table. Sans-IO: payloads are built from values and
/// times passed in.
#[derive(Clone, Debug)]
pub struct EdgeNode {
    /// bdSeq of the current (or next) MQTT session.
    bd_seq: u8,
    /// seq of the last message sent in this session.
    seq: u8,
    /// Metric names in alias order (alias = index + 1; 0 is left out so an absent alias is never
    /// mistaken for the first metric by a careless decoder).
    names: Vec<String>,
    /// The broker accepted the CONNECT carrying the current bdSeq: the next one is a new number.
    used: bool,
}

impl EdgeNode {
    /// `first_bd_seq`: the bdSeq of the first CONNECT (0 for a fresh node).
    pub fn new(first_bd_seq: u8) -> Self {
        EdgeNode {
            bd_seq: first_bd_seq,
            seq: 0,
            names: Vec::new(),
            used: false,
        }
    }

    /// The bdSeq for a new MQTT CONNECT: advanced if the broker accepted the previous one.
    pub fn next_connect(&mut self) -> u8 {
        if self.used {
            self.bd_seq = self.bd_seq.wrapping_add(1);
            self.used = false;
        }
        self.bd_seq
    }

    /// The broker accepted the CONNECT (CONNACK): its will, our NDEATH, is registered.
    pub fn connected(&mut self) {
        self.used = true;
    }

    pub fn bd_seq(&self) -> u8 {
        self.bd_seq
    }

    /// The NDEATH of the current session (the CONNECT's will; also sent before a clean disconnect).
    pub fn death(&self, now_ms: u64) -> Vec<u8> {
        Payload {
            timestamp: Some(now_ms),
            metrics: vec![Metric {
                name: Some(BD_SEQ.into()),
                datatype: Some(DataType::Int64 as u32),
                value: Some(Value::Long(u64::from(self.bd_seq))),
                ..Default::default()
            }],
            ..Default::default()
        }
        .encode_to_vec()
    }

    /// The NBIRTH of `values` alone (each metric declared by its own value, no units): for
    /// hosts' tests and tools that have no declaration.
    pub fn birth(&mut self, values: &[NamedValue], now_ms: u64) -> Vec<u8> {
        let table: Vec<MetricSpec> = values
            .iter()
            .map(|(n, v)| MetricSpec::plain(n.clone(), v.datatype()))
            .collect();
        self.birth_declared(&table, values, now_ms)
    }

    /// The NBIRTH: every metric of `table` in its order (alias = index + 1) with its datatype,
    /// properties and current value from `values` (`is_null` when it has none yet), plus bdSeq
    /// and `Node Control/Rebirth` = false; seq restarts at 0.
    pub fn birth_declared(
        &mut self,
        table: &[MetricSpec],
        values: &[NamedValue],
        now_ms: u64,
    ) -> Vec<u8> {
        self.names = table.iter().map(|m| m.name.clone()).collect();
        self.seq = 0;
        let mut metrics = vec![
            Metric {
                name: Some(BD_SEQ.into()),
                timestamp: Some(now_ms),
                datatype: Some(DataType::Int64 as u32),
                value: Some(Value::Long(u64::from(self.bd_seq))),
                ..Default::default()
            },
            Metric {
                name: Some(REBIRTH.into()),
                timestamp: Some(now_ms),
                datatype: Some(DataType::Boolean as u32),
                value: Some(Value::Boolean(false)),
                ..Default::default()
            },
        ];
        for (i, spec) in table.iter().enumerate() {
            let v = values
                .iter()
                .find(|(n, _)| *n == spec.name)
                .map_or(Value::Double(f64::NAN), |(_, v)| v.clone());
            // Declared with no value yet: a null of the declared type.
            let mut m = metric_of(&v, spec.datatype, now_ms);
            m.name = Some(spec.name.clone());
            m.alias = Some(i as u64 + 1);
            m.properties = spec.properties();
            metrics.push(m);
        }
        Payload {
            timestamp: Some(now_ms),
            metrics,
            seq: Some(0),
            ..Default::default()
        }
        .encode_to_vec()
    }

    /// Whether the birth's alias table knows every metric of `values` (else a rebirth is due).
    pub fn knows_all(&self, values: &[NamedValue]) -> bool {
        values.iter().all(|(n, _)| self.names.contains(n))
    }

    /// An NDATA of values sampled at `t_ms` (the source's timestamp, kept through the queue), by
    /// alias, with the next seq. `historical`: sent from the store-and-forward queue.
    pub fn data(&mut self, values: &[NamedValue], t_ms: u64, historical: bool) -> Vec<u8> {
        self.seq = self.seq.wrapping_add(1);
        let metrics = values
            .iter()
            .filter_map(|(name, v)| {
                let alias = self.names.iter().position(|n| n == name)? as u64 + 1;
                let mut m = metric_of(v, v.datatype(), t_ms);
                m.alias = Some(alias);
                m.is_historical = historical.then_some(true);
                Some(m)
            })
            .collect();
        Payload {
            timestamp: Some(t_ms),
            metrics,
            seq: Some(u64::from(self.seq)),
            ..Default::default()
        }
        .encode_to_vec()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn vals() -> Vec<NamedValue> {
        vec![
            ("Axis/x/applied_um".into(), Value::Double(-3.5)),
            ("Gateway/enabled".into(), Value::Boolean(true)),
        ]
    }

    #[test]
    fn bd_seq_advances_per_connect_and_wraps_and_death_matches_birth() {
        let mut n = EdgeNode::new(254);
        assert_eq!(
            n.next_connect(),
            254,
            "the first connect uses the stored value"
        );
        assert_eq!(
            n.next_connect(),
            254,
            "a refused connect registered no will: reused"
        );
        n.connected();
        assert_eq!(n.next_connect(), 255);
        n.connected();
        assert_eq!(n.next_connect(), 0, "bdSeq wraps 255 → 0");
        let death = Payload::decode(n.death(5).as_slice()).unwrap();
        let birth = Payload::decode(n.birth(&vals(), 6).as_slice()).unwrap();
        assert_eq!(death.seq, None, "NDEATH carries no seq");
        assert_eq!(death.metrics[0].value, Some(Value::Long(0)));
        assert_eq!(birth.metrics[0].name.as_deref(), Some(BD_SEQ));
        assert_eq!(birth.metrics[0].value, death.metrics[0].value);
    }

    #[test]
    fn seq_starts_at_zero_on_birth_and_wraps_after_255() {
        let mut n = EdgeNode::new(0);
        n.next_connect();
        let b = Payload::decode(n.birth(&vals(), 1).as_slice()).unwrap();
        assert_eq!(b.seq, Some(0));
        assert!(
            b.metrics
                .iter()
                .any(|m| m.name.as_deref() == Some(REBIRTH)
                    && m.value == Some(Value::Boolean(false)))
        );
        let mut last = 0;
        for i in 1..=256u64 {
            let d = Payload::decode(n.data(&vals(), 1 + i, false).as_slice()).unwrap();
            last = d.seq.unwrap();
            assert_eq!(last, i % 256);
        }
        assert_eq!(last, 0, "seq 255 is followed by 0");
        // A rebirth restarts at 0.
        let b = Payload::decode(n.birth(&vals(), 2).as_slice()).unwrap();
        assert_eq!(b.seq, Some(0));
    }

    #[test]
    fn data_uses_the_births_aliases_and_the_source_timestamp() {
        let mut n = EdgeNode::new(0);
        n.next_connect();
        let b = Payload::decode(n.birth(&vals(), 10).as_slice()).unwrap();
        let alias_of = |name: &str| {
            b.metrics
                .iter()
                .find(|m| m.name.as_deref() == Some(name))
                .and_then(|m| m.alias)
        };
        let d = Payload::decode(
            n.data(
                &[("Gateway/enabled".into(), Value::Boolean(false))],
                7,
                true,
            )
            .as_slice(),
        )
        .unwrap();
        assert_eq!(d.timestamp, Some(7));
        assert_eq!(d.metrics.len(), 1);
        assert_eq!(d.metrics[0].name, None, "NDATA goes by alias");
        assert_eq!(d.metrics[0].alias, alias_of("Gateway/enabled"));
        assert_eq!(d.metrics[0].is_historical, Some(true));
        assert!(!n.knows_all(&[("new".into(), Value::Int(1))]));
    }

    #[test]
    fn births_carry_units_and_nulls_of_the_declared_type() {
        let mut n = EdgeNode::new(0);
        n.next_connect();
        let table = vec![
            MetricSpec::numeric("Axis/x/applied_um", DataType::Double, "µm").range(-50.0, 50.0),
            MetricSpec::plain("Sink/connected", DataType::Boolean),
        ];
        let values = vec![("Axis/x/applied_um".into(), Value::Double(f64::NAN))];
        let b = Payload::decode(n.birth_declared(&table, &values, 3).as_slice()).unwrap();
        let applied = &b.metrics[2];
        assert_eq!(applied.is_null, Some(true), "NaN is sent as null");
        assert_eq!(applied.value, None);
        let props = applied.properties.as_ref().unwrap();
        assert_eq!(props.string("engUnit"), Some("µm"));
        assert_eq!(
            (props.double("engLow"), props.double("engHigh")),
            (Some(-50.0), Some(50.0))
        );
        let sink = &b.metrics[3];
        assert_eq!(sink.name.as_deref(), Some("Sink/connected"));
        assert_eq!(
            (sink.is_null, sink.datatype),
            (Some(true), Some(DataType::Boolean as u32))
        );
        assert_eq!(sink.properties, None, "a flag has no unit");
        let d = Payload::decode(
            n.data(
                &[("Axis/x/applied_um".into(), Value::Double(f64::NAN))],
                4,
                false,
            )
            .as_slice(),
        )
        .unwrap();
        assert_eq!(
            (d.metrics[0].is_null, &d.metrics[0].value),
            (Some(true), &None)
        );
        assert_eq!(
            d.metrics[0].properties, None,
            "properties only in the birth"
        );
    }

    #[test]
    fn rebirth_requests_and_host_state_are_recognised() {
        let cmd = Payload {
            timestamp: Some(1),
            metrics: vec![Metric {
                name: Some(REBIRTH.into()),
                datatype: Some(DataType::Boolean as u32),
                value: Some(Value::Boolean(true)),
                ..Default::default()
            }],
            ..Default::default()
        };
        assert!(is_rebirth_request(&cmd.encode_to_vec()));
        assert!(!is_rebirth_request(b"\xff\xff"));
        assert_eq!(host_online(br#"{"online":true,"timestamp":1}"#), Some(true));
        assert_eq!(host_online(b"nonsense"), None);
        assert_eq!(topic("g", Kind::NData, "box-1"), "spBv1.0/g/NDATA/box-1");
    }
}
