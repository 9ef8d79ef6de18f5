//! A simulated scale for the simulated sink (no `gpio` lines): native encoder edges that the
//! injector merges with the injected ones exactly as it would a real scale's, so the merged stream
//! (and its trace, [`super::trace`]) can be checked by a counter outside the project.
//!
//! The scale plays `moves_counts` once, in order (+ counts up, − down), one edge every
//! `1 / rate_hz` s, starting when the sink opens its lines; then it is still. Units: counts (A/B
//! edges), Hz. Refused with `gpio` lines (`config/check.rs`): the GPIO shell carries injected
//! counts only.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::Sender;
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use super::gray::Step;
use super::injector::Feed;

/// `simulated_native = { moves_counts = [...], rate_hz = ... }` of a `[[sink.quadrature.axis]]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimulatedNative {
    /// Moves of the scale, counts, played once in order.
    pub moves_counts: Vec<i64>,
    /// Edges per second while moving (an in-spec encoder: at most 1 / `min_edge_gap_ns`).
    pub rate_hz: f64,
}

impl SimulatedNative {
    /// Net native counts once every move is played.
    pub fn net_counts(&self) -> i64 {
        self.moves_counts.iter().sum()
    }

    /// Why this scale cannot run with `min_edge_gap_ns`, if it cannot.
    pub fn check(&self, min_edge_gap_ns: u64) -> Result<(), String> {
        let max_hz = 1e9 / min_edge_gap_ns.max(1) as f64;
        if !(self.rate_hz.is_finite() && self.rate_hz > 0.0 && self.rate_hz <= max_hz) {
            return Err(format!(
                "expected 0 < rate_hz ≤ {max_hz} (an in-spec encoder keeps min_edge_gap_ns), got {}",
                self.rate_hz
            ));
        }
        if self
            .moves_counts
            .iter()
            .map(|m| m.unsigned_abs())
            .sum::<u64>()
            > 100_000_000
        {
            return Err("expected at most 10^8 edges in moves_counts".into());
        }
        Ok(())
    }
}

/// The scale's thread: sends its edges into `feed` until done or `stop` is set.
pub(crate) fn spawn_scale(
    sim: SimulatedNative,
    feed: Sender<Feed>,
    stop: Arc<AtomicBool>,
    axis: &str,
) -> std::io::Result<std::thread::JoinHandle<()>> {
    std::thread::Builder::new()
        .name(format!("scale-sim-{axis}"))
        .spawn(move || {
            let period = Duration::from_secs_f64(1.0 / sim.rate_hz);
            let start = Instant::now();
            let mut n = 0u32;
            for &m in &sim.moves_counts {
                let Some(step) = Step::of_sign(m) else {
                    continue;
                };
                for _ in 0..m.unsigned_abs() {
                    if stop.load(Ordering::Relaxed) || feed.send(Feed::Native(step)).is_err() {
                        return;
                    }
                    n += 1;
                    // Paced on the start, so sleep overshoot does not accumulate.
                    if let Some(wait) = (period * n).checked_sub(start.elapsed()) {
                        std::thread::sleep(wait);
                    }
                }
            }
        })
}
