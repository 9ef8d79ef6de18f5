//! Sensor faults on demand, applied to a sampled channel value inside a time window:
//! `stuck` (holds the value it had when the fault began), `dropout` (no value: the bus stays silent
//! and the recording cell is empty), `spike` (Poisson-timed single-sample spikes of `spike_size`),
//! `nan` (the sensor reports NaN).

use crate::config::FaultConfig;
use crate::rng::Noise;
use serde::{Deserialize, Serialize};

#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    Stuck,
    Dropout,
    Spike,
    Nan,
}

#[derive(Clone, Debug)]
pub struct Fault {
    pub cfg: FaultConfig,
    stuck: Option<f64>,
    next_spike_s: f64,
    noise: Noise,
}

impl Fault {
    pub fn new(cfg: FaultConfig, seed: u64, index: usize) -> Self {
        let mut noise = Noise::new(seed, &format!("fault/{index}/{}", cfg.channel));
        let next_spike_s = cfg.from_s + noise.exp_wait(cfg.spike_every_s);
        Self {
            cfg,
            stuck: None,
            next_spike_s,
            noise,
        }
    }

    /// Apply to a sampled value at time `t_s`. `None` = no reading.
    pub fn apply(&mut self, t_s: f64, value: Option<f64>) -> Option<f64> {
        let active = t_s >= self.cfg.from_s && t_s <= self.cfg.to_s;
        if !active {
            self.stuck = None;
            return value;
        }
        match self.cfg.kind {
            FaultKind::Stuck => Some(*self.stuck.get_or_insert(value.unwrap_or(f64::NAN))),
            FaultKind::Dropout => None,
            FaultKind::Nan => Some(f64::NAN),
            FaultKind::Spike => {
                if t_s >= self.next_spike_s {
                    while self.next_spike_s <= t_s {
                        self.next_spike_s += self.noise.exp_wait(self.cfg.spike_every_s);
                    }
                    value.map(|v| v + self.cfg.spike_size)
                } else {
                    value
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(kind: FaultKind) -> FaultConfig {
        FaultConfig {
            channel: "T_a_C".into(),
            kind,
            from_s: 1.0,
            to_s: 2.0,
            spike_size: 50.0,
            spike_every_s: 0.1,
        }
    }

    #[test]
    fn each_kind_acts_only_inside_its_window() {
        let mut s = Fault::new(cfg(FaultKind::Stuck), 1, 0);
        assert_eq!(s.apply(0.5, Some(1.0)), Some(1.0));
        assert_eq!(s.apply(1.0, Some(2.0)), Some(2.0));
        assert_eq!(
            s.apply(1.5, Some(3.0)),
            Some(2.0),
            "stuck at the value it had"
        );
        assert_eq!(s.apply(2.5, Some(4.0)), Some(4.0));
        let mut d = Fault::new(cfg(FaultKind::Dropout), 1, 0);
        assert_eq!(d.apply(1.5, Some(3.0)), None);
        let mut n = Fault::new(cfg(FaultKind::Nan), 1, 0);
        assert!(n.apply(1.5, Some(3.0)).unwrap().is_nan());
        let mut sp = Fault::new(cfg(FaultKind::Spike), 1, 0);
        let spikes = (0..1000)
            .filter(|i| sp.apply(1.0 + f64::from(*i) * 0.001, Some(0.0)) == Some(50.0))
            .count();
        // 1 s window, one spike per 0.1 s on average: Poisson(10), far from 0 and from 1000.
        assert!((2..40).contains(&spikes), "{spikes} spikes");
    }
}
