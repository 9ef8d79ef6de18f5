//! The engine's channels by slot: what it knows of each (limits monitor, status, latched value,
//! fault source) and where each id lives, resolved once from the box's channel table. Values are
//! in the channel's unit (its name says which); time is s on the gateway clock.

use std::sync::Arc;

use retrocomp_bus::fault::FaultSource;
use retrocomp_bus::{ChannelId, ChannelTable};
use retrocomp_model::units::ChannelKind;

use crate::engine::health::{ChannelLimits, ChannelMonitor, ChannelStatus};

/// Everything the engine knows about one channel, by slot (index into `Engine::channels`).
pub(super) struct Channel {
    /// Its identity in the engine's table.
    pub(super) id: ChannelId,
    /// The configured name, for the status (shared with the table).
    pub(super) name: Arc<str>,
    /// The fault source of its health faults (`FaultSource::Channel` of its name, built once).
    pub(super) source: FaultSource,
    /// None until the first sample of a channel that is not configured (it is then judged with
    /// [`default_limits`]); such a channel has no status and no value.
    pub(super) monitor: Option<ChannelMonitor>,
    pub(super) status: Option<ChannelStatus>,
    pub(super) slow: bool,
    /// Slow channels: the value latched at the last thermal period.
    pub(super) latched: Option<f64>,
    /// What the model sees this cycle (usable, slow ones latched).
    pub(super) value: Option<f64>,
}

/// Limits for channels seen on a bus but not configured: anything finite, stale after 1 s.
pub(super) fn default_limits() -> ChannelLimits {
    ChannelLimits {
        min: -1e12,
        max: 1e12,
        stale_after_s: 1.0,
        max_rate_per_s: None,
        stuck_after_s: None,
    }
}

/// Where each channel the engine knows lives in `Engine::channels`.
#[derive(Default)]
pub(super) struct Slots {
    /// Slot by [`ChannelId::index`] (`usize::MAX`: not known to this engine).
    pub(super) by_id: Vec<usize>,
    /// Slots in channel-name order.
    pub(super) by_name: Vec<usize>,
}

impl Slots {
    /// The slot of `id`, adding a channel without monitor when it is new (the only allocation).
    pub(super) fn get_or_add(
        &mut self,
        channels: &mut Vec<Channel>,
        table: &ChannelTable,
        id: ChannelId,
    ) -> usize {
        if let Some(&slot) = self.by_id.get(id.index())
            && slot != usize::MAX
        {
            return slot;
        }
        if self.by_id.len() <= id.index() {
            self.by_id.resize(id.index() + 1, usize::MAX);
        }
        let slot = channels.len();
        let name = table.shared_name(id);
        channels.push(Channel {
            id,
            source: FaultSource::Channel(id, Arc::clone(&name)),
            name: Arc::clone(&name),
            monitor: None,
            status: None,
            slow: table.kind(id) == ChannelKind::TemperatureC,
            latched: None,
            value: None,
        });
        self.by_id[id.index()] = slot;
        let at = self.by_name.partition_point(|&s| channels[s].name < name);
        self.by_name.insert(at, slot);
        slot
    }
}
