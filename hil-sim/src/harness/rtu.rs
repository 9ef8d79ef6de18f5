//! The simulator's Modbus RTU slave in virtual time, for the gateway's `[[modbus.source]]`s: the
//! register image `hil-sim serve` serves (the [`Publisher`](crate::io::publish::Publisher)'s input
//! registers, answered by the bus crate's own [`RegisterBank::handle`]) behind the mute of the
//! `modbus_rtu_down` fault, driven by what each source's schedule asks
//! ([`GatewayCore::poll_modbus`]).
//!
//! Timing (the simplification of docs/hil-sim.md): opening the port succeeds at once (a serial
//! port opens whether or not the slave is powered); an answered read comes back in the step it was
//! sent; a read the muted slave does not answer times out exactly the source's `timeout_s` after
//! it was sent. Whether the slave answers is decided when the request reaches it.

use retrocomp_bus::modbus::{ReadOutcome, RegisterBank, RegisterTable};
use retrocomp_gateway::config::FieldConfig;
use retrocomp_gateway::gateway_core::{GatewayCore, ModbusRequest};
use tokio_modbus::prelude::{ExceptionCode, Request, Response};

/// A request of one source in flight: what it will get, and when.
#[derive(Debug)]
enum InFlight {
    Connect { due_s: f64 },
    Read { due_s: f64, outcome: ReadOutcome },
}

impl InFlight {
    fn due_s(&self) -> f64 {
        match self {
            InFlight::Connect { due_s } | InFlight::Read { due_s, .. } => *due_s,
        }
    }
}

/// The slave and the requests of every Modbus source of the gateway.
#[derive(Debug)]
pub(crate) struct RtuSlave {
    bank: RegisterBank,
    answers: bool,
    timeouts_s: Vec<f64>,
    in_flight: Vec<Option<InFlight>>,
    /// Requests the slave left unanswered so far.
    pub(crate) unanswered: u64,
}

impl RtuSlave {
    pub(crate) fn new(field: &FieldConfig) -> Self {
        let timeouts_s: Vec<f64> = field
            .modbus
            .iter()
            .flat_map(|m| m.source.iter().map(|s| s.timeout_s))
            .collect();
        RtuSlave {
            bank: RegisterBank::new(),
            answers: true,
            in_flight: timeouts_s.iter().map(|_| None).collect(),
            timeouts_s,
            unanswered: 0,
        }
    }

    /// A new gateway process: nothing of the old one's is in flight.
    pub(crate) fn restart(&mut self) {
        self.in_flight.iter_mut().for_each(|f| *f = None);
    }

    /// The sim's encoders wrote these input registers this step.
    pub(crate) fn publish(&self, input_regs: &[(u16, Vec<u16>)]) {
        for (addr, words) in input_regs {
            self.bank.set_input(*addr, words);
        }
    }

    /// Whether the slave answers from now on (`modbus_rtu_down` mutes it).
    pub(crate) fn set_answers(&mut self, answers: bool) {
        self.answers = answers;
    }

    /// Deliver what is due at `t_s`, and start the polls due, for every source.
    pub(crate) fn drive(&mut self, gw: &mut GatewayCore, t_s: f64) {
        for i in 0..self.in_flight.len() {
            loop {
                let next = match self.in_flight[i].take() {
                    Some(f) if f.due_s() <= t_s + 1e-9 => match f {
                        InFlight::Connect { .. } => gw.handle_modbus_connect(i, true, t_s),
                        InFlight::Read { outcome, .. } => {
                            gw.handle_modbus_outcome(i, &outcome, t_s)
                        }
                    },
                    Some(f) => {
                        self.in_flight[i] = Some(f);
                        break;
                    }
                    None if gw.modbus_timeout(i).is_some_and(|d| d <= t_s + 1e-9) => {
                        gw.poll_modbus(i, t_s)
                    }
                    None => break,
                };
                match next {
                    Some(r) => self.in_flight[i] = Some(self.send(i, r, t_s)),
                    None => break,
                }
            }
        }
    }

    /// The request reaches the slave at `t_s`.
    fn send(&mut self, i: usize, request: ModbusRequest, t_s: f64) -> InFlight {
        let ModbusRequest::Read {
            table,
            start,
            count,
        } = request
        else {
            return InFlight::Connect { due_s: t_s };
        };
        if !self.answers {
            self.unanswered += 1;
            return InFlight::Read {
                due_s: t_s + self.timeouts_s[i],
                outcome: ReadOutcome::Timeout,
            };
        }
        let req = match table {
            RegisterTable::Input => Request::ReadInputRegisters(start, count),
            RegisterTable::Holding => Request::ReadHoldingRegisters(start, count),
        };
        let outcome = match self.bank.handle(&req) {
            Ok(Response::ReadInputRegisters(w) | Response::ReadHoldingRegisters(w)) => {
                ReadOutcome::Registers(w)
            }
            Ok(_) => ReadOutcome::Exception(ExceptionCode::ServerDeviceFailure),
            Err(e) => ReadOutcome::Exception(e),
        };
        InFlight::Read {
            due_s: t_s,
            outcome,
        }
    }
}
