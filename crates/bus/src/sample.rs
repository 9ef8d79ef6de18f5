//! A sample is one decoded value of one channel at one time, with its health; a [`ChannelId`] is the
//! channel's identity on the per-frame and per-cycle path.
//!
//! Units are those of the channel (its name carries them: `x_mm`, `T_spindle_C`, `F_cut_N`); time is
//! seconds on the receiver's clock.
//!
//! Identity: a channel name is resolved ONCE, when a config is loaded or a decoder is built
//! ([`ChannelId::of`]), into a small `Copy` index. Samples, the engine's state and the model seam
//! carry that index; the name is looked up only for display (status, metrics, logs, JSON), where
//! [`ChannelId::name`] returns exactly the configured spelling; what the channel measures
//! ([`ChannelKind`], read from the name's prefix and unit suffix) is resolved with it, so no later
//! code reads a kind from a name. The registry is process-wide and
//! append-only (a gateway has tens of channels, so the leaked names are bounded by the configs
//! loaded), which lets every decoder resolve its channel at construction without a registry being
//! threaded through every constructor.

use std::collections::HashMap;
use std::fmt;
use std::sync::{LazyLock, RwLock};

use retrocomp_model::units::ChannelKind;

/// Health of a channel's latest value.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Health {
    Ok,
    /// No fresh value within the channel's timeout (heartbeat lost, poll failed, line silent).
    Stale,
    /// Decoded, but outside the configured physical range, or not finite.
    OutOfRange,
    /// The bytes could not be decoded (wrong length, bad checksum, garbage line, Modbus exception).
    DecodeError,
}

/// One decoded value.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Sample {
    /// The channel (resolved from its configured name, with its unit suffix: `x_mm`, `T_spindle_C`).
    pub channel: ChannelId,
    pub t_s: f64,
    pub value: f64,
    pub health: Health,
}

/// A channel's identity: an index into the process-wide registry of channel names (see the module
/// comment). Equal names give equal ids; ids order by registration, not by name.
#[derive(Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ChannelId(u32);

#[derive(Default)]
struct Registry {
    names: Vec<(&'static str, ChannelKind)>,
    ids: HashMap<&'static str, ChannelId>,
}

static REGISTRY: LazyLock<RwLock<Registry>> = LazyLock::new(Default::default);

impl ChannelId {
    /// The id of `name`, registering it the first time (setup time: config load, decoder
    /// construction; allocates only for a new name).
    pub fn of(name: &str) -> ChannelId {
        if let Some(id) = Self::lookup(name) {
            return id;
        }
        let mut r = REGISTRY.write().unwrap_or_else(|e| e.into_inner());
        if let Some(&id) = r.ids.get(name) {
            return id;
        }
        let id = ChannelId(u32::try_from(r.names.len()).expect("fewer than 2³² channel names"));
        let leaked: &'static str = Box::leak(name.to_owned().into_boxed_str());
        r.names.push((leaked, ChannelKind::of(name)));
        r.ids.insert(leaked, id);
        id
    }

    /// The id of `name` if it was ever registered.
    pub fn lookup(name: &str) -> Option<ChannelId> {
        let r = REGISTRY.read().unwrap_or_else(|e| e.into_inner());
        r.ids.get(name).copied()
    }

    /// The configured name (for display; takes the registry's read lock, so keep it off the
    /// per-cycle path: cache it at setup).
    pub fn name(self) -> &'static str {
        self.entry().0
    }

    /// What the channel measures, resolved from its name when it was registered.
    pub fn kind(self) -> ChannelKind {
        self.entry().1
    }

    fn entry(self) -> (&'static str, ChannelKind) {
        let r = REGISTRY.read().unwrap_or_else(|e| e.into_inner());
        r.names[self.0 as usize]
    }

    /// Dense index (registration order), for tables indexed by channel.
    pub fn index(self) -> usize {
        self.0 as usize
    }
}

impl fmt::Debug for ChannelId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:?}", self.name())
    }
}

impl fmt::Display for ChannelId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl From<&str> for ChannelId {
    fn from(name: &str) -> Self {
        ChannelId::of(name)
    }
}

impl From<&String> for ChannelId {
    fn from(name: &String) -> Self {
        ChannelId::of(name)
    }
}

impl From<String> for ChannelId {
    fn from(name: String) -> Self {
        ChannelId::of(&name)
    }
}

impl PartialEq<str> for ChannelId {
    fn eq(&self, other: &str) -> bool {
        self.name() == other
    }
}

impl PartialEq<&str> for ChannelId {
    fn eq(&self, other: &&str) -> bool {
        self.name() == *other
    }
}

impl serde::Serialize for ChannelId {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

impl<'de> serde::Deserialize<'de> for ChannelId {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let name = <std::borrow::Cow<'de, str>>::deserialize(d)?;
        Ok(ChannelId::of(&name))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_name_resolves_to_one_id_and_back() {
        let a = ChannelId::of("test_sample_a_mm");
        let b = ChannelId::of("test_sample_b_mm");
        assert_ne!(a, b);
        assert_eq!(ChannelId::of("test_sample_a_mm"), a);
        assert_eq!(ChannelId::lookup("test_sample_a_mm"), Some(a));
        assert_eq!(ChannelId::lookup("test_sample_never_registered"), None);
        assert_eq!(a.name(), "test_sample_a_mm");
        assert_eq!(a.to_string(), "test_sample_a_mm");
        assert_eq!(format!("{b:?}"), "\"test_sample_b_mm\"");
        assert!(a == "test_sample_a_mm");
        let json = serde_json::to_string(&a).unwrap();
        assert_eq!(json, "\"test_sample_a_mm\"");
        assert_eq!(serde_json::from_str::<ChannelId>(&json).unwrap(), a);
    }

    #[test]
    fn the_kind_is_resolved_with_the_name() {
        assert_eq!(
            ChannelId::of("test_sample_a_mm").kind(),
            ChannelKind::LengthMm
        );
        assert_eq!(
            ChannelId::of("T_test_sample_C").kind(),
            ChannelKind::TemperatureC
        );
        assert_eq!(ChannelId::of("F_test_sample_N").kind(), ChannelKind::ForceN);
        assert_eq!(ChannelId::of("test_sample_rpm").kind(), ChannelKind::Other);
    }
}
