//! End-to-end latency of the data a Sparkplug host receives: the host's clock when an NDATA
//! arrived minus the NDATA's Sparkplug timestamp (the box's clock when it sampled the record), in
//! ms. Both are ms since the Unix epoch, so a value is within ±1 ms of the true delay when box and
//! host share a clock (one machine, or NTP-synchronised); a box clock ahead of the host counts as
//! 0. Records a box held in its store-and-forward queue through an outage count with their whole
//! delay: that is what the plant saw.
//!
//! A fixed histogram (1 ms buckets up to [`MAX_MS`], one overflow bucket), allocated once, so a
//! host that runs for months keeps constant memory and recording is O(1).

use serde::Serialize;

/// The largest latency with its own bucket, ms; longer ones count in the overflow bucket (their
/// quantile reads as `MAX_MS + 1`, "more than").
pub(crate) const MAX_MS: u64 = 60_000;

/// Buckets 0 …= `MAX_MS` ms and the overflow bucket.
const BUCKETS: usize = 60_002;
// Checked when the crate compiles, not by a test that runs.
const _: () = assert!(
    BUCKETS as u64 == MAX_MS + 2,
    "one bucket per ms up to MAX_MS, one over"
);

#[derive(Clone, Debug)]
pub struct LatencyHistogram {
    buckets: Vec<u64>,
    n: u64,
    max_ms: u64,
}

/// A histogram's summary: count, p50, p99 and max, ms (None without data).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
pub struct LatencySummary {
    pub n: u64,
    pub p50_ms: Option<u64>,
    pub p99_ms: Option<u64>,
    pub max_ms: Option<u64>,
}

impl Default for LatencyHistogram {
    fn default() -> Self {
        LatencyHistogram {
            buckets: vec![0; BUCKETS],
            n: 0,
            max_ms: 0,
        }
    }
}

impl LatencyHistogram {
    /// Count one latency, ms.
    pub fn record(&mut self, ms: u64) {
        // ≤ MAX_MS + 1, which is an index on any target.
        let i = usize::try_from(ms.min(MAX_MS + 1)).unwrap_or(BUCKETS - 1);
        self.buckets[i] += 1;
        self.n += 1;
        self.max_ms = self.max_ms.max(ms);
    }

    /// Latencies counted.
    pub fn count(&self) -> u64 {
        self.n
    }

    /// The smallest latency (ms) with at least `q` of the counts at or below it (`q` in 0..=1);
    /// None when empty. `MAX_MS + 1` means "more than `MAX_MS`".
    pub fn quantile(&self, q: f64) -> Option<u64> {
        if self.n == 0 {
            return None;
        }
        // Rank of the quantile, 1-based (nearest rank).
        #[allow(
            clippy::cast_possible_truncation,
            clippy::cast_sign_loss,
            clippy::cast_precision_loss
        )]
        let rank = ((q.clamp(0.0, 1.0) * self.n as f64).ceil() as u64).max(1);
        let mut seen = 0;
        for (ms, c) in self.buckets.iter().enumerate() {
            seen += c;
            if seen >= rank {
                return Some(ms as u64);
            }
        }
        Some(MAX_MS + 1)
    }

    pub fn summary(&self) -> LatencySummary {
        LatencySummary {
            n: self.n,
            p50_ms: self.quantile(0.5),
            p99_ms: self.quantile(0.99),
            max_ms: (self.n > 0).then_some(self.max_ms),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_are_nearest_rank_and_overflow_reads_as_more_than_the_top() {
        let mut h = LatencyHistogram::default();
        assert_eq!(h.summary(), LatencySummary::default());
        for ms in 1..=100 {
            h.record(ms);
        }
        assert_eq!(h.quantile(0.5), Some(50));
        assert_eq!(h.quantile(0.99), Some(99));
        assert_eq!(h.quantile(1.0), Some(100));
        h.record(MAX_MS * 3);
        let s = h.summary();
        assert_eq!((s.n, s.max_ms), (101, Some(MAX_MS * 3)));
        assert_eq!(h.quantile(1.0), Some(MAX_MS + 1));
    }
}
