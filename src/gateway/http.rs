//! Read-only status over HTTP/1.1 on 127.0.0.1 (by default): `GET /status` (JSON snapshot),
//! `GET /metrics` (Prometheus text), `GET /` (text table). Anything else: 404; other methods: 405.
//! Hand-rolled on tokio (a handful of GET routes do not justify a web framework); one request per
//! connection, a 5 s read deadline and an 8 KiB head limit so a slow or hostile client cannot pin it.

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::watch;

use super::status::StatusSnapshot;

pub type StatusRx = watch::Receiver<Option<Arc<StatusSnapshot>>>;

/// Bind and serve until the task is dropped. Returns the bound address (port 0 → chosen port).
pub async fn serve_status(
    listen: SocketAddr,
    rx: StatusRx,
) -> std::io::Result<(SocketAddr, tokio::task::JoinHandle<()>)> {
    let listener = TcpListener::bind(listen).await?;
    let addr = listener.local_addr()?;
    if !addr.ip().is_loopback() {
        tracing::warn!(%addr, "status endpoint bound to a non-loopback address");
    }
    let task = tokio::spawn(async move {
        loop {
            let Ok((stream, _)) = listener.accept().await else {
                continue;
            };
            let rx = rx.clone();
            tokio::spawn(async move {
                let _ = tokio::time::timeout(Duration::from_secs(5), handle(stream, rx)).await;
            });
        }
    });
    Ok((addr, task))
}

async fn handle(mut stream: TcpStream, rx: StatusRx) -> std::io::Result<()> {
    let mut buf = Vec::with_capacity(1024);
    let mut chunk = [0u8; 1024];
    while !buf.windows(4).any(|w| w == b"\r\n\r\n") {
        let n = stream.read(&mut chunk).await?;
        if n == 0 {
            return Ok(());
        }
        buf.extend_from_slice(&chunk[..n]);
        if buf.len() > 8192 {
            return respond(&mut stream, 431, "text/plain", "request head too large\n").await;
        }
    }
    let head = String::from_utf8_lossy(&buf);
    let mut parts = head.lines().next().unwrap_or("").split_whitespace();
    let (method, path) = (parts.next().unwrap_or(""), parts.next().unwrap_or(""));
    if method != "GET" {
        return respond(&mut stream, 405, "text/plain", "read-only: GET only\n").await;
    }
    let snap = rx.borrow().clone();
    let Some(snap) = snap else {
        return respond(&mut stream, 503, "text/plain", "no cycle run yet\n").await;
    };
    match path {
        "/status" => {
            let body =
                serde_json::to_string(&*snap).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}"));
            respond(&mut stream, 200, "application/json", &body).await
        }
        "/metrics" => {
            respond(
                &mut stream,
                200,
                "text/plain; version=0.0.4",
                &snap.prometheus(),
            )
            .await
        }
        "/" => {
            respond(
                &mut stream,
                200,
                "text/plain; charset=utf-8",
                &snap.render_text(),
            )
            .await
        }
        _ => {
            respond(
                &mut stream,
                404,
                "text/plain",
                "not found: try /status, /metrics or /\n",
            )
            .await
        }
    }
}

async fn respond(
    stream: &mut TcpStream,
    code: u16,
    ctype: &str,
    body: &str,
) -> std::io::Result<()> {
    let reason = match code {
        200 => "OK",
        404 => "Not Found",
        405 => "Method Not Allowed",
        431 => "Request Header Fields Too Large",
        _ => "Service Unavailable",
    };
    let head = format!(
        "HTTP/1.1 {code} {reason}\r\nContent-Type: {ctype}\r\nContent-Length: {}\r\nConnection: close\r\n\r\n",
        body.len()
    );
    stream.write_all(head.as_bytes()).await?;
    stream.write_all(body.as_bytes()).await?;
    stream.shutdown().await
}

/// Minimal client for `retrocomp status`: GET `path` from `addr`, return (status code, body).
pub async fn get(addr: &str, path: &str, timeout: Duration) -> std::io::Result<(u16, String)> {
    let fut = async {
        let mut s = TcpStream::connect(addr).await?;
        s.write_all(
            format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n").as_bytes(),
        )
        .await?;
        let mut resp = Vec::new();
        s.read_to_end(&mut resp).await?;
        let text = String::from_utf8_lossy(&resp).into_owned();
        let (head, body) = text
            .split_once("\r\n\r\n")
            .ok_or_else(|| std::io::Error::other("malformed HTTP response"))?;
        let code = head
            .split_whitespace()
            .nth(1)
            .and_then(|c| c.parse().ok())
            .ok_or_else(|| std::io::Error::other("no status code"))?;
        Ok((code, body.to_string()))
    };
    tokio::time::timeout(timeout, fut).await.map_err(|_| {
        std::io::Error::new(
            std::io::ErrorKind::TimedOut,
            format!("no answer from {addr}"),
        )
    })?
}
