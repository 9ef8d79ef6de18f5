//! The socketcand hub with Rust clients: fan-out to every other client of the same bus, no echo,
//! bus isolation by name, and the handshake replies a strict client (python-can) expects.

use retrocomp_bus::can::{CanBus, Frame, Hub, SocketcandBus};
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::time::timeout;

const T: Duration = Duration::from_secs(5);

#[tokio::test]
async fn hub_fans_out_to_others_only_and_isolates_buses() {
    let hub = Hub::start_loopback().await.unwrap();
    let addr = hub.local_addr();
    let mut a = SocketcandBus::connect(addr, "can0").await.unwrap();
    let mut b = SocketcandBus::connect(addr, "can0").await.unwrap();
    let mut c = SocketcandBus::connect(addr, "can0").await.unwrap();
    let mut other = SocketcandBus::connect(addr, "can1").await.unwrap();

    let f = Frame::standard(0x181, &[0x10, 0x27, 0, 0]).unwrap();
    let g = Frame::extended(0x18FF_50E5, &[]).unwrap();
    a.send(&f).await.unwrap();
    b.send(&g).await.unwrap();

    let (rb, tb) = timeout(T, b.recv_timestamped()).await.unwrap().unwrap();
    assert_eq!(rb, f);
    assert!(tb > 1.6e9, "timestamp is Unix seconds, got {tb}");
    assert_eq!(timeout(T, c.recv()).await.unwrap().unwrap(), f);
    assert_eq!(timeout(T, c.recv()).await.unwrap().unwrap(), g);
    // a sent f and must not get it back; the next thing it sees is b's frame.
    assert_eq!(timeout(T, a.recv()).await.unwrap().unwrap(), g);
    // can1 saw nothing of can0.
    assert!(
        timeout(Duration::from_millis(200), other.recv())
            .await
            .is_err()
    );
    assert_eq!(
        hub.stats()
            .frames_in
            .load(std::sync::atomic::Ordering::Relaxed),
        2
    );
}

#[tokio::test]
async fn handshake_replies_are_separate_writes_and_errors_are_reported() {
    let hub = Hub::start_loopback().await.unwrap();
    let mut s = tokio::net::TcpStream::connect(hub.local_addr())
        .await
        .unwrap();
    let mut buf = [0u8; 256];
    let n = timeout(T, s.read(&mut buf)).await.unwrap().unwrap();
    assert_eq!(&buf[..n], b"< hi >");
    // rawmode before open is a protocol error, answered, not fatal.
    s.write_all(b"< rawmode >").await.unwrap();
    let n = timeout(T, s.read(&mut buf)).await.unwrap().unwrap();
    assert!(buf[..n].starts_with(b"< error "), "{:?}", &buf[..n]);
    s.write_all(b"< open vcan0 >").await.unwrap();
    let n = timeout(T, s.read(&mut buf)).await.unwrap().unwrap();
    assert_eq!(&buf[..n], b"< ok >");
    s.write_all(b"< rawmode >").await.unwrap();
    let n = timeout(T, s.read(&mut buf)).await.unwrap().unwrap();
    assert_eq!(&buf[..n], b"< ok >");
    s.write_all(b"< echo >").await.unwrap();
    let n = timeout(T, s.read(&mut buf)).await.unwrap().unwrap();
    assert_eq!(&buf[..n], b"< echo >");
}

#[tokio::test]
async fn client_reports_refused_handshake() {
    // A server that greets and then refuses `open`, as socketcand does for an unknown interface.
    let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr().unwrap();
    tokio::spawn(async move {
        let (mut s, _) = l.accept().await.unwrap();
        s.write_all(b"< hi >").await.unwrap();
        let mut buf = [0u8; 64];
        let _ = s.read(&mut buf).await;
        s.write_all(b"< error could not open bus >").await.unwrap();
        let _ = s.read(&mut buf).await;
    });
    let e = SocketcandBus::connect(addr, "can9").await.unwrap_err();
    assert!(e.to_string().contains("could not open bus"), "{e}");
}

#[tokio::test]
async fn backends_from_toml_talk_to_each_other() {
    use retrocomp_bus::can::{CanBackendConfig, MemBus, open};
    #[derive(serde::Deserialize)]
    struct Doc {
        can: CanBackendConfig,
    }
    let hub = Hub::start_loopback().await.unwrap();
    let text = format!(
        "[can]\nbackend = \"socketcand\"\nport = {}\nchannel = \"can0\"\n",
        hub.local_addr().port()
    );
    let cfg: Doc = toml::from_str(&text).unwrap();
    let mut a = open(&cfg.can, None).await.unwrap();
    let mut b = open(&cfg.can, None).await.unwrap();
    let f = Frame::standard(0x285, &[9, 8, 7]).unwrap();
    a.send(&f).await.unwrap();
    assert_eq!(timeout(T, b.recv()).await.unwrap().unwrap(), f);

    let mem = MemBus::default();
    let mut m1 = open(&CanBackendConfig::Mem, Some(&mem)).await.unwrap();
    let mut m2 = open(&CanBackendConfig::Mem, Some(&mem)).await.unwrap();
    m1.send(&f).await.unwrap();
    assert_eq!(timeout(T, m2.recv()).await.unwrap().unwrap(), f);

    // On a host without vcan0 (or without the kernel backend built in), `socketcan` is a clear
    // error, not a panic.
    let e = open(
        &CanBackendConfig::Socketcan {
            interface: "vcan0".into(),
        },
        None,
    )
    .await;
    match e {
        Ok(_) => {} // a host with vcan0 and the socketcan backend merged
        Err(e) => assert!(
            matches!(
                e,
                retrocomp_bus::can::CanError::Unsupported(_) | retrocomp_bus::can::CanError::Io(_)
            ),
            "{e}"
        ),
    }
}
