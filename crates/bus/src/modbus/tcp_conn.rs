//! One Modbus TCP connection of the [`super::server::TcpServer`]: MBAP framing in, the
//! [`RegisterBank`] answer out, on a stream the listener policy (`crate::listen`) admitted. Our own
//! loop rather than tokio-modbus's `Server::serve`, which owns the accept loop (it returns on the
//! first accept error and drops every connection) and never tells a service which peer it serves;
//! the request PDUs are still decoded by tokio-modbus.
//!
//! Writes from a peer not on `allow_writes_from` get exception 01 (illegal function) and a fault
//! naming the peer; reads are open to every admitted peer.

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_modbus::bytes::Bytes;
use tokio_modbus::prelude::{ExceptionCode, Request, Response};

use super::server::RegisterBank;
use crate::listen::Conn;

/// MBAP header length (transaction id, protocol id, length, unit id).
const HEAD: usize = 7;
/// Longest PDU of Modbus TCP (260-byte ADU).
const MAX_PDU: usize = 253;

/// What one request did, for the shell to report.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Outcome {
    Answered,
    /// A write from a peer that may not write: refused with exception 01.
    RefusedWrite,
}

/// Length of the PDU that follows `head`, or None when it is not a Modbus TCP header.
pub(crate) fn pdu_len(head: [u8; HEAD]) -> Option<usize> {
    let proto = u16::from_be_bytes([head[2], head[3]]);
    let len = usize::from(u16::from_be_bytes([head[4], head[5]]));
    (proto == 0 && (2..=MAX_PDU + 1).contains(&len)).then(|| len - 1)
}

/// Answer one request ADU (`head` + `pdu`) into `out` (cleared first): the sans-IO core.
pub(crate) fn answer(
    bank: &RegisterBank,
    may_write: bool,
    head: [u8; HEAD],
    pdu: &[u8],
    out: &mut Vec<u8>,
) -> Outcome {
    let fc = pdu.first().copied().unwrap_or(0);
    let mut outcome = Outcome::Answered;
    let result = match Request::try_from(Bytes::copy_from_slice(pdu)) {
        Ok(req) => {
            let writes = matches!(
                req,
                Request::WriteSingleRegister(..) | Request::WriteMultipleRegisters(..)
            );
            if writes && !may_write {
                outcome = Outcome::RefusedWrite;
                Err(ExceptionCode::IllegalFunction)
            } else {
                bank.handle(&req)
            }
        }
        // A function we serve, malformed: 03; any other function: 01 (as the bank answers it).
        Err(_) if matches!(fc, 3 | 4 | 6 | 0x10) => Err(ExceptionCode::IllegalDataValue),
        Err(_) => Err(ExceptionCode::IllegalFunction),
    };
    out.clear();
    out.extend_from_slice(&head[..4]);
    out.extend_from_slice(&[0, 0, head[6]]);
    match result {
        Ok(Response::ReadHoldingRegisters(w) | Response::ReadInputRegisters(w)) => {
            out.push(fc);
            // A read answers at most 125 registers (Modbus): 250 bytes fit the count byte.
            out.push(u8::try_from(w.len() * 2).unwrap_or(u8::MAX));
            for x in w {
                out.extend_from_slice(&x.to_be_bytes());
            }
        }
        Ok(Response::WriteSingleRegister(a, x) | Response::WriteMultipleRegisters(a, x)) => {
            out.push(fc);
            out.extend_from_slice(&a.to_be_bytes());
            out.extend_from_slice(&x.to_be_bytes());
        }
        // The bank answers nothing else; say so rather than invent a frame.
        Ok(_) => out.extend_from_slice(&[fc | 0x80, u8::from(ExceptionCode::ServerDeviceFailure)]),
        Err(e) => out.extend_from_slice(&[fc | 0x80, u8::from(e)]),
    }
    // At most 1 + 1 + 1 + 250 bytes follow the length field.
    let len = u16::try_from(out.len() - 6).unwrap_or(u16::MAX);
    out[4..6].copy_from_slice(&len.to_be_bytes());
    outcome
}

/// Serve `conn` until the peer closes, sends something that is not Modbus TCP, or idles out.
pub(crate) async fn serve(mut conn: Conn, bank: RegisterBank) {
    let mut head = [0u8; HEAD];
    let mut pdu = [0u8; MAX_PDU];
    let mut out = Vec::with_capacity(HEAD + MAX_PDU);
    loop {
        if conn.stream.read_exact(&mut head).await.is_err() {
            return;
        }
        let Some(n) = pdu_len(head) else {
            tracing::debug!(peer = %conn.peer, "modbus tcp: not an MBAP header; closing");
            return;
        };
        if conn.stream.read_exact(&mut pdu[..n]).await.is_err() {
            return;
        }
        if answer(&bank, conn.may_write, head, &pdu[..n], &mut out) == Outcome::RefusedWrite {
            conn.health.refused_write(conn.peer.ip());
        }
        if conn.stream.write_all(&out).await.is_err() {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_reads_writes_and_refusals() {
        let bank = RegisterBank::new();
        bank.set_holding(0, &[7, 8]);
        bank.allow_writes(10, 2);
        let head = |len: u16| -> [u8; HEAD] {
            let l = len.to_be_bytes();
            [0x12, 0x34, 0, 0, l[0], l[1], 5]
        };
        let mut out = Vec::new();
        // FC03 at 0, 2 registers.
        let pdu = [3, 0, 0, 0, 2];
        assert_eq!(pdu_len(head(6)), Some(5));
        assert_eq!(
            answer(&bank, false, head(6), &pdu, &mut out),
            Outcome::Answered
        );
        assert_eq!(out, [0x12, 0x34, 0, 0, 0, 7, 5, 3, 4, 0, 7, 0, 8]);
        // FC06 at 11 from a peer that may not write: exception 01, nothing written.
        let pdu = [6, 0, 11, 0x7F, 0xFF];
        assert_eq!(
            answer(&bank, false, head(6), &pdu, &mut out),
            Outcome::RefusedWrite
        );
        assert_eq!(out, [0x12, 0x34, 0, 0, 0, 3, 5, 0x86, 1]);
        assert_eq!(bank.holding(11, 1), Some(vec![0]));
        // The same from the controller is applied and echoed.
        assert_eq!(
            answer(&bank, true, head(6), &pdu, &mut out),
            Outcome::Answered
        );
        assert_eq!(out, [0x12, 0x34, 0, 0, 0, 6, 5, 6, 0, 11, 0x7F, 0xFF]);
        assert_eq!(bank.holding(11, 1), Some(vec![0x7FFF]));
        // FC16 at 10, 2 registers.
        let pdu = [0x10, 0, 10, 0, 2, 4, 0, 1, 0, 2];
        assert_eq!(
            answer(&bank, true, head(11), &pdu, &mut out),
            Outcome::Answered
        );
        assert_eq!(out, [0x12, 0x34, 0, 0, 0, 6, 5, 0x10, 0, 10, 0, 2]);
        // Unknown function, a malformed known one, not-Modbus headers.
        answer(&bank, true, head(2), &[0x2B], &mut out);
        assert_eq!(&out[7..], [0xAB, 1]);
        answer(&bank, true, head(3), &[3, 0], &mut out);
        assert_eq!(&out[7..], [0x83, 3]);
        assert_eq!(pdu_len([0, 0, 0, 1, 0, 6, 1]), None);
        assert_eq!(pdu_len(head(1)), None);
        assert_eq!(pdu_len(head(255)), None);
    }
}
