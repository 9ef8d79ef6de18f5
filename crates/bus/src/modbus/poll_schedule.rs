//! When a Modbus source connects and reads, sans-IO: the poll period, the reconnect backoff after a
//! failed connect or a read without answer, and which block is read next. The async shell
//! ([`super::ModbusPoller`]) and the virtual-time gateway (`retrocomp-gateway`'s `GatewayCore`,
//! driven by hil-sim's harness) both run it, so a change of the reconnect or stale rule is one
//! change under both.
//!
//! Driving vocabulary: [`PollSchedule::poll_timeout`] says when the next poll is due;
//! [`PollSchedule::poll`] starts it and returns the first [`PollStep`]; the I/O's result goes back
//! through [`PollSchedule::handle_connect`] or [`PollSchedule::handle_outcome`], each returning the
//! next step, until [`PollStep::Done`]. Times are seconds on the caller's monotonic clock; samples
//! are stamped with the poll's start.
//!
//! The rule (as the poller always had it): a poll reads every planned block in order; a timeout or
//! transport failure drops the connection and the rest of the poll's blocks go `Stale` (last good
//! value kept); the next connect is tried no earlier than the backoff after the failure (doubling
//! up to its maximum, reset by a successful connect); while it may not be tried, every block of a
//! poll is `Stale`. Polls start every `period_s`; one that overran its period starts the next one a
//! whole period after it began late.

use super::poll_core::{PollCore, PollCounters, ReadOutcome};
use super::poller::ModbusSourceConfig;
use crate::{Backoff, ChannelTable, Sample};

/// The I/O the schedule asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PollRequest {
    /// Open the connection (the shell bounds it by `timeout_s`).
    Connect,
    /// Read planned block `b` ([`PollCore::plan`]).
    Read(usize),
}

/// What to do after a poll or one of its steps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PollStep {
    /// Do this I/O and hand its result back.
    Request(PollRequest),
    /// The poll ended (its samples are out): the counters around it and the link after it.
    Done {
        before: PollCounters,
        after: PollCounters,
        connected: bool,
    },
    /// Nothing due (no poll now, or one is waiting for its I/O).
    Idle,
}

#[derive(Clone, Copy, Debug)]
enum Busy {
    Connecting,
    Reading(usize),
}

/// The poll being run: its stamp, the counters before it, what it waits for.
#[derive(Clone, Copy, Debug)]
struct Running {
    stamp_s: f64,
    before: PollCounters,
    busy: Busy,
}

/// One Modbus source's schedule around its [`PollCore`].
#[derive(Debug, Clone)]
pub struct PollSchedule {
    pub core: PollCore,
    period_s: f64,
    backoff: Backoff,
    connected: bool,
    /// No connect before this.
    next_connect_s: f64,
    /// The next poll's start (the first poll: at once).
    next_poll_s: f64,
    running: Option<Running>,
}

impl PollSchedule {
    /// The schedule of `cfg`, its channels resolved in `channels` (the gateway's table).
    pub fn new(cfg: &ModbusSourceConfig, channels: &mut ChannelTable) -> Self {
        PollSchedule {
            core: PollCore::new(cfg.channel.clone(), channels, 125, cfg.max_gap),
            period_s: if cfg.period_s.is_finite() {
                cfg.period_s.max(1e-3)
            } else {
                1.0
            },
            backoff: Backoff::from_secs_f64(cfg.backoff_min_s, cfg.backoff_max_s),
            connected: false,
            next_connect_s: f64::NEG_INFINITY,
            next_poll_s: f64::NEG_INFINITY,
            running: None,
        }
    }

    pub fn is_connected(&self) -> bool {
        self.connected
    }

    pub fn counters(&self) -> PollCounters {
        self.core.counters
    }

    /// When the next poll is due (None while one waits for its I/O).
    pub fn poll_timeout(&self) -> Option<f64> {
        match self.running {
            Some(_) => None,
            None => Some(self.next_poll_s),
        }
    }

    /// Start the poll due at `now_s` (samples stamped `stamp_s`), or [`PollStep::Idle`].
    pub fn poll(&mut self, now_s: f64, stamp_s: f64, out: &mut Vec<Sample>) -> PollStep {
        if self.running.is_some() || now_s < self.next_poll_s {
            return PollStep::Idle;
        }
        let next = self.next_poll_s + self.period_s;
        self.next_poll_s = if next > now_s {
            next
        } else {
            now_s + self.period_s
        };
        self.begin(now_s, stamp_s, out)
    }

