//! Who may write what (issue 33 point 2): the Modbus TCP server the origin-shift server mode runs
//! accepts position, held and marker writes only from `allow_writes_from`. A real pymodbus client
//! bound to 127.0.0.2 (a host not on the list; only 127.0.0.1 is) gets exception 01 for FC06 and
//! FC16, nothing changes, and the listener reports a fault naming it; the same client from
//! 127.0.0.1 writes. The HTTP endpoint refuses an action from a peer not on its list with 403
//! before looking at the token, with the same fault.

use crate::peers;

use std::net::SocketAddr;

use retrocomp_bus::fault::FaultKind;
use retrocomp_bus::listen::ListenPolicy;
use retrocomp_bus::modbus::{RegisterBank, TcpServer};
use retrocomp_gateway::northbound::http::{Api, Limits, request, serve};

fn only(ip: &str) -> ListenPolicy {
    ListenPolicy {
        allow_writes_from: vec![ip.parse().unwrap()],
        ..ListenPolicy::default()
    }
}

/// Run tests/peers/pymodbus_rogue.py from `source` against `addr`; its three result lines.
fn rogue(addr: SocketAddr, source: &str) -> Vec<String> {
    let peer = peers::spawn_python(
        "pymodbus_rogue.py",
        &["127.0.0.1", &addr.port().to_string(), source],
    );
    (0..3).map(|_| peer.line(20)).collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn modbus_writes_only_from_the_controller() {
    let _turn = crate::turn::take(file!());
    let bank = RegisterBank::new();
    bank.set_holding(0, &[0]);
    bank.allow_writes(10, 3);
    let any: SocketAddr = "127.0.0.1:0".parse().unwrap();
    let server = TcpServer::start_with(any, bank.clone(), only("127.0.0.1"))
        .await
        .unwrap();
    let addr = server.local_addr();

    let lines = tokio::task::spawn_blocking(move || rogue(addr, "127.0.0.2"))
        .await
        .unwrap();
    assert_eq!(
        lines,
        ["FC06 exception 1", "FC16 exception 1", "FC03 ok 0 0 0"],
        "the rogue peer's requests"
    );
    assert_eq!(
        bank.holding(10, 3),
        Some(vec![0, 0, 0]),
        "a rogue write landed"
    );
    let faults = server.health().faults();
    assert!(
        faults.iter().any(
            |(src, kind, _)| src == "listener.modbus_server.peer.127.0.0.2"
                && *kind == FaultKind::Unauthorized
        ),
        "no fault naming the rogue peer: {faults:?}"
    );

    let lines = tokio::task::spawn_blocking(move || rogue(addr, "127.0.0.1"))
        .await
        .unwrap();
    assert_eq!(lines, ["FC06 ok", "FC16 ok", "FC03 ok 20000 0 21930"]);
    assert_eq!(bank.holding(10, 3), Some(vec![20000, 0, 21930]));
}

#[tokio::test]
async fn http_actions_only_from_the_list() {
    let _turn = crate::turn::take(file!());
    let (_tx, rx) = tokio::sync::watch::channel(None);
    let api = Api {
        token: Some("a-token-of-sixteen-chars".into()),
        ..Api::default()
    };
    let limits = Limits {
        policy: only("10.0.0.5"),
        ..Limits::default()
    };
    let (addr, _task) = serve("127.0.0.1:0".parse().unwrap(), rx, api, limits)
        .await
        .unwrap();
    let (code, body) = request(
        &addr.to_string(),
        axum::http::Method::POST,
        "/api/compensation",
        &[
            ("authorization", "Bearer a-token-of-sixteen-chars"),
            ("content-type", "application/json"),
        ],
        axum::body::Bytes::from_static(br#"{"enabled": false}"#),
        std::time::Duration::from_secs(10),
    )
    .await
    .unwrap();
    assert_eq!(code, 403, "{body}");
    assert!(body.contains("allow_writes_from"), "{body}");
    // The read routes stay open to every peer.
    let (code, _) = retrocomp_gateway::northbound::http::get(
        &addr.to_string(),
        "/status",
        std::time::Duration::from_secs(10),
    )
    .await
    .unwrap();
    assert_eq!(code, 503, "no cycle yet: the read route answers, not a 403");
}
