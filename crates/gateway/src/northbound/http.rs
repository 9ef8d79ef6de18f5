//! The box's HTTP endpoint, on axum over hyper, bound to 127.0.0.1 by default:
//! `GET /status` (JSON snapshot), `GET /metrics` (Prometheus text), `GET /text` (text table), all
//! read-only and open; the live page `GET /` and its JSON (`crate::northbound::web`, history in
//! `crate::northbound::history`); `POST /api/compensation` (`{"enabled": bool}`), the first action, needs
//! `Authorization: Bearer <[gateway] api_token>` and is forwarded to the run loop as a [`Control`].
//! Every action, accepted or refused, is logged (tracing) and kept in the page's action log with
//! the peer address. Unknown path: 404; wrong method: 405; no cycle run yet: 503 on the read routes.
//!
//! Actions are taken only from peers on `[gateway.listen_policy] allow_writes_from` (others: 403
//! and a fault naming the peer), then only with the token.
//!
//! Bounded everything: connections are kept by the listener policy every server of the box keeps
//! (`retrocomp_bus::listen`: connection and per-peer caps, refused ones answered 503 and closed at once,
//! never queued; idle timeout; descriptor reserve; accept backoff logged once per episode; restart);
//! one request per connection; the request head must arrive within [`Limits::header_read_timeout`]
//! (a client trickling one byte a second is cut off), the head is capped at
//! [`Limits::max_head_bytes`] (431) and the body at [`Limits::max_body_bytes`] (413); the whole
//! connection lives at most [`Limits::connection_deadline`].

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use axum::Router;
use axum::body::{Body, Bytes};
use axum::extract::rejection::JsonRejection;
use axum::extract::{ConnectInfo, DefaultBodyLimit, Json, State};
use axum::http::{HeaderMap, Method, Request, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get as get_route, post};
use http_body_util::BodyExt;
use hyper_util::rt::{TokioIo, TokioTimer};
use hyper_util::service::TowerToHyperService;
use tokio::net::TcpStream;
use tower::ServiceExt;

pub use crate::northbound::http_state::{Api, Control, StatusRx};
use crate::northbound::http_state::{AppState, authorize, not_allowed, plain, record};
use crate::status::StatusSnapshot;
use retrocomp_bus::listen::{Conn, IdleStream, ListenPolicy, ListenerHealth, Spec, listen_with};

/// Resource bounds of the endpoint; [`Limits::default`] is what `retrocomp run` uses (with the
/// field config's `[gateway.listen_policy]`).
#[derive(Clone, Debug)]
pub struct Limits {
    /// Connection caps, idle timeout, descriptor reserve, who may act (`retrocomp_bus::listen`).
    pub policy: ListenPolicy,
    pub header_read_timeout: Duration,
    /// A handler that has not answered by then gets 503.
    pub request_timeout: Duration,
    pub connection_deadline: Duration,
    pub max_head_bytes: usize,
    pub max_body_bytes: usize,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            policy: ListenPolicy::default(),
            header_read_timeout: Duration::from_secs(5),
            request_timeout: Duration::from_secs(5),
            connection_deadline: Duration::from_secs(15),
            max_head_bytes: 8192,
            max_body_bytes: 4096,
        }
    }
}

/// Bind and serve the read-only routes until the task is dropped (actions refused: no token).
/// Returns the bound address (port 0 → chosen port).
pub async fn serve_status(
    listen: SocketAddr,
    rx: StatusRx,
) -> std::io::Result<(SocketAddr, tokio::task::JoinHandle<()>)> {
    serve(listen, rx, Api::default(), Limits::default()).await
}

