//! A gateway status snapshot for the Sparkplug tests: one axis `x` tracking, its correction and
//! position moving with the cycle count `k` (so every snapshot differs and NDATA keeps flowing).
//! Used by `real_peers`' `telemetry_mqtt`, `telemetry_fleet_drift` and `telemetry_fleet_host`.

use std::collections::BTreeMap;

use retrocomp_gateway::Mode;
use retrocomp_gateway::status::{AxisStatus, StatusSnapshot};
use retrocomp_model::approach::Approach;

pub(crate) fn snapshot(k: u64) -> StatusSnapshot {
    StatusSnapshot {
        t_s: k as f64 * 0.01,
        cycles: k,
        enabled: true,
        axes: vec![AxisStatus {
            axis: "x".into(),
            position_mm: Some(k as f64),
            direction: Some(Approach::Forward),
            weight_forward: 1.0,
            target_um: Some(-(k as f64) * 0.1),
            applied_um: -(k as f64) * 0.1,
            mode: Mode::Tracking,
            terms_um: BTreeMap::from([("thermal".to_string(), -(k as f64) * 0.1)]),
            clamp_hits: 0,
            cap_hits: 0,
        }],
        ..Default::default()
    }
}
