//! python-can 4.6.1 (`interface="socketcand"`, a third-party client) joins the Rust socketcand hub:
//! frames it sends are decoded by retrocomp (CiA 406 position, heartbeat), frames retrocomp sends
//! (NMT start, SDO 6200h write, an extended frame) are received by python-can.
//! Peer: tests/peers/pycan_socketcand.py.

use crate::peers;

use retrocomp_bus::Health;
use retrocomp_bus::can::{CanBus, Frame, Hub, SocketcandBus};
use retrocomp_bus::canopen::{
    CYCLIC_TIMER_6200, EncoderChannel, HeartbeatMonitor, NmtCommand, PositionDecoder, SdoRequest,
    encode_nmt,
};
use std::time::Duration;
use tokio::time::timeout;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn python_can_and_retrocomp_exchange_frames_through_the_hub() {
    let _turn = crate::turn::take(file!());
    let hub = Hub::start_loopback().await.unwrap();
    let addr = hub.local_addr();
    let mut gw = SocketcandBus::connect(addr, "can0").await.unwrap();
    let port = addr.port().to_string();
    let peer = tokio::task::spawn_blocking(move || {
        peers::spawn_python("pycan_socketcand.py", &["127.0.0.1", &port, "3"])
    })
    .await
    .unwrap();

    // python-can → retrocomp
    let enc = EncoderChannel {
        cyclic_ms: Some(10),
        ..EncoderChannel::new("x_mm", 1, 1000.0)
    };
    let mut dec = PositionDecoder::new(enc, &mut retrocomp_bus::ChannelTable::default());
    let mut hb = HeartbeatMonitor::new(1, 1.0);
    let mut got = Vec::new();
    let mut t_last = 0.0;
    for _ in 0..3 {
        let (f, t) = timeout(Duration::from_secs(10), gw.recv_timestamped())
            .await
            .expect("python-can frame did not arrive")
            .unwrap();
        got.push(f);
        if let Some(s) = dec.decode(&f, t) {
            assert_eq!((s.value, s.health), (12.345, Health::Ok));
        }
        hb.handle_frame(&f, t);
        t_last = t;
    }
    assert_eq!(dec.frames, 1, "the TPDO was decoded: {got:?}");
    // Heartbeat judged on the hub's timestamps: fresh just after, stale past the 1 s timeout.
    assert_eq!(hb.poll(t_last + 0.1), Health::Ok);
    assert_eq!(hb.poll(t_last + 2.0), Health::Stale);
    let ext = got.iter().find(|f| f.raw_id() == 0x18FF_50E5).unwrap();
    assert!(embedded_can::Frame::is_extended(ext) && embedded_can::Frame::data(ext).is_empty());

    // retrocomp → python-can
    let sent = [
        encode_nmt(NmtCommand::Start, 1),
        SdoRequest::write_u16(CYCLIC_TIMER_6200, 0, 10).encode(1),
        Frame::extended(0x01AB_CDE0, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap(),
    ];
    for f in &sent {
        gw.send(f).await.unwrap();
    }
    let lines = tokio::task::spawn_blocking(move || {
        let l: Vec<String> = (0..4).map(|_| peer.line(10)).collect();
        l
    })
    .await
    .unwrap();
    assert_eq!(
        lines,
        vec![
            "RX 0 0 0101".to_string(),
            "RX 601 0 2b0062000a000000".to_string(),
            "RX 1ABCDE0 1 0102030405060708".to_string(),
            "DONE".to_string(),
        ]
    );
}