/// Bind and serve every route with the given action config and bounds.
pub async fn serve(
    listen: SocketAddr,
    rx: StatusRx,
    api: Api,
    limits: Limits,
) -> std::io::Result<(SocketAddr, tokio::task::JoinHandle<()>)> {
    let health = ListenerHealth::new("http");
    // Fed from the watch channel at ≤ 10 Hz; ends when the run loop drops the sender.
    let (history, _history_task) = crate::northbound::history::spawn(rx.clone());
    let app = router(
        AppState {
            rx,
            api: Arc::new(api),
            history,
            model_request: Default::default(),
            policy: Arc::new(limits.policy.clone()),
            listener: health.clone(),
        },
        &limits,
    );
    let spec = Spec {
        name: "http",
        policy: limits.policy.clone(),
        refusal:
            b"HTTP/1.1 503 Service Unavailable\r\ncontent-length: 0\r\nconnection: close\r\n\r\n",
        handler: Arc::new({
            let app = app.clone();
            move |conn: Conn| {
                Box::pin(serve_connection(
                    conn.stream,
                    conn.peer,
                    app.clone(),
                    limits.clone(),
                ))
            }
        }),
    };
    let l = listen_with(listen, spec, health).await?;
    let addr = l.addr;
    if !addr.ip().is_loopback() {
        tracing::warn!(%addr, "status endpoint bound to a non-loopback address");
    }
    // Aborting this task (the caller's way to stop the endpoint) drops the listener with it.
    Ok((
        addr,
        tokio::spawn(async move {
            let _listening = l;
            std::future::pending::<()>().await;
        }),
    ))
}

fn router(state: AppState, limits: &Limits) -> Router {
    let api = Router::new()
        .route("/status", get_route(status_json).fallback(not_allowed))
        .route("/metrics", get_route(metrics).fallback(not_allowed))
        .route("/text", get_route(text).fallback(not_allowed))
        .route("/api/compensation", post(set_compensation));
    // The live page and its assets (feature `web`); without it `/` is the fallback's 404.
    #[cfg(feature = "web")]
    let api = api.merge(crate::northbound::web::routes());
    api.fallback(fallback)
        .layer(DefaultBodyLimit::max(limits.max_body_bytes))
        .layer(tower_http::limit::RequestBodyLimitLayer::new(
            limits.max_body_bytes,
        ))
        .layer(tower_http::timeout::TimeoutLayer::with_status_code(
            StatusCode::SERVICE_UNAVAILABLE,
            limits.request_timeout,
        ))
        .with_state(state)
}

/// The latest snapshot, or the 503 every read route gives before the first cycle.
fn snapshot(s: &AppState) -> Result<Arc<StatusSnapshot>, Box<Response>> {
    let snap = s.rx.borrow().clone();
    snap.ok_or_else(|| Box::new(plain(StatusCode::SERVICE_UNAVAILABLE, "no cycle run yet\n")))
}

async fn status_json(State(s): State<AppState>) -> Response {
    match snapshot(&s) {
        Ok(snap) => {
            let body =
                serde_json::to_string(&*snap).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}"));
            ([(header::CONTENT_TYPE, "application/json")], body).into_response()
        }
        Err(r) => *r,
    }
}

async fn metrics(State(s): State<AppState>) -> Response {
    match snapshot(&s) {
        Ok(snap) => (
            [(header::CONTENT_TYPE, "text/plain; version=0.0.4")],
            snap.prometheus(),
        )
            .into_response(),
        Err(r) => *r,
    }
}

async fn text(State(s): State<AppState>) -> Response {
    match snapshot(&s) {
        Ok(snap) => (
            [(header::CONTENT_TYPE, "text/plain; charset=utf-8")],
            snap.render_text(),
        )
            .into_response(),
        Err(r) => *r,
    }
}

async fn fallback(State(s): State<AppState>, method: Method) -> Response {
    if method != Method::GET && method != Method::HEAD {
        return not_allowed().await;
    }
    if let Err(r) = snapshot(&s) {
        return *r;
    }
    plain(
        StatusCode::NOT_FOUND,
        "not found: try /, /status, /metrics or /text\n",
    )
}

#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct CompensationBody {
    enabled: bool,
}

