//! The live page's actions against a RUNNING gateway (issue 16.2): the real `retrocomp run` on the
//! real hil-sim (see `gateway_support/web_rig.rs`). Without a valid token `POST /api/compensation`
//! is 401 and nothing changes; with it `{"enabled": false}` takes the correction to 0 through the
//! safety ramps, which hil-sim's own log of every PLC write shows (no step beyond the dosing cap,
//! intermediate values on the way down, zero at the end). Also: acknowledging faults needs the token;
//! switching to a model not declared in `[gateway.models]` is refused with 404 (the switch itself:
//! `gateway_model_switch.rs`); every action is in `/api/actions` with the peer address.

use crate::configs;
use crate::observe;
use crate::web_rig;

use std::time::{Duration, Instant};

use web_rig::{TOKEN, applied};

const OFF: &str = r#"{"enabled": false}"#;

#[test]
fn disabling_over_the_api_ramps_a_running_gateway_to_zero_and_needs_the_token() {
    let _turn = crate::turn::take(file!());
    // Four strokes: the program ends by itself after ≈ 13 s (hil-sim then writes its logs).
    let mut rig = web_rig::start("gateway_web_actions", 4, "");
    let before = rig.wait_status("tracking with a correction", Duration::from_secs(30), |s| {
        s["enabled"] == true
            && s["axes"]
                .as_array()
                .unwrap()
                .iter()
                .all(|a| a["mode"] == "tracking")
            && applied(s).iter().any(|(_, v)| v.abs() > 1.0)
    });
    assert!(
        before["model"]["sha256"].as_str().unwrap().len() == 64,
        "{before}"
    );

    // No token or a wrong one: 401, and the gateway keeps compensating.
    for auth in [None, Some("wrong-token-wrong-token")] {
        let (code, body) = rig.call("POST", "/api/compensation", auth, OFF);
        assert_eq!(code, 401, "{auth:?}: {body}");
    }
    let (code, _) = rig.call("POST", "/api/faults/ack", None, "{}");
    assert_eq!(code, 401, "acknowledging needs the token");
    let (code, body) = rig.call("POST", "/api/model", Some(TOKEN), r#"{"model": "other"}"#);
    assert_eq!(code, 404, "no [gateway.models] declared here: {body}");
    let (code, body) = rig.call("POST", "/api/faults/ack", Some(TOKEN), "{}");
    assert_eq!(code, 200, "{body}");
    let (code, _) = rig.call("POST", "/api/compensation", Some(TOKEN), "{\"enabled\": 3}");
    assert_eq!(
        code, 422,
        "a bad body with the token is a 4xx, not a change"
    );
    let until = Instant::now() + Duration::from_millis(500);
    while Instant::now() < until {
        let s = rig.status().unwrap();
        assert_eq!(s["enabled"], true, "a refused action changed nothing: {s}");
        assert!(
            s["axes"]
                .as_array()
                .unwrap()
                .iter()
                .all(|a| a["mode"] != "ramping_out"),
            "{s}"
        );
        std::thread::sleep(Duration::from_millis(20));
    }

    let off_at_s = rig.t0.elapsed().as_secs_f64();
    let (code, body) = rig.call("POST", "/api/compensation", Some(TOKEN), OFF);
    assert_eq!((code, body.trim()), (200, r#"{"enabled":false}"#));
    let off = rig.wait_status("ramped to zero", Duration::from_secs(20), |s| {
        s["enabled"] == false && applied(s).iter().all(|(_, v)| *v == 0.0)
    });
    eprintln!("disabled at ≈ {off_at_s:.2} s; /status at zero: {off}");

    let actions = rig.call("GET", "/api/actions", None, "").1;
    let log: serde_json::Value = serde_json::from_str(&actions).unwrap();
    let lines = log["log"].as_array().unwrap();
    let refused = lines
        .iter()
        .filter(|l| {
            l["result"]
                .as_str()
                .unwrap()
                .starts_with("refused: missing")
        })
        .count();
    assert_eq!(
        refused, 3,
        "three refusals logged (2 compensation, 1 ack): {actions}"
    );
    assert!(
        lines
            .iter()
            .any(|l| l["action"] == "switch model to \"other\""
                && l["result"].as_str().unwrap().contains("404"))
    );
    let last = lines.last().unwrap();
    assert_eq!(last["action"], "compensation enabled=false", "{actions}");
    assert_eq!(last["who"], "api_token");
    assert!(
        last["peer"].as_str().unwrap().starts_with("127.0.0.1:"),
        "{last}"
    );
    assert!(
        rig.log_text()
            .contains("action accepted: POST /api/compensation")
    );

    let text = rig.plc_writes_after_sim_ends();
    let writes: Vec<_> = observe::parse_writes(&text)
        .into_iter()
        .filter(|w| w.address == 0)
        .collect();
    let (_, max_step) = observe::assert_clamp_and_cap(&writes);
    // Around the disable (the sim clock runs a few ms ahead of the test's t0): from a correction to
    // zero through intermediate values, each within the cap.
    let after: Vec<[f64; 3]> = writes
        .iter()
        .filter(|w| w.t_s >= off_at_s - 0.05)
        .map(|w| w.um)
        .collect();
    let peak = |u: &[f64; 3]| u.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    assert!(
        peak(&after[0]) > 1.0,
        "a correction was applied when disabled: {:?}",
        after[0]
    );
    assert_eq!(*after.last().unwrap(), [0.0; 3], "zero at the end");
    let first_zero = after.iter().position(|u| peak(u) == 0.0).unwrap();
    let ramp: Vec<_> = after[..first_zero]
        .iter()
        .filter(|u| peak(u) < peak(&after[0]))
        .collect();
    assert!(
        !ramp.is_empty() || peak(&after[0]) <= configs::CAP_UM + configs::LSB_UM,
        "no intermediate value on the way down: {:?}",
        &after[..=first_zero]
    );
    eprintln!(
        "ramp down from {:.1} µm in {} writes, largest change between writes {max_step:.2} µm",
        peak(&after[0]),
        first_zero
    );
}
