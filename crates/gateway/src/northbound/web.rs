//! The live page a technician looks at (`GET /`) and the JSON it polls, served by the status
//! endpoint (`http.rs`: same bounds, same token). Assets are compiled into the binary
//! (`crates/gateway/assets/web/`, uPlot 1.6.32 from the npm registry with its MIT licence): nothing is fetched
//! from the internet at run time.
//!
//! Read routes (open): `/`, `/assets/*`, `/api/history?window=fine|coarse` (corrections, µm, per
//! axis and term; see `history.rs`), `/api/faults` (active + start/clear log), `/api/health`
//! (sensor health changes), `/api/actions` (who did what, when). Actions (token): `POST
//! /api/faults/ack` (`{}` or `{"source": "..."}`: records that a person saw the faults; changes
//! nothing on the machine) and `POST /api/model` (`{"model": "<name>"}`: switch to a model declared
//! in `[gateway.models]`, through the safety ramps, see `model_switch.rs`); `GET /api/models` (open)
//! lists the declared ones, the one in use and a switch in progress. The token is checked before
//! the body is read, so a client without it learns nothing.

use std::net::SocketAddr;

use axum::Router;
use axum::extract::rejection::JsonRejection;
use axum::extract::{ConnectInfo, Json, Query, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};

use crate::northbound::history::{Ack, unix_now_s};
use crate::northbound::http_state::{AppState, Control, authorize, not_allowed, plain, record};

const INDEX_HTML: &str = include_str!("../../assets/web/index.html");
const APP_JS: &str = include_str!("../../assets/web/app.js");
const APP_CSS: &str = include_str!("../../assets/web/app.css");
const UPLOT_JS: &str = include_str!("../../assets/web/uplot/uPlot.iife.min.js");
const UPLOT_CSS: &str = include_str!("../../assets/web/uplot/uPlot.min.css");
const UPLOT_LICENSE: &str = include_str!("../../assets/web/uplot/LICENSE");

pub(super) fn routes() -> Router<AppState> {
    let asset = |body: &'static str, kind: &'static str| {
        get(move || async move {
            (
                [
                    (header::CONTENT_TYPE, kind),
                    (header::CACHE_CONTROL, "no-cache"),
                ],
                body,
            )
        })
        .fallback(not_allowed)
    };
    Router::new()
        .route("/", asset(INDEX_HTML, "text/html; charset=utf-8"))
        .route("/assets/app.js", asset(APP_JS, "text/javascript"))
        .route("/assets/app.css", asset(APP_CSS, "text/css"))
        .route(
            "/assets/uPlot.iife.min.js",
            asset(UPLOT_JS, "text/javascript"),
        )
        .route("/assets/uPlot.min.css", asset(UPLOT_CSS, "text/css"))
        .route("/assets/uPlot-LICENSE", asset(UPLOT_LICENSE, "text/plain"))
        .route("/api/history", get(history).fallback(not_allowed))
        .route("/api/faults", get(faults).fallback(not_allowed))
        .route("/api/health", get(health).fallback(not_allowed))
        .route("/api/actions", get(actions).fallback(not_allowed))
        .route("/api/faults/ack", post(ack))
        .route("/api/model", post(switch_model))
        .route("/api/models", get(models).fallback(not_allowed))
}

#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Window {
    window: Option<String>,
}

fn json(v: serde_json::Value) -> Response {
    (
        [
            (header::CONTENT_TYPE, "application/json"),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        v.to_string(),
    )
        .into_response()
}

fn with_history<F: FnOnce(&crate::northbound::history::History) -> serde_json::Value>(
    s: &AppState,
    f: F,
) -> Response {
    let h = s.history.lock().unwrap_or_else(|p| p.into_inner());
    json(f(&h))
}

async fn history(
    State(s): State<AppState>,
    q: Result<Query<Window>, axum::extract::rejection::QueryRejection>,
) -> Response {
    let coarse = match q.as_ref().map(|q| q.window.as_deref()) {
        Ok(None | Some("fine")) => false,
        Ok(Some("coarse")) => true,
        // Unknown window, unknown key or bad encoding.
        _ => {
            return plain(
                StatusCode::BAD_REQUEST,
                "query: ?window=fine (15 min at 1 s) or ?window=coarse (24 h at 10 s)\n",
            );
        }
    };
    with_history(&s, |h| h.history_json(coarse))
}

async fn faults(State(s): State<AppState>) -> Response {
    with_history(&s, |h| h.faults_json())
}

async fn health(State(s): State<AppState>) -> Response {
    with_history(&s, |h| h.health_json())
}

async fn actions(State(s): State<AppState>) -> Response {
    with_history(&s, |h| h.actions_json())
}

#[derive(Debug, Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct AckBody {
    source: Option<String>,
}

