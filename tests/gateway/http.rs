//! The status endpoint's own behaviour, in-process on loopback: read routes without a snapshot,
//! method/size limits, the slowloris cut-off, and the token-guarded `POST /api/compensation`.
//! (Route content with a live snapshot is checked by gateway_closed_loop.rs.)

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::body::Bytes;
use axum::http::Method;
use retrocomp_gateway::northbound::http::{Api, Control, Limits, StatusRx, request, serve};
use retrocomp_gateway::status::StatusSnapshot;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::sync::{mpsc, watch};

const T: Duration = Duration::from_secs(10);
const TOKEN: &str = "s3cret-token-for-tests-0123456789";

async fn start(api: Api, limits: Limits) -> (String, watch::Sender<Option<Arc<StatusSnapshot>>>) {
    let (tx, rx): (_, StatusRx) = watch::channel(None);
    let listen: SocketAddr = "127.0.0.1:0".parse().unwrap();
    let (addr, task) = serve(listen, rx, api, limits).await.unwrap();
    // Dropping a JoinHandle detaches the task: the server lives as long as the test's runtime.
    drop(task);
    (addr.to_string(), tx)
}

fn with_token() -> (Api, mpsc::Receiver<Control>) {
    let (tx, rx) = mpsc::channel(4);
    let api = Api {
        token: Some(TOKEN.into()),
        control_tx: Some(tx),
        models: None,
    };
    (api, rx)
}

async fn post(addr: &str, auth: Option<&str>, body: &str) -> (u16, String) {
    let mut h = vec![("content-type", "application/json")];
    let bearer;
    if let Some(a) = auth {
        bearer = a.to_string();
        h.push(("authorization", &bearer));
    }
    let body = Bytes::from(body.to_string());
    request(addr, Method::POST, "/api/compensation", &h, body, T)
        .await
        .unwrap()
}

#[tokio::test]
async fn read_routes_without_snapshot_and_wrong_methods() {
    let (addr, _tx) = start(Api::default(), Limits::default()).await;
    for path in ["/status", "/metrics", "/text", "/nope"] {
        let (code, body) = request(&addr, Method::GET, path, &[], Bytes::new(), T)
            .await
            .unwrap();
        assert_eq!((code, body.as_str()), (503, "no cycle run yet\n"), "{path}");
    }
    for (m, path) in [
        (Method::POST, "/status"),
        (Method::PUT, "/metrics"),
        (Method::DELETE, "/x"),
    ] {
        let (code, _) = request(&addr, m.clone(), path, &[], Bytes::new(), T)
            .await
            .unwrap();
        assert_eq!(code, 405, "{m} {path}");
    }
    let (code, _) = request(
        &addr,
        Method::GET,
        "/api/compensation",
        &[],
        Bytes::new(),
        T,
    )
    .await
    .unwrap();
    assert_eq!(code, 405, "GET on the action route");
}

