//! Rate limit of Sparkplug rebirths, sans-IO (times passed in, ms on any monotonic clock), used on
//! both sides of `Node Control/Rebirth`:
//! - the box ([`super::publisher`]) answers NCMD rebirth requests with at most one NBIRTH per
//!   `telemetry.mqtt.rebirth_min_interval_s`: a request inside the interval is remembered and
//!   answered once the interval has passed, so a storm of requests costs one NBIRTH per interval;
//! - the fleet host (`retrocomp_fleet::FleetView`) asks each node for a rebirth at most once per interval while
//!   it has no birth for it (every NDATA of an unknown node would otherwise be one NCMD).
//!
//! Any NBIRTH (asked for or not) answers what is pending and starts a new interval.

/// One node's (or one box's) rebirth bookkeeping.
#[derive(Clone, Debug)]
pub struct RebirthLimiter {
    min_interval_ms: u64,
    /// When the last NBIRTH went out (box) or the last request went out (host).
    last_ms: Option<u64>,
    /// A request not answered yet.
    pending: bool,
}

impl RebirthLimiter {
    pub fn new(min_interval_ms: u64) -> Self {
        RebirthLimiter {
            min_interval_ms,
            last_ms: None,
            pending: false,
        }
    }

    /// A rebirth is wanted at `now_ms`: true when it may happen now (the caller does it and the
    /// interval restarts); false when it is deferred to [`RebirthLimiter::due_ms`].
    pub fn request(&mut self, now_ms: u64) -> bool {
        if self.allowed(now_ms) {
            self.fired(now_ms);
            true
        } else {
            self.pending = true;
            false
        }
    }

    /// A deferred request whose time has come: true once (the caller does it now).
    pub fn poll(&mut self, now_ms: u64) -> bool {
        if self.pending && self.allowed(now_ms) {
            self.fired(now_ms);
            true
        } else {
            false
        }
    }

    /// When a deferred request becomes due (None: nothing pending).
    pub fn due_ms(&self) -> Option<u64> {
        self.pending.then(|| {
            self.last_ms
                .map_or(0, |l| l.saturating_add(self.min_interval_ms))
        })
    }

    /// An NBIRTH happened at `now_ms` (whatever caused it): it answers what was pending.
    pub fn born(&mut self, now_ms: u64) {
        self.fired(now_ms);
    }

    /// The node is gone (NDEATH): nothing to ask until it shows up again.
    pub fn forget(&mut self) {
        self.pending = false;
    }

    fn allowed(&self, now_ms: u64) -> bool {
        self.last_ms
            .is_none_or(|l| now_ms >= l.saturating_add(self.min_interval_ms))
    }

    fn fired(&mut self, now_ms: u64) {
        self.last_ms = Some(now_ms);
        self.pending = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_storm_of_requests_yields_one_rebirth_per_interval_and_none_is_lost() {
        let mut l = RebirthLimiter::new(1000);
        let mut fired = vec![];
        // 200 requests in 2 s (every 10 ms), polled every ms.
        for t in 0..3000u64 {
            if t < 2000 && t % 10 == 0 && l.request(t) {
                fired.push(t);
            }
            if l.poll(t) {
                fired.push(t);
            }
        }
        assert_eq!(
            fired,
            vec![0, 1000, 2000],
            "the last request (1990) answered at 2000"
        );
        assert_eq!(l.due_ms(), None);
    }

    #[test]
    fn a_birth_answers_what_is_pending_and_restarts_the_interval() {
        let mut l = RebirthLimiter::new(500);
        l.born(100);
        assert!(
            !l.request(300),
            "inside the interval of the connect's NBIRTH"
        );
        assert_eq!(l.due_ms(), Some(600));
        l.born(400);
        assert_eq!(l.due_ms(), None, "the NBIRTH at 400 answered it");
        assert!(!l.poll(10_000));
        assert!(l.request(900));
        assert!(!l.request(901));
        l.forget();
        assert!(!l.poll(5000), "a node that died is not asked");
    }
}