async fn ack(
    State(s): State<AppState>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
    body: Result<Json<AckBody>, JsonRejection>,
) -> Response {
    if let Err(r) = authorize(&s, peer, &headers, "POST /api/faults/ack") {
        return *r;
    }
    let Json(AckBody { source }) = match body {
        Ok(b) => b,
        Err(e) => return (e.status(), format!("{}\n", e.body_text())).into_response(),
    };
    let n = {
        let mut h = s.history.lock().unwrap_or_else(|p| p.into_inner());
        let who = Ack {
            unix_s: unix_now_s(),
            peer: peer.to_string(),
        };
        h.acknowledge(source.as_deref(), &who)
    };
    let action = format!(
        "acknowledge faults of {}",
        source.as_deref().unwrap_or("every source")
    );
    tracing::info!(%peer, who = "api_token", n, "action accepted: {action}");
    record(
        &s,
        peer,
        "api_token",
        &action,
        &format!("accepted: {n} acknowledged"),
    );
    json(serde_json::json!({ "acknowledged": n }))
}

#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ModelBody {
    model: String,
}

/// The declared models, the one in use and the last switch accepted (open, read-only).
async fn models(State(s): State<AppState>) -> Response {
    let declared = s.api.models.as_ref().map_or(Vec::new(), |c| c.names());
    let current = s.rx.borrow().as_ref().and_then(|snap| snap.model.clone());
    let requested = s
        .model_request
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .clone();
    let switching = requested
        .as_ref()
        .filter(|(_, sha)| current.as_ref().is_none_or(|c| &c.sha256 != sha));
    json(serde_json::json!({
        "declared": declared,
        "current": current,
        "switching_to": switching.map(|(n, sha)| serde_json::json!({"name": n, "sha256": sha})),
    }))
}

/// `POST /api/model {"model": "<name in [gateway.models]>"}`: load and check the model here (off
/// the cycle thread), then hand it to the cycle, which ramps out, swaps and ramps in
/// (`model_switch.rs`). 202 when handed over; 404 for a name not declared; 422 when it does not
/// load or check; 409 when it is the model already in use. A refusal changes nothing.
async fn switch_model(
    State(s): State<AppState>,
    ConnectInfo(peer): ConnectInfo<SocketAddr>,
    headers: HeaderMap,
    body: Result<Json<ModelBody>, JsonRejection>,
) -> Response {
    if let Err(r) = authorize(&s, peer, &headers, "POST /api/model") {
        return *r;
    }
    let Json(ModelBody { model: name }) = match body {
        Ok(b) => b,
        Err(e) => return (e.status(), format!("{}\n", e.body_text())).into_response(),
    };
    let action = format!("switch model to {name:?}");
    let refuse = |code: StatusCode, why: String| {
        tracing::warn!(%peer, who = "api_token", "action refused: {action}: {why}");
        record(
            &s,
            peer,
            "api_token",
            &action,
            &format!("refused ({}): {why}", code.as_u16()),
        );
        (
            code,
            [(header::CONTENT_TYPE, "text/plain")],
            format!("{why}\n"),
        )
            .into_response()
    };
    let (Some(catalog), Some(tx)) = (s.api.models.clone(), s.api.control_tx.as_ref()) else {
        return refuse(
            StatusCode::SERVICE_UNAVAILABLE,
            "no run loop takes actions".into(),
        );
    };
    let snap = s.rx.borrow().clone();
    let seen: Vec<String> = snap
        .as_ref()
        .map_or(Vec::new(), |s| s.channels.keys().cloned().collect());
    let current = snap
        .as_ref()
        .and_then(|s| s.model.as_ref())
        .map(|m| m.sha256.clone());
    let loading = name.clone();
    let loaded = tokio::task::spawn_blocking(move || catalog.load(&loading, &seen)).await;
    let swap = match loaded {
        Ok(Ok(swap)) => swap,
        Ok(Err(e)) => {
            let code = StatusCode::from_u16(e.http_status()).unwrap_or(StatusCode::BAD_REQUEST);
            return refuse(code, e.to_string());
        }
        Err(e) => {
            return refuse(
                StatusCode::INTERNAL_SERVER_ERROR,
                format!("loading failed: {e}"),
            );
        }
    };
    if current.as_deref() == Some(swap.identity.sha256.as_str()) {
        return refuse(
            StatusCode::CONFLICT,
            format!("model {name:?} is already in use"),
        );
    }
    let target = serde_json::json!({
        "name": swap.name, "model_name": swap.identity.name, "sha256": swap.identity.sha256,
    });
    let sha = swap.identity.sha256.clone();
    if tx.try_send(Control::SwitchModel(Box::new(swap))).is_err() {
        return refuse(
            StatusCode::SERVICE_UNAVAILABLE,
            "run loop busy or stopped; retry".into(),
        );
    }
    *s.model_request.lock().unwrap_or_else(|p| p.into_inner()) = Some((name.clone(), sha.clone()));
    tracing::info!(%peer, who = "api_token", sha256 = sha, "action accepted: POST /api/model: {action}");
    record(
        &s,
        peer,
        "api_token",
        &action,
        &format!("accepted: ramping out, then {sha}"),
    );
    (
        StatusCode::ACCEPTED,
        json(serde_json::json!({ "switching_to": target })),
    )
        .into_response()
}
