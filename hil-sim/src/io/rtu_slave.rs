//! The simulator's Modbus RTU slave on its pty: retrocomp's register service
//! ([`retrocomp_bus::modbus::RegisterService`]) behind a mute switch, for the
//! `modbus_rtu_down` transport fault. Muted, the slave still reads every request off the line (so
//! the pty never fills and no half frame is left behind) but answers none and applies no write — what
//! a powered-off or unplugged slave looks like to the master: a timeout on every request. Unmuted,
//! it answers again from the live register image (current values, nothing replayed).
//!
//! Whether it is muted is decided by the pure schedule ([`super::transport_faults::Active::rtu_answers`]);
//! this shell only holds the flag the serve loop flips.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use retrocomp_bus::modbus::{RegisterBank, RegisterService};
use tokio::task::JoinHandle;
use tokio_modbus::prelude::{ExceptionCode, Response, SlaveRequest};
use tokio_modbus::server::Service;

/// Shared mute switch of one RTU slave (clone it into the serve loop).
#[derive(Clone, Debug, Default)]
pub(crate) struct RtuMute(Arc<AtomicBool>);

impl RtuMute {
    pub(crate) fn set(&self, muted: bool) {
        self.0.store(muted, Ordering::Relaxed);
    }

    pub(crate) fn is_muted(&self) -> bool {
        self.0.load(Ordering::Relaxed)
    }
}

/// The register service, silent while muted.
#[derive(Clone, Debug)]
pub(crate) struct MutableService {
    pub inner: RegisterService,
    pub mute: RtuMute,
}

impl Service for MutableService {
    type Request = SlaveRequest<'static>;
    type Response = Option<Response>;
    type Exception = ExceptionCode;
    type Future = std::future::Ready<Result<Self::Response, Self::Exception>>;

    fn call(&self, req: Self::Request) -> Self::Future {
        if self.mute.is_muted() {
            // `None`: tokio-modbus's RTU server sends nothing and reads the next request.
            return std::future::ready(Ok(None));
        }
        self.inner.call(req)
    }
}

/// Serve `bank` as RTU slave `slave` on `serial` (the pty master), mutable through the returned switch.
pub(crate) fn spawn(
    serial: tokio_serial::SerialStream,
    bank: RegisterBank,
    slave: u8,
) -> (JoinHandle<std::io::Result<()>>, RtuMute) {
    let mute = RtuMute::default();
    let svc = MutableService {
        inner: RegisterService {
            bank,
            slave: Some(slave),
        },
        mute: mute.clone(),
    };
    let server = tokio_modbus::server::rtu::Server::new(serial);
    (tokio::spawn(server.serve_forever(svc)), mute)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::borrow::Cow;
    use tokio_modbus::prelude::{Request, SlaveId};

    fn req(slave: SlaveId, request: Request<'static>) -> SlaveRequest<'static> {
        SlaveRequest { slave, request }
    }

    #[tokio::test]
    async fn muted_slave_answers_nothing_and_applies_no_write_then_answers_current_values() {
        let bank = RegisterBank::new();
        bank.set_input(0, &[215]);
        bank.allow_writes(0, 1);
        let svc = MutableService {
            inner: RegisterService {
                bank: bank.clone(),
                slave: Some(1),
            },
            mute: RtuMute::default(),
        };
        let read = || req(1, Request::ReadInputRegisters(0, 1));
        assert_eq!(
            svc.call(read()).await,
            Ok(Some(Response::ReadInputRegisters(vec![215])))
        );
        svc.mute.set(true);
        assert_eq!(svc.call(read()).await, Ok(None), "muted: no answer");
        let write = req(1, Request::WriteMultipleRegisters(0, Cow::Owned(vec![7])));
        assert_eq!(svc.call(write).await, Ok(None));
        assert_eq!(
            bank.holding(0, 1),
            Some(vec![0]),
            "muted: write not applied"
        );
        // Not even an exception for a bad address: a dead slave says nothing at all.
        let bad = req(1, Request::ReadInputRegisters(9, 1));
        assert_eq!(svc.call(bad).await, Ok(None));
        bank.set_input(0, &[230]);
        svc.mute.set(false);
        assert_eq!(
            svc.call(read()).await,
            Ok(Some(Response::ReadInputRegisters(vec![230]))),
            "back with the current value"
        );
    }
}
