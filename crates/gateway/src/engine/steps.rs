//! The steps of a cycle that [`Engine::cycle_in_place`] and [`Engine::correction_at`] share:
//! channel health and substitution, the values the model sees (slow channels latched at the
//! thermal period), the model's inputs and its evaluation, and an axis' target from its terms.
//!
//! Signs and units as in the engine: the model returns errors (µm), targets are corrections
//! (= −error, µm); channel values are in their own units.

use super::{AxisErrors, AxisRuntime, Engine, ErrorModel};
use crate::engine::health::{ChannelStatus, FaultKind};
use retrocomp_bus::Health;
use retrocomp_bus::fault::FaultSource;

impl AxisRuntime {
    /// The axis' target from the model's errors: correction = −error per term (kept for the
    /// status), their sum the target, µm.
    pub(super) fn take_target(&mut self, errors: &AxisErrors) -> f64 {
        self.terms.clear();
        let mut total = 0.0;
        for t in errors.axis(self.axis) {
            let corr = -t.error_um;
            total += corr;
            self.terms.push((t.term.clone(), corr));
        }
        self.target_um = Some(total);
        total
    }
}

impl Engine {
    /// Steps 1–3 of a cycle for the channels, shared by [`Engine::cycle_in_place`] and
    /// [`Engine::correction_at`]: health of every channel with fault transitions logged once (in
    /// name order), failed channels substituted from their neighbours, and the value the model
    /// sees of each (slow channels latched at the thermal period).
    pub(super) fn judge_channels(&mut self, now_s: f64) {
        // 1. Health of every channel, with fault transitions logged once (in name order).
        for &slot in &self.slots.by_name {
            let c = &mut self.channels[slot];
            let Some(m) = c.monitor.as_mut() else {
                c.status = None;
                continue;
            };
            // Judged into last cycle's status: its fault list is reused (no allocation while a
            // fault stays active).
            let st = c.status.get_or_insert_with(ChannelStatus::unknown);
            m.status_judged_into(now_s, self.newest_input_s, st);
            if self.undelivered.contains(&c.id) {
                st.faults.push(FaultKind::NoSource);
            }
            let mut gone = m
                .take_rejected()
                .filter(|k| !st.faults.contains(k))
                .peekable();
            if gone.peek().is_some() {
                // Rejected readings that a good one replaced before this cycle: never used, but
                // logged — started now, cleared next cycle. (At most one of each kind: on the
                // stack.)
                let mut seen = [FaultKind::Stale; FaultKind::ALL.len()];
                let mut n = 0;
                for k in st.faults.iter().copied().chain(gone) {
                    if n < seen.len() && !seen[..n].contains(&k) {
                        seen[n] = k;
                        n += 1;
                    }
                }
                seen[..n].sort();
                self.fault_events
                    .extend(self.faults.update(&c.source, &seen[..n], now_s));
            } else {
                self.fault_events
                    .extend(self.faults.update(&c.source, &st.faults, now_s));
            }
        }
        // 2. Substitute failed channels from their neighbours (Ni's recovery).
        for r in &mut self.recoveries {
            let failed = self.channels[r.target]
                .status
                .as_ref()
                .is_none_or(|s| s.health != Health::Ok);
            if !failed {
                continue;
            }
            r.values.clear();
            for &n in &r.neighbours {
                match self.channels[n]
                    .status
                    .as_ref()
                    .filter(|s| s.health == Health::Ok)
                    .and_then(|s| s.value)
                {
                    Some(v) => r.values.push(v),
                    None => break,
                }
            }
            if r.values.len() == r.neighbours.len()
                && let Ok(est) = r.estimate.estimate(&r.values)
            {
                let st = self.channels[r.target]
                    .status
                    .get_or_insert_with(|| ChannelStatus {
                        value: None,
                        health: Health::Stale,
                        faults: vec![FaultKind::Stale],
                        substituted: false,
                        reading_t_s: None,
                    });
                st.value = Some(est);
                st.substituted = true;
                st.reading_t_s = None;
            }
        }
        // 3. Usable channel values; slow channels latched at the thermal period.
        let latch_slow = self
            .last_slow_latch_s
            .is_none_or(|t| now_s - t >= self.thermal_period_s);
        if latch_slow {
            self.last_slow_latch_s = Some(now_s);
        }
        for c in &mut self.channels {
            let usable = c
                .status
                .as_ref()
                .filter(|st| st.health == Health::Ok || st.substituted)
                .and_then(|st| st.value);
            c.value = if c.status.is_none() {
                None
            } else if c.slow {
                if latch_slow || usable.is_none() {
                    // A slow channel that fails between latches is dropped at once, not at the
                    // next latch.
                    c.latched = usable;
                }
                c.latched
            } else {
                usable
            };
        }
    }

    /// Step 4's inputs: the model's channels resolved to slots once (first cycle, model
    /// replaced), their values handed over in its order. True when every required channel that
    /// is not optional has a value.
    pub(super) fn model_inputs(&mut self, model: &dyn ErrorModel) -> bool {
        if self.required.is_none() {
            let required = model.required_channels();
            let optional = model.optional_channels();
            let slots = required.iter().map(|name| self.slot_of(name)).collect();
            self.required = Some(slots);
            self.optional = optional.iter().map(|name| self.slot_of(name)).collect();
        }
        self.state.inputs.clear();
        let values = self
            .required
            .iter()
            .flatten()
            .map(|&s| self.channels[s].value);
        self.state.inputs.extend(values);
        let optional = &self.optional;
        self.required
            .iter()
            .flatten()
            .filter(|id| !optional.contains(id))
            .all(|&id| self.channels[id].value.is_some())
    }

    /// Some optional model input is unusable now (its terms are left out).
    pub(super) fn optional_missing(&self) -> bool {
        self.optional
            .iter()
            .any(|&id| self.channels[id].value.is_none())
    }

    /// Step 4's evaluation (when `inputs_ok`) into `self.errors`, its failure a `decode` fault of
    /// the model (logged once). True when the model was evaluated.
    pub(super) fn evaluate_model(
        &mut self,
        model: &mut dyn ErrorModel,
        inputs_ok: bool,
        now_s: f64,
    ) -> bool {
        self.errors.clear();
        let model_result = if inputs_ok {
            model
                .axis_errors(&self.state, &mut self.errors)
                .map(|()| true)
        } else {
            Ok(false)
        };
        let model_fault = model_result.as_ref().err();
        self.fault_events.extend(self.faults.update(
            &FaultSource::Model,
            if model_fault.is_some() {
                &[FaultKind::Decode]
            } else {
                &[]
            },
            now_s,
        ));
        if model_fault != self.model_error.as_ref() {
            if let Some(e) = model_fault {
                tracing::warn!(error = %e, "model evaluation failed");
            }
            self.model_error = model_fault.cloned();
        }
        matches!(model_result, Ok(true))
    }
}
