//! The quadrature sink's sans-IO core: per axis, the cycle's correction (µm, = −error) passes the
//! box's one last-step guard ([`crate::sinks::guard`]), then becomes whole counts ([`CountQuantizer`]),
//! persisted ahead of the edges ([`write_ahead`]) and handed to the injector as a delta.
//!
//! Pulses have no read-back: the guard's evidence of what the controller holds is the held count
//! persisted ahead of every step ([`super::held`]), read at start as the controller's value (a
//! count beyond the clamp is a `BeyondClamp` fault: that axis injects nothing and is not ramped
//! from), then every count handed out (unconfirmed until the injector has put all its edges on the
//! lines, [`QuadratureCore::settled`]). The guard's output resolution is one count
//! (`resolution_um`), so a step is whole counts within the clamp and the per-write cap.
//!
//! Stop ([`QuadratureCore::begin_ramp_out`]): every axis wants 0, at most one cap per step, until
//! the controller holds 0 counts on every axis.

use std::collections::BTreeMap;

use super::CountQuantizer;
use super::config::QuadratureSink;
use super::counts::CountError;
use super::held::{HeldCounts, HeldError, write_ahead};
use crate::sinks::StartValues;
use crate::sinks::guard::{AxisLimits, SinkFaults, Verdict, WriteGuard};
use retrocomp_model::Axis;

#[derive(Clone, Debug)]
struct CoreAxis {
    name: String,
    axis: Option<Axis>,
    quant: CountQuantizer,
}

/// Guard, quantizer and write-ahead of every configured axis (the config's axis order).
#[derive(Clone, Debug)]
pub struct QuadratureCore {
    axes: Vec<CoreAxis>,
    guard: WriteGuard,
    faults: SinkFaults,
    ramping_out: bool,
}

impl QuadratureCore {
    /// Continue from `held` counts per axis (0 for an axis not given).
    pub fn new(
        cfg: &QuadratureSink,
        limits: &[AxisLimits],
        held: &BTreeMap<String, i64>,
    ) -> Result<Self, CountError> {
        let mut axes = Vec::with_capacity(cfg.axes.len());
        for a in &cfg.axes {
            let n = held.get(&a.axis).copied().unwrap_or(0);
            axes.push(CoreAxis {
                name: a.axis.clone(),
                axis: Axis::from_name(&a.axis),
                quant: CountQuantizer::continuing_from(a.resolution_um, a.count_sign, n)?,
            });
        }
        let mut guard = WriteGuard::new(
            cfg.axes
                .iter()
                .map(|a| AxisLimits::of(limits, &a.axis, a.resolution_um)),
        );
        for (i, a) in axes.iter().enumerate() {
            guard.observe_read(i, a.quant.correction_um_of(a.quant.emitted_counts()));
        }
        let n = axes.len();
        Ok(Self {
            axes,
            guard,
            faults: SinkFaults::none(n),
            ramping_out: false,
        })
    }

    pub fn len(&self) -> usize {
        self.axes.len()
    }

    pub fn is_empty(&self) -> bool {
        self.axes.is_empty()
    }

    /// Axis `i`'s identity (None for a name that is not x, y or z: never driven).
    pub fn axis(&self, i: usize) -> Option<Axis> {
        self.axes[i].axis
    }

    /// The configured axes' names, config order.
    pub fn axis_names(&self) -> impl Iterator<Item = &str> {
        self.axes.iter().map(|a| a.name.as_str())
    }

    /// Counts axis `i` holds (persisted ahead), as the correction they realise, µm.
    pub fn held_um(&self, i: usize) -> f64 {
        let q = &self.axes[i].quant;
        q.correction_um_of(q.emitted_counts())
    }

    /// Counts handed out on axis `i` so far (what the controller holds once the edges are out).
    pub fn held_counts(&self, i: usize) -> i64 {
        self.axes[i].quant.emitted_counts()
    }

    /// The engine's start values: what the held counts realise, for axes within the clamp.
    pub fn start_values(&self) -> StartValues {
        (0..self.axes.len())
            .filter(|&i| !matches!(self.guard.check(i, f64::NAN), Verdict::BeyondClamp { .. }))
            .map(|i| (self.axes[i].name.clone(), self.held_um(i)))
            .collect()
    }

    pub fn faults(&self) -> &SinkFaults {
        &self.faults
    }

