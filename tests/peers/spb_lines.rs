//! The JSON lines a Sparkplug host peer prints (`spb_host.py`, `spb_stock_host.py`), collected
//! until a condition holds. Used by `real_peers`' `telemetry_mqtt` and `telemetry_stock_host`.

use std::time::{Duration, Instant};

use serde_json::Value;

use crate::peers::Peer;

/// How long one awaited message may take; only a broken publisher reaches it.
pub(crate) const PATIENCE: Duration = Duration::from_secs(60);

/// Collects the host's decoded messages (`{"event": …}` lines are the host's own, left out).
pub(crate) struct Host {
    pub(crate) peer: Peer,
    pub(crate) msgs: Vec<Value>,
}

impl Host {
    pub(crate) fn new(peer: Peer) -> Self {
        Host { peer, msgs: vec![] }
    }

    /// Read lines until `done(msgs)` holds (each line within PATIENCE).
    pub(crate) fn until(&mut self, what: &str, done: impl Fn(&[Value]) -> bool) {
        let deadline = Instant::now() + PATIENCE;
        while !done(&self.msgs) {
            assert!(
                Instant::now() < deadline,
                "host: no {what} within {PATIENCE:?}"
            );
            let line = self.peer.line(PATIENCE.as_secs());
            let v: Value = serde_json::from_str(&line).unwrap_or_else(|e| panic!("{e}: {line}"));
            if v.get("event").is_none() {
                self.msgs.push(v);
            }
        }
    }

    pub(crate) fn of(&self, kind: &str) -> Vec<&Value> {
        of(&self.msgs, kind)
    }
}

/// The messages of one type (`NBIRTH`, `NDATA`, `NDEATH`).
pub(crate) fn of<'a>(msgs: &'a [Value], kind: &str) -> Vec<&'a Value> {
    msgs.iter().filter(|m| m["type"] == kind).collect()
}
