//! `[sink.origin_shift_server]` in virtual time: the register bank the controller reads and
//! writes, and the [`ServedSink`] that decides each write and update period — the objects the
//! server's tokio shell drives, here driven by [`super::GatewayCore`]. The driver plays the
//! controller (a Modbus master such as LinuxCNC's mb2hal or a PLC): its requests are answered by
//! the bank (reads of registers not served yet or withdrawn get exception 02, writes only to the
//! position, held and marker registers), and an accepted write is a controller write, as the
//! shell's write subscription makes it.
//!
//! Units: corrections µm, positions mm; time s on the gateway clock.

use retrocomp_bus::modbus::server::RegisterBank;
use retrocomp_bus::{Health, Sample};
use tokio_modbus::prelude::{ExceptionCode, Request, Response};

use crate::sinks::guard::AxisLimits;
use crate::sinks::origin_shift::Words;
use crate::sinks::origin_shift::served::{Period, ServedSink};
use crate::sinks::origin_shift::server::ServerConfig;

/// The served register image and its sans-IO sink.
#[derive(Debug)]
pub struct ServedBox {
    bank: RegisterBank,
    sink: ServedSink,
}

impl ServedBox {
    /// The server of `cfg` with `limits`, serving from `now_s`: nothing is readable until the
    /// controller has reported what it holds.
    pub(super) fn new(cfg: &ServerConfig, limits: &[AxisLimits], now_s: f64) -> Self {
        let bank = RegisterBank::new();
        for (address, count) in cfg.map.writable() {
            bank.allow_writes(address, count);
        }
        ServedBox {
            bank,
            sink: ServedSink::new(cfg, limits, now_s),
        }
    }

    /// One request of the controller at `now_s`; the positions of an accepted write go to
    /// `samples`, as the shell sends them to the cycle.
    pub(super) fn handle_request(
        &mut self,
        req: &Request<'_>,
        now_s: f64,
        samples: &mut Vec<Sample>,
    ) -> Result<Response, ExceptionCode> {
        let answer = self.bank.handle(req);
        let wrote = matches!(
            req,
            Request::WriteSingleRegister(..) | Request::WriteMultipleRegisters(..)
        );
        if wrote && answer.is_ok() {
            let bank = &self.bank;
            let read = |a: u16, n: u16| {
                let mut w = Words::from_elem(0, usize::from(n));
                bank.holding_into(a, &mut w).then_some(w)
            };
            for &(channel, value) in self.sink.handle_write(read, now_s) {
                samples.push(Sample {
                    channel,
                    t_s: now_s,
                    value,
                    health: Health::Ok,
                });
            }
        }
        answer
    }

    /// One update period at `now_s` toward `targets`, applied to the image as the shell does.
    pub(super) fn poll_period(
        &mut self,
        targets: &[(retrocomp_model::Axis, f64)],
        now_s: f64,
    ) -> Period {
        let period = self.sink.poll_period(targets, now_s);
        if period.updated {
            let update = self.sink.update();
            for &(address, count) in &update.withdrawn {
                self.bank.clear_holding(address, count);
            }
            for b in &update.blocks {
                self.bank.set_holding(b.address, &b.words);
            }
        }
        period
    }

    pub(super) fn sink_mut(&mut self) -> &mut ServedSink {
        &mut self.sink
    }

    pub fn sink(&self) -> &ServedSink {
        &self.sink
    }

    /// The register image (what a read would see, without going through a request).
    pub fn bank(&self) -> &RegisterBank {
        &self.bank
    }
}