    /// The counts to inject on axis `i` for `want_um` (0 when the guard refuses: a fault flag).
    /// The new count is persisted before it is handed out; a failed save hands out nothing.
    pub fn step(
        &mut self,
        i: usize,
        want_um: f64,
        store: &mut dyn HeldCounts,
    ) -> Result<i64, HeldError> {
        let want = if self.ramping_out { 0.0 } else { want_um };
        let verdict = self.guard.check(i, want);
        self.faults.beyond_clamp[i] = matches!(verdict, Verdict::BeyondClamp { .. });
        self.faults.uncertain[i] = matches!(verdict, Verdict::Uncertain { .. });
        match verdict {
            Verdict::Write(v) => {
                let a = &mut self.axes[i];
                let d = write_ahead(store, &a.name, &mut a.quant, v)?;
                let held = self.held_um(i);
                // Until the edges are out the controller may hold the old count or the new one.
                self.guard.wrote(i, held, false);
                Ok(d)
            }
            Verdict::Uncertain { .. } => {
                self.guard.forget_unconfirmed(i);
                Ok(0)
            }
            Verdict::Unknown | Verdict::BeyondClamp { .. } => Ok(0),
        }
    }

    /// Every edge of axis `i` is on the lines: the controller holds exactly the emitted count.
    pub fn settled(&mut self, i: usize) {
        let held = self.held_um(i);
        self.guard.wrote(i, held, true);
    }

    /// From now on every axis wants 0 (the stop ramp-out), within the cap per step.
    pub fn begin_ramp_out(&mut self) {
        self.ramping_out = true;
    }

    /// Stopping: every axis wants 0 ([`Self::begin_ramp_out`] was called).
    pub fn is_ramping_out(&self) -> bool {
        self.ramping_out
    }

    /// Ramping out and every axis holds 0 counts, its edges out.
    pub fn is_ramped_out(&self) -> bool {
        self.ramping_out && (0..self.axes.len()).all(|i| self.guard.holds_zero(i))
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::sinks::quadrature::config::QuadratureAxis;

    /// Held counts in memory (the sink's tests use it too).
    pub(crate) struct Mem(pub(crate) BTreeMap<String, i64>);
    impl HeldCounts for Mem {
        fn load(&mut self) -> Result<Option<BTreeMap<String, i64>>, HeldError> {
            Ok(Some(self.0.clone()))
        }
        fn save(&mut self, axis: &str, count: i64) -> Result<(), HeldError> {
            self.0.insert(axis.into(), count);
            Ok(())
        }
    }

    /// One axis x: 0.5 µm counts, 400 ns gap, 100 kHz, simulated, no trace.
    pub(crate) fn cfg() -> QuadratureSink {
        QuadratureSink {
            axes: vec![QuadratureAxis {
                axis: "x".into(),
                resolution_um: 0.5,
                count_sign: 1,
                min_edge_gap_ns: 400,
                max_inject_rate_hz: 100_000.0,
                gpio: None,
                simulated_native: None,
            }],
            state_file: None,
            trace: None,
        }
    }

    /// x: clamp 50 µm, cap 1 µm per write.
    pub(crate) fn limits() -> Vec<AxisLimits> {
        vec![AxisLimits {
            axis: "x".into(),
            max_correction_um: 50.0,
            max_change_um_per_write: 1.0,
        }]
    }

    #[test]
    fn counts_move_at_most_one_cap_and_never_beyond_the_clamp() {
        let mut store = Mem(BTreeMap::new());
        let mut c = QuadratureCore::new(&cfg(), &limits(), &BTreeMap::new()).unwrap();
        let mut total = 0;
        for _ in 0..200 {
            let d = c.step(0, 1e9, &mut store).unwrap();
            assert!(d.abs() <= 2, "{d} counts of 0.5 µm > 1 µm");
            total += d;
            c.settled(0);
        }
        assert_eq!(
            total, -100,
            "50 µm = 100 counts, sign: correction + → counts −"
        );
        assert_eq!(store.0["x"], -100);
        c.begin_ramp_out();
        for _ in 0..60 {
            total += c.step(0, 30.0, &mut store).unwrap();
            c.settled(0);
        }
        assert_eq!(total, 0);
        assert!(c.is_ramped_out());
    }

    #[test]
    fn held_counts_beyond_the_clamp_inject_nothing_and_are_no_start_value() {
        let held = BTreeMap::from([("x".to_string(), -30_000)]);
        let mut store = Mem(held.clone());
        let mut c = QuadratureCore::new(&cfg(), &limits(), &held).unwrap();
        assert!(c.start_values().is_empty());
        assert_eq!(c.step(0, 0.0, &mut store).unwrap(), 0);
        assert_eq!(c.faults().beyond_clamp, vec![true]);
        assert_eq!(c.held_um(0), 15_000.0);
    }
}
