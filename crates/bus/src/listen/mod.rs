//! One policy every TCP listener of the box keeps: the HTTP status/API endpoint, the Modbus TCP
//! server (origin-shift server mode, the simulator), the OPC UA server and the socketcand hub.
//!
//! [`ListenPolicy`] is the config (the same keys wherever a listener is configured, as a
//! `listen_policy` table): a connection cap with a per-peer cap (a peer on `allow_writes_from` is
//! held only to its per-peer cap, so a flood from elsewhere never locks the controller out), an
//! idle timeout, a reserve of file descriptors kept free for the controller link and the sources,
//! and the allow-list of peers whose writes and actions are accepted. This file is the sans-IO
//! core: [`Admissions`] decides who is let in, [`ListenerHealth`] turns refusals, accept errors,
//! restarts and refused writes into faults, each logged once when it starts and once when it
//! clears. `shell.rs` is the accept loop (backoff on accept errors, restart of a listener that
//! fails) and the idle-timeout stream. Times are seconds since the listener started (`_s`).

mod shell;

use std::collections::{BTreeMap, HashMap};
use std::net::IpAddr;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::fault::FaultKind;

pub use shell::{
    Conn, Handler, IdleStream, Listening, Spec, listen, listen_with, open_fds,
    raise_nofile_soft_limit,
};

/// `listen_policy` of a listener's config section; [`ListenPolicy::default`] when absent.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ListenPolicy {
    /// Connections served at once; more are accepted and closed at once, never queued.
    #[serde(default = "default_max_connections")]
    pub max_connections: usize,
    /// Connections one peer address may hold at once.
    #[serde(default = "default_max_connections_per_peer")]
    pub max_connections_per_peer: usize,
    /// A connection that neither sends nor receives a byte for this long is closed, s.
    #[serde(default = "default_idle_timeout_s")]
    pub idle_timeout_s: f64,
    /// New connections are refused while the process's open descriptors are within this many of
    /// its limit (0: no reserve, only the accept backoff when the process runs out).
    #[serde(default = "default_fd_reserve")]
    pub fd_reserve: u64,
    /// Peer addresses whose writes (Modbus position, held and marker registers) and actions (HTTP
    /// `POST /api/…`) are accepted; any other peer gets a Modbus exception 01 or HTTP 403 and a
    /// fault naming it. Default: loopback only.
    #[serde(default = "default_allow_writes_from")]
    pub allow_writes_from: Vec<IpAddr>,
}

fn default_max_connections() -> usize {
    64
}
fn default_max_connections_per_peer() -> usize {
    8
}
fn default_idle_timeout_s() -> f64 {
    60.0
}
fn default_fd_reserve() -> u64 {
    128
}
fn default_allow_writes_from() -> Vec<IpAddr> {
    vec![
        IpAddr::from([127, 0, 0, 1]),
        IpAddr::from([0u16, 0, 0, 0, 0, 0, 0, 1]),
    ]
}

impl Default for ListenPolicy {
    fn default() -> Self {
        ListenPolicy {
            max_connections: default_max_connections(),
            max_connections_per_peer: default_max_connections_per_peer(),
            idle_timeout_s: default_idle_timeout_s(),
            fd_reserve: default_fd_reserve(),
            allow_writes_from: default_allow_writes_from(),
        }
    }
}

impl ListenPolicy {
    /// Why this policy cannot be kept: (`<section>.listen_policy.<key>`, what was expected), for
    /// the config check of `section`.
    pub fn check(&self, section: &str) -> Result<(), (String, String)> {
        let key = |k: &str, what: &str| {
            Err((
                format!("{section}.listen_policy.{k}"),
                format!("expected {what}"),
            ))
        };
        if self.max_connections == 0 {
            return key("max_connections", "at least 1");
        }
        if self.max_connections_per_peer == 0
            || self.max_connections_per_peer > self.max_connections
        {
            return key("max_connections_per_peer", "1 ..= max_connections");
        }
        if !(self.idle_timeout_s.is_finite() && self.idle_timeout_s > 0.0) {
            return key("idle_timeout_s", "a finite number of seconds above 0");
        }
        if self.fd_reserve > 100_000 {
            return key("fd_reserve", "at most 100000 descriptors");
        }
        if self.allow_writes_from.iter().any(IpAddr::is_unspecified) {
            return key(
                "allow_writes_from",
                "peer addresses (0.0.0.0 or :: is nobody's address)",
            );
        }
        Ok(())
    }

    /// Whether writes and actions from `peer` are accepted (an IPv4-mapped IPv6 peer counts as IPv4).
    pub fn may_write(&self, peer: IpAddr) -> bool {
        let peer = canonical(peer);
        self.allow_writes_from.iter().any(|a| canonical(*a) == peer)
    }
}

fn canonical(ip: IpAddr) -> IpAddr {
    match ip {
        IpAddr::V6(v6) => v6.to_ipv4_mapped().map_or(ip, IpAddr::V4),
        v4 => v4,
    }
}

