//! What every HTTP route shares, whether it lives in `http.rs` (the read routes and
//! `POST /api/compensation`) or `web.rs` (the live page and its JSON): the router's state, the
//! actions forwarded to the run loop ([`Control`]), the bearer-token check and the action log.
//! Both route files import this one; neither imports the other's handlers (`http.rs` only merges
//! `web::routes()` into its router).

use std::net::SocketAddr;
use std::sync::Arc;

use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use tokio::sync::{mpsc, watch};

use crate::status::StatusSnapshot;

pub type StatusRx = watch::Receiver<Option<Arc<StatusSnapshot>>>;

/// A run-time action accepted on the authenticated API (defined with the switch that applies it).
pub use crate::engine::model_switch::Control;

/// What the action routes need: the token from the field config (`[gateway] api_token`; `None`
/// → every action is refused with 403), the channel to the run loop (`None` → 503) and the
/// models that may be switched to (`[gateway.models]`; `None` → none).
#[derive(Clone, Debug, Default)]
pub struct Api {
    pub token: Option<String>,
    pub control_tx: Option<mpsc::Sender<Control>>,
    pub models: Option<Arc<crate::engine::model_switch::Catalog>>,
}

#[derive(Clone)]
pub(super) struct AppState {
    pub(super) rx: StatusRx,
    pub(super) api: Arc<Api>,
    pub(super) history: crate::northbound::history::SharedHistory,
    /// The last model switch accepted (name, sha256), for `GET /api/models`.
    #[cfg_attr(not(feature = "web"), allow(dead_code))]
    pub(super) model_request: Arc<std::sync::Mutex<Option<(String, String)>>>,
    /// The endpoint's listener policy (`allow_writes_from` decides who may act) and faults.
    pub(super) policy: Arc<retrocomp_bus::listen::ListenPolicy>,
    pub(super) listener: retrocomp_bus::listen::ListenerHealth,
}

pub(super) fn plain(code: StatusCode, body: &'static str) -> Response {
    (code, [(header::CONTENT_TYPE, "text/plain")], body).into_response()
}

pub(super) async fn not_allowed() -> Response {
    plain(StatusCode::METHOD_NOT_ALLOWED, "read-only: GET only\n")
}

/// Compare in time independent of where the strings first differ (the token is a secret).
fn same_secret(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// Check the bearer token of an action (before looking at its body: an unauthorised caller
/// learns nothing else). Refusals are logged and kept in the action log.
pub(super) fn authorize(
    s: &AppState,
    peer: SocketAddr,
    headers: &HeaderMap,
    action: &str,
) -> Result<(), Box<Response>> {
    if !s.policy.may_write(peer.ip()) {
        s.listener.refused_write(peer.ip());
        record(
            s,
            peer,
            "-",
            action,
            "refused: peer not on allow_writes_from (403)",
        );
        return Err(Box::new(plain(
            StatusCode::FORBIDDEN,
            "actions refused from this address: not on [gateway.listen_policy] allow_writes_from\n",
        )));
    }
    let Some(expected) = s.api.token.as_deref() else {
        record(s, peer, "-", action, "refused: no api_token configured");
        return Err(Box::new(plain(
            StatusCode::FORBIDDEN,
            "actions disabled: no [gateway] api_token in the field config\n",
        )));
    };
    let presented = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.strip_prefix("Bearer "));
    if !presented.is_some_and(|t| same_secret(t.trim().as_bytes(), expected.as_bytes())) {
        tracing::warn!(%peer, action, "action refused: missing or wrong bearer token");
        record(
            s,
            peer,
            "-",
            action,
            "refused: missing or wrong token (401)",
        );
        let mut r = plain(StatusCode::UNAUTHORIZED, "valid bearer token required\n");
        r.headers_mut()
            .insert(header::WWW_AUTHENTICATE, "Bearer".parse().expect("static"));
        return Err(Box::new(r));
    }
    Ok(())
}

/// Keep an action in the page's action log (who: `api_token` when authorised, `-` otherwise).
pub(super) fn record(s: &AppState, peer: SocketAddr, who: &str, action: &str, result: &str) {
    let ev = crate::northbound::history::ActionEvent {
        unix_s: crate::northbound::history::unix_now_s(),
        peer: peer.to_string(),
        who: who.to_string(),
        action: action.to_string(),
        result: result.to_string(),
    };
    let mut h = s.history.lock().unwrap_or_else(|p| p.into_inner());
    h.record_action(ev);
}
