//! The origin-shift sink's Modbus client connection in virtual time: the same decisions as
//! `retrocomp_gateway::sinks::origin_shift::OriginShiftClient` (`ensure_connected` / `failed`), driven by the
//! workspace's one reconnect backoff ([`Backoff`], `reconnect_min_ms` / `reconnect_max_ms` of the
//! field file), with the harness' clock passed in instead of tokio's:
//!
//! - connected: every request goes out; a request that finds the link down fails, drops the
//!   connection and schedules the next attempt one backoff delay later (`min`, then doubling to
//!   `max`);
//! - not connected: a period before the scheduled attempt fails at once without trying (the
//!   client's `Disconnected`); the first period at or after it tries to connect: success (the link
//!   is up) resets the backoff, failure schedules the next attempt.
//!
//! Time is a [`Duration`] since the world's start (whole steps), so the schedule's instants compare
//! exactly; attempts are logged in seconds for the scenarios.

use std::time::Duration;

use retrocomp_bus::Backoff;

/// One connection attempt of the client.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ConnectAttempt {
    pub t_s: f64,
    pub ok: bool,
}

#[derive(Clone, Debug)]
pub struct ClientLink {
    connected: bool,
    backoff: Backoff,
    next_attempt: Duration,
    attempts: Vec<ConnectAttempt>,
}

impl ClientLink {
    /// A client that just connected (the gateway's start read what the controller holds).
    pub fn connected(reconnect_min_ms: u64, reconnect_max_ms: u64) -> Self {
        Self {
            connected: true,
            backoff: Backoff::from_millis(reconnect_min_ms, reconnect_max_ms),
            next_attempt: Duration::ZERO,
            attempts: Vec::new(),
        }
    }

    pub fn is_connected(&self) -> bool {
        self.connected
    }

    /// At the start of a write period (`now` on the harness clock, `t_s` the same instant in s):
    /// connect unless connected, respecting the backoff. Returns whether the period may run.
    pub fn ensure_connected(&mut self, now: Duration, t_s: f64, link_up: bool) -> bool {
        if self.connected {
            return true;
        }
        if now < self.next_attempt {
            return false;
        }
        self.attempts.push(ConnectAttempt { t_s, ok: link_up });
        if link_up {
            self.connected = true;
            self.backoff.reset();
        } else {
            self.failed(now);
        }
        self.connected
    }

    /// A request or a connect failed at `now`: drop the connection, wait one backoff delay.
    pub fn failed(&mut self, now: Duration) {
        self.connected = false;
        self.next_attempt = self.backoff.retry_at(now);
    }

    /// Every connection attempt after the first connection, in order.
    pub fn attempts(&self) -> &[ConnectAttempt] {
        &self.attempts
    }
}
