//! The quadrature side of the loop: the box's lines (polled from the gateway's `QuadratureBox` in
//! virtual time) seen by the controller's ×4 receivers, whose counts go into the servos' feedback.
//! Units: counts, ns.

use retrocomp_model::Axis;

use super::{ClosedLoop, Pulse};

impl ClosedLoop {
    /// The box takes the cycle's outputs (on a cycle tick) and puts the edges due by now on the
    /// lines; the controller's receiver counts them into the servo's feedback.
    pub(super) fn run_quadrature(&mut self, tick: u64) {
        let Some(gw) = self.gateway.as_mut() else {
            return;
        };
        let now_ns = tick * self.dt_ns;
        if tick.is_multiple_of(self.cycle_ticks) {
            gw.poll_quadrature(now_ns, self.world.t_s());
        }
        let Some(q) = gw.quadrature_mut() else {
            return;
        };
        let edges: Vec<_> = q
            .poll_edges(now_ns)
            .into_iter()
            .map(|(axis, tr)| (axis, tr.t_ns, (tr.a, tr.b)))
            .collect();
        self.receive(&edges);
    }

    /// The receivers see these line levels (axis, time, (A, B)); their counts go to the servos.
    pub(super) fn receive(&mut self, levels: &[(Axis, u64, (bool, bool))]) {
        let Some(rx) = self.receivers.as_mut() else {
            return;
        };
        for &(axis, t_ns, (a, b)) in levels {
            let Some(step) = rx[axis.index()].see(a, b) else {
                continue;
            };
            if let Ok(n) = step {
                self.world.inject_counts(axis.index(), n);
            }
            self.pulses.push(Pulse {
                t_ns,
                axis,
                step,
                generation: self.generation,
            });
        }
    }
}
