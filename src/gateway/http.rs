//! The box's HTTP endpoint, on axum over hyper, bound to 127.0.0.1 by default:
//! `GET /status` (JSON snapshot), `GET /metrics` (Prometheus text), `GET /text` (text table), all
//! read-only and open; the live page `GET /` and its JSON (`super::web`, history in
//! `super::history`); `POST /api/compensation` (`{"enabled": bool}`), the first action, needs
//! `Authorization: Bearer <[gateway] api_token>` and is forwarded to the run loop as a [`Control`].
//! Every action, accepted or refused, is logged (tracing) and kept in the page's action log with
//! the peer address. Unknown path: 404; wrong method: 405; no cycle run yet: 503 on the read routes.
//!
//! Bounded everything (issue 18.6): at most [`Limits::max_connections`] connections (more are
//! answered 503 and closed at once, never queued); one request per connection; the request head
//! must arrive within [`Limits::header_read_timeout`] (a client trickling one byte a second is cut
//! off), the head is capped at [`Limits::max_head_bytes`] (431) and the body at
//! [`Limits::max_body_bytes`] (413); the whole connection lives at most
//! [`Limits::connection_deadline`]. Accept errors (EMFILE, ENFILE, ENOMEM…) back off exponentially
//! to 1 s, logged once at start and once at clear. Descriptors: at start the soft RLIMIT_NOFILE is
//! raised to the hard limit, and a new connection is refused while the process's open descriptors
//! (counted in /proc/self/fd) are within [`Limits::fd_reserve`] of that limit, so a flood of
//! clients can never take the descriptors the controller link and the sources need to reconnect.

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
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::Semaphore;
use tower::ServiceExt;

pub use super::http_state::{Api, Control, StatusRx};
use super::http_state::{AppState, authorize, not_allowed, plain, record};
use super::status::StatusSnapshot;
use crate::bus::Backoff;

/// Resource bounds of the endpoint; [`Limits::default`] is what `retrocomp run` uses.
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    pub max_connections: usize,
    pub header_read_timeout: Duration,
    /// A handler that has not answered by then gets 503.
    pub request_timeout: Duration,
    pub connection_deadline: Duration,
    pub max_head_bytes: usize,
    pub max_body_bytes: usize,
    /// Descriptors kept free for the controller link, sources and logs (0: no reserve, only the
    /// accept backoff when the process runs out).
    pub fd_reserve: u64,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_connections: 64,
            header_read_timeout: Duration::from_secs(5),
            request_timeout: Duration::from_secs(5),
            connection_deadline: Duration::from_secs(15),
            max_head_bytes: 8192,
            max_body_bytes: 4096,
            fd_reserve: 128,
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
    let listener = TcpListener::bind(listen).await?;
    let addr = listener.local_addr()?;
    if !addr.ip().is_loopback() {
        tracing::warn!(%addr, "status endpoint bound to a non-loopback address");
    }
    raise_nofile_soft_limit();
    // Fed from the watch channel at ≤ 10 Hz; ends when the run loop drops the sender.
    let (history, _history_task) = super::history::spawn(rx.clone());
    let app = router(
        AppState {
            rx,
            api: Arc::new(api),
            history,
            model_request: Default::default(),
        },
        &limits,
    );
    Ok((addr, tokio::spawn(accept_loop(listener, app, limits))))
}

fn router(state: AppState, limits: &Limits) -> Router {
    Router::new()
        .route("/status", get_route(status_json).fallback(not_allowed))
        .route("/metrics", get_route(metrics).fallback(not_allowed))
        .route("/text", get_route(text).fallback(not_allowed))
        .route("/api/compensation", post(set_compensation))
        .merge(super::web::routes())
        .fallback(fallback)
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

/// Why new connections are being refused right now (logged at start and clear).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Refusing {
    AcceptError,
    Busy,
    FdReserve,
}