    /// Start a poll now, whatever the period says (the shell's `poll_once`).
    pub fn begin(&mut self, now_s: f64, stamp_s: f64, out: &mut Vec<Sample>) -> PollStep {
        let before = self.core.counters;
        if !self.connected && now_s >= self.next_connect_s {
            self.running = Some(Running {
                stamp_s,
                before,
                busy: Busy::Connecting,
            });
            return PollStep::Request(PollRequest::Connect);
        }
        self.running = Some(Running {
            stamp_s,
            before,
            busy: Busy::Reading(0),
        });
        self.next_block(0, out)
    }

    /// The connect the schedule asked for succeeded (`ok`) or failed / timed out, at `now_s`.
    pub fn handle_connect(&mut self, ok: bool, now_s: f64, out: &mut Vec<Sample>) -> PollStep {
        if !matches!(
            self.running,
            Some(Running {
                busy: Busy::Connecting,
                ..
            })
        ) {
            return PollStep::Idle;
        }
        if ok {
            self.core.counters.connects += 1;
            self.backoff.reset();
            self.connected = true;
        } else {
            self.core.counters.connect_failures += 1;
            self.failed(now_s);
        }
        self.next_block(0, out)
    }

    /// The read the schedule asked for came back with `outcome` at `now_s`.
    pub fn handle_outcome(
        &mut self,
        outcome: &ReadOutcome,
        now_s: f64,
        out: &mut Vec<Sample>,
    ) -> PollStep {
        let Some(Running {
            stamp_s,
            busy: Busy::Reading(b),
            ..
        }) = self.running
        else {
            return PollStep::Idle;
        };
        if matches!(outcome, ReadOutcome::Timeout | ReadOutcome::Transport(_)) {
            // The context may hold a late reply or a half frame: the shell rebuilds it.
            self.failed(now_s);
        }
        self.core.handle_outcome(b, outcome, stamp_s, out);
        self.next_block(b + 1, out)
    }

    fn failed(&mut self, now_s: f64) {
        self.connected = false;
        self.next_connect_s = now_s + self.backoff.next_delay().as_secs_f64();
    }