#[tokio::test]
async fn action_refused_without_configured_token() {
    let (tx, mut rx) = mpsc::channel(4);
    let api = Api {
        token: None,
        control_tx: Some(tx),
        models: None,
    };
    let (addr, _s) = start(api, Limits::default()).await;
    let (code, _) = post(&addr, Some("Bearer anything"), r#"{"enabled": false}"#).await;
    assert_eq!(code, 403);
    let (code, _) = post(&addr, None, r#"{"enabled": false}"#).await;
    assert_eq!(code, 403);
    assert!(rx.try_recv().is_err(), "nothing may reach the run loop");
}

#[tokio::test]
async fn action_needs_the_token_and_a_well_formed_body() {
    let (api, mut rx) = with_token();
    let (addr, _s) = start(api, Limits::default()).await;
    let good = format!("Bearer {TOKEN}");
    let wrong = format!("Bearer {TOKEN}x");
    for auth in [
        None,
        Some("Bearer"),
        Some("Basic Zm9vOmJhcg=="),
        Some(wrong.as_str()),
    ] {
        let (code, _) = post(&addr, auth, r#"{"enabled": false}"#).await;
        assert_eq!(code, 401, "auth {auth:?}");
    }
    assert!(rx.try_recv().is_err(), "refused requests change nothing");

    for bad in [
        "",
        "not json",
        r#"{"enabled": "no"}"#,
        r#"{"enabled": false, "x": 1}"#,
        "[]",
    ] {
        let (code, _) = post(&addr, Some(&good), bad).await;
        assert!((400..500).contains(&code), "body {bad:?} → {code}");
    }
    assert!(rx.try_recv().is_err(), "bad bodies change nothing");

    let (code, body) = post(&addr, Some(&good), r#"{"enabled": false}"#).await;
    assert_eq!(code, 200, "{body}");
    assert_eq!(
        rx.try_recv().unwrap(),
        Control::SetCompensation { enabled: false }
    );
    let (code, _) = post(&addr, Some(&good), r#"{"enabled": true}"#).await;
    assert_eq!(code, 200);
    assert_eq!(
        rx.try_recv().unwrap(),
        Control::SetCompensation { enabled: true }
    );
}

#[tokio::test]
async fn oversized_head_and_body_get_4xx() {
    let (api, mut rx) = with_token();
    let limits = Limits::default();
    let (addr, _s) = start(api, limits.clone()).await;

    // A head over the limit (but within what the server buffers, so it reads it all and answers).
    let mut s = TcpStream::connect(&addr).await.unwrap();
    let filler = "a".repeat(limits.max_head_bytes + 1000);
    let head = format!("GET /status HTTP/1.1\r\nHost: x\r\nX-Filler: {filler}\r\n\r\n");
    s.write_all(head.as_bytes()).await.unwrap();
    let mut resp = Vec::new();
    let _ = tokio::time::timeout(T, s.read_to_end(&mut resp))
        .await
        .unwrap();
    let resp = String::from_utf8_lossy(&resp);
    assert!(resp.starts_with("HTTP/1.1 431"), "got {resp:?}");

    // A body over the limit, with the right token: 413, nothing forwarded.
    let body = format!(
        r#"{{"enabled": false, "pad": "{}"}}"#,
        "p".repeat(limits.max_body_bytes)
    );
    let good = format!("Bearer {TOKEN}");
    let (code, _) = post(&addr, Some(&good), &body).await;
    assert_eq!(code, 413);
    assert!(rx.try_recv().is_err());
}

/// A client trickling its head one byte at a time is cut off once the header timeout passes,
/// long before it could finish (it would need far longer than the bound of this loop).
#[tokio::test]
async fn slowloris_is_disconnected_within_the_header_timeout() {
    let limits = Limits {
        header_read_timeout: Duration::from_secs(1),
        ..Limits::default()
    };
    let (addr, _s) = start(Api::default(), limits.clone()).await;
    let mut s = TcpStream::connect(&addr).await.unwrap();
    let t0 = Instant::now();
    let trickle = b"GET /status HTTP/1.1\r\nX-Slow: "
        .iter()
        .chain(std::iter::repeat(&b'a'));
    let mut sent = 0usize;
    let mut buf = [0u8; 256];
    let mut closed = false;
    // Bounded: at most 600 bytes at one per 50 ms (30 s), far under the head size limit.
    for &byte in trickle.take(600) {
        if s.write_all(&[byte]).await.is_err() {
            closed = true;
            break;
        }
        sent += 1;
        match tokio::time::timeout(Duration::from_millis(50), s.read(&mut buf)).await {
            Ok(Ok(0) | Err(_)) => {
                closed = true;
                break;
            }
            Ok(Ok(_)) => {} // a 408 before the close is fine; keep going until EOF
            Err(_) => {}
        }
    }
    assert!(
        closed,
        "server still holding a slowloris after {sent} bytes"
    );
    assert!(
        t0.elapsed() >= limits.header_read_timeout,
        "cut before the header timeout: it must be the timeout doing it"
    );
    assert!(sent < 600 && sent < limits.max_head_bytes);
}

/// `[gateway] api_token` is read from the field config; a short one is refused at start, naming
/// the key.
#[test]
fn api_token_comes_from_the_field_config() {
    use retrocomp_gateway::config::FieldConfig;
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("deploy/field/mill-quadrature.toml");
    let text = std::fs::read_to_string(&path).unwrap();
    assert!(
        FieldConfig::parse(&text, &path)
            .unwrap()
            .gateway
            .api_token
            .is_none()
    );
    let with = |t: &str| {
        text.replacen(
            "[gateway]\n",
            &format!("[gateway]\napi_token = \"{t}\"\n"),
            1,
        )
    };
    let cfg = FieldConfig::parse(&with(TOKEN), &path).unwrap();
    assert_eq!(cfg.gateway.api_token.as_deref(), Some(TOKEN));
    let msg = FieldConfig::parse(&with("short"), &path)
        .unwrap_err()
        .to_string();
    assert!(msg.contains("gateway.api_token"), "{msg}");
}
