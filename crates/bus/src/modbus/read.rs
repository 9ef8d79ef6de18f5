//! One register read as every Modbus client of the box makes it (the source poller, the origin-shift
//! client sink): the request through tokio-modbus's `Client::call`, the reply checked here.
//!
//! tokio-modbus's `read_holding_registers`/`read_input_registers` check the reply's header and
//! function code but only `debug_assert` its word count: a peer that answers 1 word to a 2-word read
//! panicked a debug build and gave a release build a short vector. Here a reply of any other length
//! is a transport error (the stream may be out of step; callers drop the connection on it).

use std::io;

use tokio_modbus::client::{Client, Context};
use tokio_modbus::prelude::{Request, Response};

use super::regmap::RegisterTable;

/// Read `count` registers of `table` from `address`: `Ok(Ok(words))` with exactly `count` words,
/// `Ok(Err(exception))` for a Modbus exception, `Err` for a transport failure or a reply that does
/// not answer this request.
pub async fn read_registers(
    ctx: &mut Context,
    table: RegisterTable,
    address: u16,
    count: u16,
) -> tokio_modbus::Result<Vec<u16>> {
    let req = match table {
        RegisterTable::Holding => Request::ReadHoldingRegisters(address, count),
        RegisterTable::Input => Request::ReadInputRegisters(address, count),
    };
    let rsp = match ctx.call(req).await? {
        Ok(rsp) => rsp,
        Err(exception) => return Ok(Err(exception)),
    };
    check_reply(table, count, rsp).map(Ok)
}

/// The words of `rsp` if it answers a read of `count` registers of `table`.
pub(crate) fn check_reply(
    table: RegisterTable,
    count: u16,
    rsp: Response,
) -> Result<Vec<u16>, tokio_modbus::Error> {
    let words = match (table, rsp) {
        (RegisterTable::Holding, Response::ReadHoldingRegisters(w))
        | (RegisterTable::Input, Response::ReadInputRegisters(w)) => w,
        (_, other) => {
            return Err(invalid(format!(
                "reply {other:?} does not answer a read of {table:?} registers"
            )));
        }
    };
    if words.len() != usize::from(count) {
        return Err(invalid(format!(
            "reply holds {} registers, {count} were asked for",
            words.len()
        )));
    }
    Ok(words)
}

fn invalid(what: String) -> tokio_modbus::Error {
    tokio_modbus::Error::Transport(io::Error::new(io::ErrorKind::InvalidData, what))
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    /// A peer that answers `pdu` (in a TCP header echoing the request's) to one 12-byte request.
    async fn read_against(
        table: RegisterTable,
        count: u16,
        pdu: &[u8],
    ) -> tokio_modbus::Result<Vec<u16>> {
        let (ours, mut peer) = tokio::io::duplex(1024);
        let mut ctx = tokio_modbus::client::tcp::attach(ours);
        let pdu = pdu.to_vec();
        let answer = async move {
            let mut req = [0u8; 12];
            peer.read_exact(&mut req).await.unwrap();
            let mut out = req[..4].to_vec();
            out.extend(u16::try_from(pdu.len() + 1).unwrap().to_be_bytes());
            out.push(req[6]);
            out.extend(&pdu);
            peer.write_all(&out).await.unwrap();
        };
        tokio::join!(read_registers(&mut ctx, table, 7, count), answer).0
    }

    #[tokio::test]
    async fn a_reply_with_another_count_is_an_error_not_a_panic() {
        // FC03 asked for 2 registers, answered with 1 (tokio-modbus's own reader debug-asserts).
        let e = read_against(RegisterTable::Holding, 2, &[3, 2, 0, 1])
            .await
            .unwrap_err();
        assert!(e.to_string().contains("1 registers, 2 were asked"), "{e}");
        let e = read_against(RegisterTable::Input, 1, &[4, 4, 0, 1, 0, 2])
            .await
            .unwrap_err();
        assert!(e.to_string().contains("2 registers, 1 were asked"), "{e}");
        // The right count passes, and an exception stays an exception.
        let w = read_against(RegisterTable::Input, 2, &[4, 4, 0, 1, 0, 2])
            .await
            .unwrap();
        assert_eq!(w.unwrap(), vec![1, 2]);
        let x = read_against(RegisterTable::Holding, 1, &[0x83, 2])
            .await
            .unwrap();
        assert!(x.is_err());
    }
}
