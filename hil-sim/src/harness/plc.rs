//! The origin-shift side of the loop: the sink's request in flight answered from the simulated
//! PLC's registers (every write logged with what the PLC applied), or failed while the link is
//! down; a new write period on its tick. Units: µm, s.

use retrocomp_gateway::sinks::origin_shift::{Action, Reply};

use super::{ClosedLoop, PlcWrite};

impl ClosedLoop {
    /// Answer the request in flight from the PLC (or fail it: link down), or begin a period.
    pub(super) fn run_sink(&mut self, tick: u64, t: f64) {
        let Some(gw) = self.gateway.as_mut() else {
            return;
        };
        let link_up = self.link_up;
        let now = std::time::Duration::from_nanos(tick * self.dt_ns);
        if let Some(a) = gw.pending().cloned() {
            if let Action::Read { not_before_s, .. } = a
                && not_before_s > t + 1e-9
            {
                return;
            }
            let reply = if link_up {
                let plc = self.world.plc_mut();
                match &a {
                    Action::Write(b) => {
                        let applied_um = std::array::from_fn(|k| plc.shift_um(k));
                        match plc.write(b.address, &b.words) {
                            Ok(()) => {
                                let regs = crate::io::plc_server::shifts_um(
                                    plc.config(),
                                    plc.read(0, plc.len()).expect("whole window"),
                                );
                                self.writes.push(PlcWrite {
                                    t_s: t,
                                    address: b.address,
                                    words: b.words.to_vec(),
                                    applied_um,
                                    registers_um: regs,
                                    generation: self.generation,
                                });
                                Reply::Written
                            }
                            Err(e) => Reply::Failed(format!("Modbus exception: {e}")),
                        }
                    }
                    Action::Read { address, count, .. } => {
                        match plc.read(*address, *count as usize) {
                            Ok(w) => Reply::Read(w.to_vec().into()),
                            Err(e) => Reply::Failed(format!("Modbus exception: {e}")),
                        }
                    }
                    Action::Done(_) => unreachable!("never pending"),
                }
            } else {
                self.client.failed(now);
                Reply::Failed("transport: connection lost (harness link down)".into())
            };
            gw.handle_reply(reply, t, self.client.is_connected());
            return;
        }
        if tick.is_multiple_of(self.write_ticks) {
            let connected = self.client.ensure_connected(now, t, link_up);
            gw.poll_period(t, connected);
        }
    }
}