async fn set_compensation(
    State(s): State<AppState>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
    body: Result<Json<CompensationBody>, JsonRejection>,
) -> Response {
    if let Err(r) = authorize(&s, peer, &headers, "POST /api/compensation") {
        return *r;
    }
    let Json(CompensationBody { enabled }) = match body {
        Ok(b) => b,
        Err(e) => return (e.status(), format!("{}\n", e.body_text())).into_response(),
    };
    let action = format!("compensation enabled={enabled}");
    let Some(tx) = s.api.control_tx.as_ref() else {
        record(&s, peer, "api_token", &action, "refused: no run loop (503)");
        return plain(
            StatusCode::SERVICE_UNAVAILABLE,
            "no run loop takes actions\n",
        );
    };
    if tx.try_send(Control::SetCompensation { enabled }).is_err() {
        record(
            &s,
            peer,
            "api_token",
            &action,
            "refused: run loop busy (503)",
        );
        return plain(
            StatusCode::SERVICE_UNAVAILABLE,
            "run loop busy or stopped; retry\n",
        );
    }
    let unix_s = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_secs());
    let agent = headers
        .get(header::USER_AGENT)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("-");
    tracing::info!(%peer, agent, unix_s, enabled, who = "api_token", "action accepted: POST /api/compensation");
    record(
        &s,
        peer,
        "api_token",
        &action,
        "accepted (ramps through the safety layer)",
    );
    Json(serde_json::json!({ "enabled": enabled })).into_response()
}

async fn serve_connection(
    stream: IdleStream<TcpStream>,
    peer: SocketAddr,
    app: Router,
    limits: Limits,
) {
    let svc = app.map_request(move |mut req: Request<hyper::body::Incoming>| {
        req.extensions_mut().insert(ConnectInfo(peer));
        req
    });
    let mut b = hyper::server::conn::http1::Builder::new();
    b.timer(TokioTimer::new())
        .header_read_timeout(limits.header_read_timeout)
        .max_buf_size(limits.max_head_bytes.max(8192) + limits.max_body_bytes)
        .max_header_size(limits.max_head_bytes)
        // A client that sends its request and then shuts its write side (`nc -N`, scripts) still
        // gets the answer, as the hand-rolled server gave it.
        .half_close(true)
        .keep_alive(false);
    let conn = b.serve_connection(TokioIo::new(stream), TowerToHyperService::new(svc));
    let _ = tokio::time::timeout(limits.connection_deadline, conn).await;
}

/// Minimal client for `retrocomp status`: GET `path` from `addr`, return (status code, body).
pub async fn get(addr: &str, path: &str, timeout: Duration) -> std::io::Result<(u16, String)> {
    request(addr, Method::GET, path, &[], Bytes::new(), timeout).await
}

/// One HTTP/1.1 request on a fresh connection (hyper's client); returns (status code, body).
pub async fn request(
    addr: &str,
    method: Method,
    path: &str,
    headers: &[(&str, &str)],
    body: Bytes,
    timeout: Duration,
) -> std::io::Result<(u16, String)> {
    let fut = async {
        let stream = TcpStream::connect(addr).await?;
        let (mut sender, conn) = hyper::client::conn::http1::handshake(TokioIo::new(stream))
            .await
            .map_err(std::io::Error::other)?;
        let conn = tokio::spawn(conn);
        let mut req = Request::builder()
            .method(method)
            .uri(path)
            .header(header::HOST, addr);
        for (k, v) in headers {
            req = req.header(*k, *v);
        }
        let req = req.body(Body::from(body)).map_err(std::io::Error::other)?;
        let resp = sender
            .send_request(req)
            .await
            .map_err(std::io::Error::other)?;
        let code = resp.status().as_u16();
        let body = resp
            .into_body()
            .collect()
            .await
            .map_err(std::io::Error::other)?
            .to_bytes();
        conn.abort();
        Ok((code, String::from_utf8_lossy(&body).into_owned()))
    };
    tokio::time::timeout(timeout, fut).await.map_err(|_| {
        std::io::Error::new(
            std::io::ErrorKind::TimedOut,
            format!("no answer from {addr}"),
        )
    })?
}

#[cfg(test)]
#[path = "http_spelling_tests.rs"]
mod spelling_tests;
