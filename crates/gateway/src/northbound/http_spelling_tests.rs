//! One spelling per state across every API: the router in-process, fed a snapshot holding every
//! health, mode, fault kind and CAN bus state (and a history that saw faults start and clear),
//! answers every read route; every word of every answer, and every string literal of the page's
//! script, is compared with the states' serde names. A word that is a state under another spelling
//! (`Ok`, `RampingIn`, `bus-off`, `DISCONNECTED`) fails the test. (`/api/health` once spelled
//! `"Ok"` while `/status` spelled `"ok"` and the page tested `"ok"`: every recovery showed red.)

use std::collections::BTreeMap;
use std::sync::Arc;

use axum::body::Body;
use axum::http::Request;
use http_body_util::BodyExt;
use tower::ServiceExt;

use super::{Limits, router};
use crate::engine::health::FaultKind;
use crate::northbound::history::History;
use crate::northbound::http_state::{Api, AppState};
use crate::northbound::state_name;
use crate::status::AxisStatus;
use crate::status::{CanBusStatus, ChannelStatus, Mode, SourceStatus, StatusSnapshot};
use retrocomp_bus::Health;
use retrocomp_bus::can::BusState;

const HEALTHS: [Health; 4] = [
    Health::Ok,
    Health::Stale,
    Health::OutOfRange,
    Health::DecodeError,
];
const MODES: [Mode; 4] = [
    Mode::Tracking,
    Mode::RampingIn,
    Mode::Holding,
    Mode::RampingOut,
];
const BUS: [BusState; 4] = [
    BusState::Active,
    BusState::Warning,
    BusState::Passive,
    BusState::BusOff,
];

/// Every state's one spelling, and the link words (a link is `connected` or `disconnected`).
fn vocabulary() -> Vec<String> {
    let mut v: Vec<String> = HEALTHS.iter().map(state_name).collect();
    v.extend(MODES.iter().map(state_name));
    v.extend(BUS.iter().map(state_name));
    v.extend(FaultKind::ALL.iter().map(state_name));
    v.extend(["connected".to_string(), "disconnected".to_string()]);
    v
}

fn norm(w: &str) -> String {
    w.chars()
        .filter(|c| c.is_alphanumeric())
        .flat_map(char::to_lowercase)
        .collect()
}

/// The words of `text` that spell a state otherwise than its serde name (`where` says whose).
fn misspelled(text: &str, whose: &str, vocab: &[String]) -> Vec<String> {
    let by_norm: BTreeMap<String, &String> = vocab.iter().map(|w| (norm(w), w)).collect();
    text.split(|c: char| !(c.is_alphanumeric() || c == '_' || c == '-'))
        .filter(|w| !w.is_empty())
        .filter_map(|w| {
            let canon = by_norm.get(&norm(w))?;
            (w != canon.as_str()).then(|| format!("{whose}: `{w}` (one spelling: `{canon}`)"))
        })
        .collect()
}

