//! The server side of the loop (`[sink.origin_shift_server]`): the box serves, the controller's
//! own Modbus master (LinuxCNC's mb2hal, a PLC's master block) polls it. Every
//! [`MASTER_PERIOD_MS`] the master reads each correction register (FC03; an exception — not served
//! yet, or withdrawn — keeps what the PLC applies), puts what it read into the PLC's shift
//! registers (and toggles the strobe when the window has a handshake, as the PLC program that
//! latches its master's input would), copies the box's heartbeat into the PLC watchdog's register
//! if it has one, writes back what the PLC applies into the box's held registers (FC16 each), then
//! sets the write marker when the map has one (FC06: mb2hal's marker register, set once its
//! outputs are valid; the box takes the held registers as a report only once it reads the marker).
//! While the Modbus link is down (`modbus_down`) the master's requests do not arrive. The box's
//! update period runs on its own tick (`update_period_ms`), after the cycle of the same step.
//!
//! Units: µm for shifts (the PLC and the box use the same LSB, checked at start), s for time.

use retrocomp_gateway::sinks::origin_shift::ServerConfig;
use retrocomp_gateway::sinks::origin_shift::{decode_value, encode_value};
use tokio_modbus::prelude::{Request, Response};

use super::{ClosedLoop, PlcWrite};

/// How often the controller's master polls the box, ms (two 4 ms PLC scans of the demo mill).
pub(super) const MASTER_PERIOD_MS: u64 = 8;
/// The master's phase within its period, in steps: its polls do not coincide with the box's
/// update ticks (which start at step 0).
const MASTER_PHASE: u64 = 3;

impl ClosedLoop {
    /// The box's update period on its tick, then the controller's master on its own.
    pub(super) fn run_server(&mut self, tick: u64, t: f64) {
        let Some(gw) = self.gateway.as_mut() else {
            return;
        };
        if tick.is_multiple_of(self.write_ticks) {
            gw.poll_served(t);
        }
        if tick % self.master_ticks != MASTER_PHASE % self.master_ticks || !self.link_up {
            return;
        }
        let Some(srv) = self.field.sink.origin_shift_server.as_ref() else {
            return;
        };
        let plc = self.world.plc_mut();
        let applied_um: [f64; 3] = std::array::from_fn(|k| plc.shift_um(k));
        let mut latched = false;
        for reg in &srv.map.axes {
            let Some(k) =
                retrocomp_model::Axis::from_name(&reg.axis).map(retrocomp_model::Axis::index)
            else {
                continue;
            };
            let read = Request::ReadHoldingRegisters(reg.address, reg.data_type.words());
            let Ok(Response::ReadHoldingRegisters(words)) = gw.handle_server_request(&read, t)
            else {
                continue;
            };
            let Ok(um) = decode_value(reg, &words) else {
                continue;
            };
            let counts = retrocomp_analysis::numeric::round_i64(um / plc.config().lsb_um);
            let shift = plc
                .encode(counts)
                .expect("a served value fits the PLC's register");
            let address = plc.shift_register(k);
            plc.write(address, &shift)
                .expect("the shift register is in the window");
            latched = true;
            let regs = crate::io::plc_server::shifts_um(
                plc.config(),
                plc.read(0, plc.len()).expect("whole window"),
            );
            self.writes.push(PlcWrite {
                t_s: t,
                address,
                words: shift,
                applied_um,
                registers_um: regs,
                generation: self.generation,
            });
        }
        if let Some(h) = plc.config().handshake.clone()
            && latched
        {
            let strobe = plc
                .read(h.strobe_register, 1)
                .expect("strobe in the window")[0];
            plc.write(h.strobe_register, &[strobe.wrapping_add(1)])
                .expect("strobe in the window");
        }
        if let Some(w) = plc.config().watchdog.clone() {
            let beat = Request::ReadHoldingRegisters(srv.map.heartbeat_address, 1);
            if let Ok(Response::ReadHoldingRegisters(words)) = gw.handle_server_request(&beat, t) {
                plc.write(w.heartbeat_register, &words)
                    .expect("heartbeat in the window");
            }
        }
        report_held(gw, srv, &applied_um, t);
        if let Some(m) = &srv.map.write_marker {
            let mark = Request::WriteSingleRegister(m.address, m.value);
            let r = gw.handle_server_request(&mark, t);
            debug_assert!(r.is_ok(), "the marker register takes writes: {r:?}");
        }
    }
}

/// The master's write of what the PLC applies into each held register of the box.
fn report_held(
    gw: &mut retrocomp_gateway::gateway_core::GatewayCore,
    srv: &ServerConfig,
    applied_um: &[f64; 3],
    t: f64,
) {
    for h in &srv.map.held {
        let Some(reg) = srv.map.held_register(h) else {
            continue;
        };
        let Some(k) = retrocomp_model::Axis::from_name(&h.axis).map(retrocomp_model::Axis::index)
        else {
            continue;
        };
        let words = encode_value(&reg, applied_um[k]).expect("what the PLC applies fits");
        let write = Request::WriteMultipleRegisters(reg.address, words.into());
        let r = gw.handle_server_request(&write, t);
        debug_assert!(r.is_ok(), "the held registers take writes: {r:?}");
    }
}
