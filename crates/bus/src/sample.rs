//! A sample is one decoded value of one channel at one time, with its health; a [`ChannelId`] is the
//! channel's identity on the per-frame and per-cycle path.
//!
//! Units are those of the channel (its name carries them: `x_mm`, `T_spindle_C`, `F_cut_N`); time is
//! seconds on the receiver's clock.
//!
//! Identity: a channel name is resolved ONCE, when a gateway is built (config load, decoder
//! construction), into a small `Copy` index by the [`ChannelTable`] that gateway owns. Samples,
//! the engine's state and the model seam carry that index; the name is looked up in the table
//! only for display (status, metrics, logs, JSON), where [`ChannelTable::name`] returns exactly
//! the configured spelling. What the channel measures ([`ChannelKind`], read from the name's
//! prefix and unit suffix) is resolved with it, so no later code reads a kind from a name. An id
//! means something only in the table that issued it: one gateway, one table, built before its
//! decoders and moved into its engine.

use std::collections::HashMap;
use std::sync::Arc;

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
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sample {
    /// The channel (resolved from its configured name, with its unit suffix: `x_mm`, `T_spindle_C`).
    pub channel: ChannelId,
    pub t_s: f64,
    pub value: f64,
    pub health: Health,
}

/// A channel's identity: a dense index into the [`ChannelTable`] that resolved its name (see the
/// module comment). Equal names in one table give equal ids; ids order by registration, not by
/// name. It prints as its index (`ChannelId(3)`): the name is the table's.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ChannelId(u32);

impl ChannelId {
    /// Dense index (registration order), for tables indexed by channel.
    pub fn index(self) -> usize {
        self.0 as usize
    }
}

/// One configured channel: its name as written and what it measures.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Entry {
    name: Arc<str>,
    kind: ChannelKind,
}

/// The channels one gateway knows, append-only: each name resolved once into a [`ChannelId`]
/// with its [`ChannelKind`]. Built with the gateway (its decoders, its engine's configured and
/// model channels) and owned by its engine; every display of a channel asks it for the name.
#[derive(Clone, Debug, Default)]
pub struct ChannelTable {
    entries: Vec<Entry>,
    ids: HashMap<Arc<str>, ChannelId>,
}

impl ChannelTable {
    /// The id of `name`, adding it the first time (setup time; allocates only for a new name).
    pub fn resolve(&mut self, name: &str) -> ChannelId {
        if let Some(&id) = self.ids.get(name) {
            return id;
        }
        let id = ChannelId(u32::try_from(self.entries.len()).expect("fewer than 2³² channels"));
        let name: Arc<str> = Arc::from(name);
        self.entries.push(Entry {
            kind: ChannelKind::of(&name),
            name: Arc::clone(&name),
        });
        self.ids.insert(name, id);
        id
    }

    /// The id of `name` if this table has it.
    pub fn get(&self, name: &str) -> Option<ChannelId> {
        self.ids.get(name).copied()
    }

    /// The configured name of `id`. Panics for an id this table did not issue (a bug: ids of
    /// one gateway never meet another's table).
    pub fn name(&self, id: ChannelId) -> &str {
        &self.entries[id.index()].name
    }

    /// [`ChannelTable::name`] as a shared string (a reference count, never an allocation), for
    /// a status, fault source or error that outlives the borrow.
    pub fn shared_name(&self, id: ChannelId) -> Arc<str> {
        Arc::clone(&self.entries[id.index()].name)
    }

    /// What `id` measures, resolved from its name when it was added.
    pub fn kind(&self, id: ChannelId) -> ChannelKind {
        self.entries[id.index()].kind
    }

    /// How many channels the table holds (ids are `0..len`).
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_name_resolves_to_one_id_and_back() {
        let mut t = ChannelTable::default();
        let a = t.resolve("x_mm");
        let b = t.resolve("y_mm");
        assert_ne!(a, b);
        assert_eq!(t.resolve("x_mm"), a);
        assert_eq!(t.get("x_mm"), Some(a));
        assert_eq!(t.get("never_registered"), None);
        assert_eq!(t.name(a), "x_mm");
        assert_eq!(&*t.shared_name(b), "y_mm");
        assert_eq!((a.index(), b.index(), t.len()), (0, 1, 2));
        assert_eq!(format!("{b:?}"), "ChannelId(1)");
    }

    #[test]
    fn two_tables_are_independent() {
        let mut one = ChannelTable::default();
        let mut two = ChannelTable::default();
        one.resolve("x_mm");
        let y_in_one = one.resolve("y_mm");
        let y_in_two = two.resolve("y_mm");
        assert_ne!(y_in_one, y_in_two);
        assert_eq!(two.get("x_mm"), None);
        assert_eq!(one.name(y_in_one), two.name(y_in_two));
    }

    #[test]
    fn the_kind_is_resolved_with_the_name() {
        let mut t = ChannelTable::default();
        let kinds = [
            "x_mm",
            "T_spindle_C",
            "F_cut_N",
            "strain_column_ue",
            "spindle_rpm",
        ]
        .map(|n| {
            let id = t.resolve(n);
            t.kind(id)
        });
        assert_eq!(
            kinds,
            [
                ChannelKind::LengthMm,
                ChannelKind::TemperatureC,
                ChannelKind::ForceN,
                ChannelKind::StrainUe,
                ChannelKind::Other
            ]
        );
    }
}