/// Retry delays after a failed accept (e.g. out of file descriptors): doubling from the min, reset by
/// the next accepted connection.
const ACCEPT_RETRY_MIN: Duration = Duration::from_millis(10);
const ACCEPT_RETRY_MAX: Duration = Duration::from_secs(1);

async fn accept_loop(listener: TcpListener, app: Router, limits: Limits) {
    let permits = Arc::new(Semaphore::new(limits.max_connections));
    let mut refusing: Option<Refusing> = None;
    let mut refused = 0u64;
    let mut backoff = Backoff::new(ACCEPT_RETRY_MIN, ACCEPT_RETRY_MAX);
    let mut set = |now: Option<Refusing>, refused: &mut u64| {
        if now == refusing {
            return;
        }
        if let Some(was) = refusing {
            tracing::info!(reason = ?was, refused = *refused, "status endpoint: fault cleared");
        }
        if let Some(r) = now {
            tracing::warn!(reason = ?r, "status endpoint: fault, refusing or delaying connections");
        }
        *refused = 0;
        refusing = now;
    };
    loop {
        let (stream, peer) = match listener.accept().await {
            Ok(x) => x,
            // The peer gave up before we accepted: nothing wrong on our side.
            Err(e) if e.kind() == std::io::ErrorKind::ConnectionAborted => continue,
            Err(e) => {
                set(Some(Refusing::AcceptError), &mut refused);
                let delay = backoff.next_delay();
                tracing::debug!(error = %e, backoff = ?delay, "accept failed");
                tokio::time::sleep(delay).await;
                continue;
            }
        };
        backoff.reset();
        if limits.fd_reserve > 0
            && let (Some(open), Some(limit)) = (open_fds(), nofile_soft_limit())
            && open + limits.fd_reserve >= limit
        {
            set(Some(Refusing::FdReserve), &mut refused);
            refused += 1;
            refuse(stream);
            continue;
        }
        let Ok(permit) = Arc::clone(&permits).try_acquire_owned() else {
            set(Some(Refusing::Busy), &mut refused);
            refused += 1;
            refuse(stream);
            continue;
        };
        set(None, &mut refused);
        let app = app.clone();
        tokio::spawn(async move {
            serve_connection(stream, peer, app, limits).await;
            drop(permit);
        });
    }
}

/// Best effort 503 without waiting on the peer, then close.
fn refuse(stream: TcpStream) {
    let _ = stream.try_write(
        b"HTTP/1.1 503 Service Unavailable\r\ncontent-length: 0\r\nconnection: close\r\n\r\n",
    );
}

async fn serve_connection(stream: TcpStream, peer: SocketAddr, app: Router, limits: Limits) {
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

/// Open descriptors of this process (Linux: entries of /proc/self/fd, minus the one read_dir uses).
fn open_fds() -> Option<u64> {
    let n = std::fs::read_dir("/proc/self/fd").ok()?.count() as u64;
    Some(n.saturating_sub(1))
}

fn nofile_soft_limit() -> Option<u64> {
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit writes into the struct we pass and nothing else.
    let rc = unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim) };
    (rc == 0 && lim.rlim_cur != libc::RLIM_INFINITY).then_some(lim.rlim_cur)
}

/// Raise the soft descriptor limit to the hard one (many distributions start services at 1024
/// soft with a much higher hard limit); the connection cap stays far below either.
fn raise_nofile_soft_limit() {
    let mut lim = libc::rlimit {
        rlim_cur: 0,
        rlim_max: 0,
    };
    // SAFETY: getrlimit/setrlimit read and write only the struct we pass.
    unsafe {
        if libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim) == 0 && lim.rlim_cur < lim.rlim_max {
            let was = lim.rlim_cur;
            lim.rlim_cur = lim.rlim_max;
            if libc::setrlimit(libc::RLIMIT_NOFILE, &lim) == 0 {
                tracing::info!(
                    from = was,
                    to = lim.rlim_max,
                    "raised soft RLIMIT_NOFILE to the hard limit"
                );
            }
        }
    }
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