/// Why a connection was not let in, or accepts are being delayed.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Refusal {
    /// `max_connections` reached.
    Busy,
    /// The peer holds `max_connections_per_peer` already.
    PeerCap,
    /// The process's descriptors are within `fd_reserve` of its limit.
    FdReserve,
    /// `accept` itself failed (EMFILE, ENFILE, ENOMEM…): backing off.
    AcceptError,
}

/// Who holds a connection now (sans-IO: the shell asks, then releases when the connection ends).
#[derive(Debug, Default)]
pub struct Admissions {
    /// Connections of peers not on the allow-list (the ones `max_connections` bounds).
    others: usize,
    per_peer: HashMap<IpAddr, usize>,
}

impl Admissions {
    /// Let `peer` in or say why not. `fds`: (open, limit) of the process when a reserve is kept.
    pub fn admit(
        &mut self,
        policy: &ListenPolicy,
        peer: IpAddr,
        fds: Option<(u64, u64)>,
    ) -> Result<(), Refusal> {
        if let Some((open, limit)) = fds
            && open + policy.fd_reserve >= limit
        {
            return Err(Refusal::FdReserve);
        }
        let privileged = policy.may_write(peer);
        let held = self.per_peer.get(&peer).copied().unwrap_or(0);
        if held >= policy.max_connections_per_peer {
            return Err(Refusal::PeerCap);
        }
        if !privileged && self.others >= policy.max_connections {
            return Err(Refusal::Busy);
        }
        *self.per_peer.entry(peer).or_insert(0) += 1;
        if !privileged {
            self.others += 1;
        }
        Ok(())
    }

    /// A connection of `peer` admitted with `policy` ended.
    pub fn release(&mut self, policy: &ListenPolicy, peer: IpAddr) {
        if let Some(n) = self.per_peer.get_mut(&peer) {
            *n -= 1;
            if *n == 0 {
                self.per_peer.remove(&peer);
            }
            if !policy.may_write(peer) {
                self.others = self.others.saturating_sub(1);
            }
        }
    }

    /// Connections held now.
    pub fn held(&self) -> usize {
        self.per_peer.values().sum()
    }
}

/// A refused write clears this long after the peer's last attempt, s.
pub const ROGUE_HOLD_S: f64 = 10.0;

#[derive(Debug)]
struct HealthState {
    refusing: Option<(Refusal, f64)>,
    refused: u64,
    /// When the listener failed (cleared once it serves again), and how often it was restarted.
    failed_s: Option<f64>,
    restarts: u64,
    /// Peers whose writes were refused: (first, last) refused write, s.
    rogue: BTreeMap<IpAddr, (f64, f64)>,
}

/// A listener's faults, shared by its accept loop, its connections and whoever reports status.
/// Every transition is logged once (start and clear), never once per connection or per write.
#[derive(Clone, Debug)]
pub struct ListenerHealth {
    name: Arc<str>,
    epoch: Instant,
    state: Arc<Mutex<HealthState>>,
}

impl ListenerHealth {
    pub fn new(name: &str) -> Self {
        ListenerHealth {
            name: Arc::from(name),
            epoch: Instant::now(),
            state: Arc::new(Mutex::new(HealthState {
                refusing: None,
                refused: 0,
                failed_s: None,
                restarts: 0,
                rogue: BTreeMap::new(),
            })),
        }
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    fn lock(&self) -> MutexGuard<'_, HealthState> {
        // Every update is a few field writes: a poisoned lock is still consistent.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn now_s(&self) -> f64 {
        self.epoch.elapsed().as_secs_f64()
    }

    /// The accept loop's state after one accept: `Some(reason)` refused or delayed, `None` served.
    pub fn refusing(&self, now: Option<Refusal>) {
        let mut st = self.lock();
        if let Some(r) = now {
            st.refused += 1;
            if st.refusing.map(|(was, _)| was) == Some(r) {
                return;
            }
        }
        let t_s = self.now_s();
        if let Some((was, since)) = st.refusing.take() {
            tracing::info!(
                listener = &*self.name,
                reason = ?was,
                refused = st.refused - u64::from(now.is_some()),
                lasted_s = t_s - since,
                "listener: fault cleared"
            );
            st.refused = u64::from(now.is_some());
        }
        if let Some(r) = now {
            tracing::warn!(listener = &*self.name, reason = ?r, "listener: fault, refusing or delaying connections");
            st.refusing = Some((r, t_s));
        }
        // Serving again also ends a failure episode (the restarted listener accepted).
        if now.is_none()
            && let Some(since) = st.failed_s.take()
        {
            tracing::info!(
                listener = &*self.name,
                lasted_s = t_s - since,
                restarts = st.restarts,
                "listener: serving again after a restart"
            );
        }
    }

    /// The listener's accept loop ended (`why`); it is being restarted.
    pub fn failed(&self, why: &str) {
        let mut st = self.lock();
        st.restarts += 1;
        if st.failed_s.is_none() {
            st.failed_s = Some(self.now_s());
            tracing::error!(
                listener = &*self.name,
                why,
                "listener: fault, failed; restarting it"
            );
        }
    }