fn snapshot(t_s: f64, faulted: bool) -> StatusSnapshot {
    let axes = MODES
        .iter()
        .enumerate()
        .map(|(i, m)| AxisStatus {
            axis: ["x", "y", "z", "a"][i].into(),
            position_mm: Some(1.0),
            direction: None,
            weight_forward: 1.0,
            target_um: Some(1.0),
            applied_um: 1.0,
            mode: *m,
            terms_um: [("thermal".to_string(), 0.5)].into(),
            clamp_hits: 0,
            cap_hits: 0,
        })
        .collect();
    let channels = HEALTHS
        .iter()
        .enumerate()
        .map(|(i, h)| {
            let faults = if faulted && *h != Health::Ok {
                FaultKind::ALL.to_vec()
            } else {
                Vec::new()
            };
            let c = ChannelStatus {
                value: Some(1.0),
                health: if faulted { *h } else { Health::Ok },
                faults,
                substituted: false,
                reading_t_s: Some(t_s - 0.1),
            };
            (format!("ch{i}_C"), c)
        })
        .collect();
    let active_faults = if faulted {
        FaultKind::ALL
            .iter()
            .map(|k| ("ch1_C".to_string(), *k, t_s - 1.0))
            .collect()
    } else {
        Vec::new()
    };
    let sources = BUS
        .iter()
        .map(|b| SourceStatus {
            name: format!("can{}", *b as u8),
            connected: *b != BusState::BusOff,
            reconnects: 0,
            faults: FaultKind::ALL.iter().map(|k| (*k, 1.0)).collect(),
            last_error: None,
            can: Some(CanBusStatus {
                state: *b,
                error_frames: 0,
                bus_off_events: 0,
                tx_error_count: None,
                rx_error_count: None,
            }),
            modbus: None,
        })
        .collect();
    let sink = crate::sinks::SinkStatus {
        kind: "origin_shift".into(),
        connected: false,
        writes_ok: 1,
        writes_failed: 1,
        last_error: None,
        held_um: BTreeMap::new(),
        faults: FaultKind::ALL
            .iter()
            .map(|k| ("sink.origin_shift".to_string(), *k, 1.0))
            .collect(),
    };
    StatusSnapshot {
        t_s,
        cycles: 10,
        enabled: true,
        axes,
        channels,
        active_faults,
        sink: Some(sink),
        sources,
        ..Default::default()
    }
}

#[tokio::test]
async fn every_api_and_the_page_spell_each_state_one_way() {
    // The history saw every fault start (t = 2) and clear (t = 3): its logs hold every state.
    let mut h = History::default();
    h.observe(&snapshot(1.0, false), 101.0);
    h.observe(&snapshot(2.0, true), 102.0);
    h.observe(&snapshot(3.0, false), 103.0);
    h.observe(&snapshot(4.0, true), 104.0);
    let (_tx, rx) = tokio::sync::watch::channel(Some(Arc::new(snapshot(4.0, true))));
    let state = AppState {
        rx,
        api: Arc::new(Api::default()),
        history: Arc::new(std::sync::Mutex::new(h)),
        model_request: Default::default(),
        policy: Arc::default(),
        listener: retrocomp_bus::listen::ListenerHealth::new("http"),
    };
    let app = router(state, &Limits::default());
    let vocab = vocabulary();
    let mut wrong = Vec::new();
    let mut routes = vec!["/status", "/metrics", "/text"];
    if cfg!(feature = "web") {
        routes.extend([
            "/api/health",
            "/api/faults",
            "/api/history?window=fine",
            "/api/history?window=coarse",
            "/api/actions",
            "/api/models",
            "/assets/app.js",
            "/",
        ]);
    }
    let mut seen = BTreeMap::new();
    for path in routes {
        let req = Request::get(path).body(Body::empty()).unwrap();
        let resp = app.clone().oneshot(req).await.unwrap();
        assert_eq!(resp.status(), 200, "{path}");
        let body = resp.into_body().collect().await.unwrap().to_bytes();
        let text = String::from_utf8(body.to_vec()).unwrap();
        for w in &vocab {
            if text.contains(w.as_str()) {
                *seen.entry(w.clone()).or_insert(0) += 1;
            }
        }
        wrong.extend(misspelled(&text, path, &vocab));
    }
    assert!(wrong.is_empty(), "second spellings:\n{}", wrong.join("\n"));
    // The test saw what it checks: every state is in some answer (else it proves nothing).
    let unseen: Vec<_> = vocab.iter().filter(|w| !seen.contains_key(*w)).collect();
    assert!(unseen.is_empty(), "states no route showed: {unseen:?}");
}

#[test]
fn the_checker_finds_a_second_spelling() {
    let v = vocabulary();
    assert_eq!(
        misspelled(r#"{"health":"Ok","mode":"ramping_in"}"#, "t", &v).len(),
        1
    );
    assert_eq!(misspelled("bus=bus-off DISCONNECTED", "t", &v).len(), 2);
    assert!(misspelled("ok stale bus_off ramping_out okay", "t", &v).is_empty());
}
