//! The Modbus register server over real TCP on loopback, read and written by the tokio-modbus client,
//! and by mbpoll (a third-party client) when installed.

use retrocomp::bus::modbus::{RegisterBank, TcpServer};
use std::time::Duration;
use tokio::time::timeout;
use tokio_modbus::prelude::*;

const T: Duration = Duration::from_secs(5);

async fn server() -> (RegisterBank, TcpServer) {
    let bank = RegisterBank::new();
    bank.set_input(0, &[235, 241, 0xFF38]);
    bank.allow_writes(200, 2);
    let srv = TcpServer::start("127.0.0.1:0".parse().unwrap(), bank.clone())
        .await
        .unwrap();
    (bank, srv)
}

#[tokio::test]
async fn tokio_modbus_client_reads_writes_and_gets_exceptions_as_values() {
    let (bank, srv) = server().await;
    let mut ctx = tcp::connect_slave(srv.local_addr(), Slave(1))
        .await
        .unwrap();
    let r = timeout(T, ctx.read_input_registers(0, 3)).await.unwrap();
    assert_eq!(r.unwrap(), Ok(vec![235, 241, 0xFF38]));
    let r = timeout(T, ctx.read_input_registers(2, 2)).await.unwrap();
    assert_eq!(r.unwrap(), Err(ExceptionCode::IllegalDataAddress));
    let mut changed = bank.subscribe_writes();
    let r = timeout(T, ctx.write_multiple_registers(200, &[0x0001, 0x86A0]))
        .await
        .unwrap();
    assert_eq!(r.unwrap(), Ok(()));
    timeout(T, changed.changed()).await.unwrap().unwrap();
    assert_eq!(bank.holding(200, 2), Some(vec![0x0001, 0x86A0]));
    let r = timeout(T, ctx.write_single_register(0, 1)).await.unwrap();
    assert_eq!(
        r.unwrap(),
        Err(ExceptionCode::IllegalDataAddress),
        "not in the allow-list"
    );
}

#[tokio::test]
async fn mbpoll_reads_the_server() {
    let (_bank, srv) = server().await;
    let port = srv.local_addr().port().to_string();
    // mbpoll is blocking: run it on a thread so the server keeps running on this runtime.
    let out = tokio::task::spawn_blocking(move || {
        std::process::Command::new("mbpoll")
            // -t 3: input registers (16-bit int, mbpoll prints them unsigned); -r 1 = address 0; -1 once.
            .args([
                "-m",
                "tcp",
                "-p",
                &port,
                "-a",
                "1",
                "-t",
                "3",
                "-r",
                "1",
                "-c",
                "3",
                "-1",
                "127.0.0.1",
            ])
            .output()
    })
    .await
    .unwrap()
    .unwrap_or_else(|e| panic!("mbpoll not runnable ({e}): run scripts/setup-peers.sh"));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "mbpoll failed: {stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // mbpoll prints `[1]: 235` … with 1-based reference numbers; int16 is its default type.
    for (reg, v) in [(1, "235"), (2, "241"), (3, "65336")] {
        let line = format!("[{reg}]: \t{v}");
        let alt = format!("[{reg}]:\t{v}");
        assert!(
            stdout.contains(&line) || stdout.contains(&alt),
            "missing {line:?} in:\n{stdout}"
        );
    }
}