    /// A write or action from `peer` was refused (not on `allow_writes_from`).
    pub fn refused_write(&self, peer: IpAddr) {
        let t_s = self.now_s();
        let mut st = self.lock();
        match st.rogue.get_mut(&peer) {
            Some((_, last)) => *last = t_s,
            None => {
                tracing::warn!(listener = &*self.name, %peer, "listener: fault, write refused from a peer not on allow_writes_from");
                st.rogue.insert(peer, (t_s, t_s));
            }
        }
    }

    /// Active faults: (source, kind, since s). Rogue peers quiet for [`ROGUE_HOLD_S`] clear here
    /// (logged once).
    pub fn faults(&self) -> Vec<(String, FaultKind, f64)> {
        let t_s = self.now_s();
        let mut st = self.lock();
        st.rogue.retain(|peer, (first, last)| {
            let keep = t_s - *last < ROGUE_HOLD_S;
            if !keep {
                tracing::info!(listener = &*self.name, %peer, lasted_s = *last - *first, "listener: fault cleared, no more refused writes from the peer");
            }
            keep
        });
        let mut out = Vec::new();
        if let Some((_, since)) = st.refusing {
            out.push((
                format!("listener.{}", self.name),
                FaultKind::Overloaded,
                since,
            ));
        }
        if let Some(since) = st.failed_s {
            out.push((
                format!("listener.{}", self.name),
                FaultKind::ListenerFailed,
                since,
            ));
        }
        for (peer, (first, _)) in &st.rogue {
            out.push((
                format!("listener.{}.peer.{peer}", self.name),
                FaultKind::Unauthorized,
                *first,
            ));
        }
        out
    }

    /// Times the listener was restarted since it started.
    pub fn restarts(&self) -> u64 {
        self.lock().restarts
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ip(s: &str) -> IpAddr {
        s.parse().unwrap()
    }

    #[test]
    fn caps_per_peer_and_total_and_reserve() {
        let p = ListenPolicy {
            max_connections: 3,
            max_connections_per_peer: 2,
            allow_writes_from: vec![ip("127.0.0.1")],
            ..ListenPolicy::default()
        };
        let mut a = Admissions::default();
        let rogue = [ip("127.0.0.2"), ip("127.0.0.3")];
        assert_eq!(a.admit(&p, rogue[0], None), Ok(()));
        assert_eq!(a.admit(&p, rogue[0], None), Ok(()));
        assert_eq!(a.admit(&p, rogue[0], None), Err(Refusal::PeerCap));
        assert_eq!(a.admit(&p, rogue[1], None), Ok(()));
        assert_eq!(a.admit(&p, rogue[1], None), Err(Refusal::Busy));
        // The controller is held only to its per-peer cap: the flood does not lock it out.
        assert_eq!(a.admit(&p, ip("127.0.0.1"), None), Ok(()));
        assert_eq!(
            a.admit(&p, ip("::ffff:127.0.0.1"), Some((10, 1024))),
            Ok(())
        );
        assert_eq!(
            a.admit(&p, ip("127.0.0.1"), Some((900, 1024))),
            Err(Refusal::FdReserve)
        );
        assert_eq!(a.held(), 5);
        a.release(&p, rogue[1]);
        assert_eq!(a.admit(&p, rogue[1], None), Ok(()));
        for _ in 0..10 {
            a.release(&p, rogue[0]);
        }
        assert_eq!(a.held(), 3);
        assert_eq!(a.admit(&p, rogue[0], None), Ok(()));
    }

    #[test]
    fn check_names_the_key() {
        let ok = ListenPolicy::default();
        assert_eq!(ok.check("opcua"), Ok(()));
        let bad = |f: fn(&mut ListenPolicy)| {
            let mut p = ListenPolicy::default();
            f(&mut p);
            let (key, what) = p.check("sink.origin_shift_server").unwrap_err();
            format!("{key}: {what}")
        };
        assert!(bad(|p| p.max_connections = 0).contains("listen_policy.max_connections:"));
        assert!(bad(|p| p.max_connections_per_peer = 65).contains("max_connections_per_peer"));
        assert!(bad(|p| p.idle_timeout_s = f64::NAN).contains("idle_timeout_s"));
        assert!(bad(|p| p.allow_writes_from = vec![ip("0.0.0.0")]).contains("allow_writes_from"));
        assert!(ok.may_write(ip("::1")) && !ok.may_write(ip("127.0.0.2")));
    }

    #[test]
    fn health_reports_each_episode_once() {
        let h = ListenerHealth::new("t");
        assert!(h.faults().is_empty());
        for _ in 0..1000 {
            h.refusing(Some(Refusal::AcceptError));
        }
        h.refused_write(ip("127.0.0.2"));
        h.refused_write(ip("127.0.0.2"));
        let f = h.faults();
        assert_eq!(f.len(), 2, "{f:?}");
        assert_eq!(f[0].1, FaultKind::Overloaded);
        assert_eq!(f[1].0, "listener.t.peer.127.0.0.2");
        assert_eq!(f[1].1, FaultKind::Unauthorized);
        h.failed("test");
        h.refusing(None);
        assert_eq!(h.faults().len(), 1);
        assert_eq!(h.restarts(), 1);
    }
}