    /// Read block `b` next, or (link down) every block from `b` on is stale and the poll ends.
    fn next_block(&mut self, b: usize, out: &mut Vec<Sample>) -> PollStep {
        let Some(run) = self.running.as_mut() else {
            return PollStep::Idle;
        };
        if self.connected && b < self.core.plan.len() {
            run.busy = Busy::Reading(b);
            return PollStep::Request(PollRequest::Read(b));
        }
        let (stamp_s, before) = (run.stamp_s, run.before);
        for rest in b..self.core.plan.len() {
            self.core.stale_block(rest, stamp_s, out);
        }
        self.running = None;
        PollStep::Done {
            before,
            after: self.core.counters,
            connected: self.connected,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Health;

    fn cfg() -> ModbusSourceConfig {
        toml::from_str(
            r#"
name = "rtu"
transport = "rtu"
device = "/dev/null"
period_s = 0.125
timeout_s = 0.0625
backoff_min_s = 0.25
backoff_max_s = 1.0
channel = [
  { channel = "A_C", kind = "input", address = 0, type = "int16", scale = 0.1 },
  { channel = "B_C", kind = "input", address = 10, type = "int16", scale = 0.1 },
]
"#,
        )
        .unwrap()
    }

    fn healths(out: &[Sample]) -> Vec<Health> {
        out.iter().map(|s| s.health).collect()
    }

    #[test]
    fn connect_then_every_block_in_order_once_per_period() {
        let mut s = PollSchedule::new(&cfg(), &mut ChannelTable::default());
        assert_eq!(s.core.plan.len(), 2, "two blocks (max_gap 0)");
        let mut out = Vec::new();
        assert_eq!(s.poll_timeout(), Some(f64::NEG_INFINITY));
        assert_eq!(
            s.poll(0.0, 0.0, &mut out),
            PollStep::Request(PollRequest::Connect)
        );
        assert_eq!(s.poll_timeout(), None, "waiting for the connect");
        assert_eq!(
            s.handle_connect(true, 0.01, &mut out),
            PollStep::Request(PollRequest::Read(0))
        );
        let words = ReadOutcome::Registers(vec![215]);
        assert_eq!(
            s.handle_outcome(&words, 0.02, &mut out),
            PollStep::Request(PollRequest::Read(1))
        );
        let done = s.handle_outcome(&words, 0.03, &mut out);
        assert!(
            matches!(done, PollStep::Done { connected: true, after, .. } if after.responses == 2)
        );
        assert_eq!(healths(&out), [Health::Ok, Health::Ok]);
        assert!(
            out.iter().all(|x| x.t_s == 0.0),
            "stamped at the poll's start"
        );
        assert_eq!(s.poll_timeout(), Some(0.125));
        assert_eq!(s.poll(0.0625, 0.0625, &mut out), PollStep::Idle);
        assert_eq!(
            s.poll(0.125, 0.125, &mut out),
            PollStep::Request(PollRequest::Read(0)),
            "connected: no second connect"
        );
    }

    #[test]
    fn a_timeout_drops_the_link_stales_the_rest_and_reconnects_after_the_doubling_backoff() {
        let mut s = PollSchedule::new(&cfg(), &mut ChannelTable::default());
        let mut out = Vec::new();
        s.poll(0.0, 0.0, &mut out);
        s.handle_connect(true, 0.0, &mut out);
        let words = ReadOutcome::Registers(vec![215]);
        s.handle_outcome(&words, 0.0, &mut out);
        s.handle_outcome(&words, 0.0, &mut out);
        out.clear();
        // The next poll: block 0 times out 62.5 ms later; block 1 is not read, stale.
        assert_eq!(
            s.poll(0.125, 0.125, &mut out),
            PollStep::Request(PollRequest::Read(0))
        );
        let done = s.handle_outcome(&ReadOutcome::Timeout, 0.1875, &mut out);
        assert!(matches!(
            done,
            PollStep::Done {
                connected: false,
                ..
            }
        ));
        assert_eq!(healths(&out), [Health::Stale, Health::Stale]);
        assert_eq!(out[0].value, 21.5, "the last good value kept");
        assert_eq!(s.counters().timeouts, 1);
        // The backoff, 0.25 s from the failure (0.4375): the polls before are stale without I/O.
        for t in [0.25, 0.375] {
            out.clear();
            let step = s.poll(t, t, &mut out);
            assert!(
                matches!(
                    step,
                    PollStep::Done {
                        connected: false,
                        ..
                    }
                ),
                "{t}: {step:?}"
            );
            assert_eq!(healths(&out), [Health::Stale, Health::Stale]);
        }
        // The connect at 0.5 fails: the next wait is 0.5 s (doubled), then 1 s (the maximum).
        assert_eq!(
            s.poll(0.5, 0.5, &mut out),
            PollStep::Request(PollRequest::Connect)
        );
        s.handle_connect(false, 0.5, &mut out);
        assert!(matches!(
            s.poll(0.875, 0.875, &mut out),
            PollStep::Done { .. }
        ));
        assert_eq!(
            s.poll(1.0, 1.0, &mut out),
            PollStep::Request(PollRequest::Connect)
        );
        s.handle_connect(false, 1.0, &mut out);
        assert!(matches!(
            s.poll(1.875, 1.875, &mut out),
            PollStep::Done { .. }
        ));
        assert_eq!(
            s.poll(2.0, 2.0, &mut out),
            PollStep::Request(PollRequest::Connect)
        );
        // Back: the backoff starts over at its minimum.
        assert_eq!(
            s.handle_connect(true, 2.0, &mut out),
            PollStep::Request(PollRequest::Read(0))
        );
        s.handle_outcome(&ReadOutcome::Timeout, 2.0625, &mut out);
        assert!(matches!(
            s.poll(2.25, 2.25, &mut out),
            PollStep::Done { .. }
        ));
        assert_eq!(
            s.poll(2.375, 2.375, &mut out),
            PollStep::Request(PollRequest::Connect),
            "0.25 s after the failure at 2.0625"
        );
    }

    #[test]
    fn a_poll_that_overran_its_period_starts_the_next_a_period_after_it_began() {
        let mut s = PollSchedule::new(&cfg(), &mut ChannelTable::default());
        let mut out = Vec::new();
        s.poll(0.0, 0.0, &mut out);
        s.handle_connect(true, 0.0, &mut out);
        s.handle_outcome(&ReadOutcome::Registers(vec![1]), 0.0, &mut out);
        s.handle_outcome(&ReadOutcome::Registers(vec![1]), 0.0, &mut out);
        assert_eq!(s.poll_timeout(), Some(0.125));
        // The shell came back late (0.4375): the poll runs now, the next one a period later.
        s.poll(0.4375, 0.4375, &mut out);
        assert_eq!(s.poll_timeout(), None);
        s.handle_outcome(&ReadOutcome::Registers(vec![1]), 0.4375, &mut out);
        s.handle_outcome(&ReadOutcome::Registers(vec![1]), 0.4375, &mut out);
        assert_eq!(s.poll_timeout(), Some(0.5625));
    }
}
