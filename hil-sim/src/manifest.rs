//! The JSON manifest of hidden truth written next to every recording: which effects the true machine
//! has, named with the effect ids of docs/diagnose-json.md and their parameters in that table's units and sign
//! conventions, plus the raw config so nothing is lost in translation.

use crate::config::SimConfig;
use crate::physics::thermal::ThermalEffect;
use crate::truth::TruthModel;
use serde_json::{Value, json};

const AXES: [&str; 3] = ["x", "y", "z"];

pub fn build(cfg: &SimConfig, truth: &dyn TruthModel) -> Value {
    let mut effects = Vec::new();
    let h = &cfg.hidden;
    for (k, ax) in AXES.iter().enumerate() {
        let signal = format!("e{ax}_um");
        if let Some(b) = h.backlash.get(k) {
            if b.profile.is_empty() {
                effects.push(json!({"effect": "backlash", "axis": ax, "signal": signal,
                    "params": {"b_um": -b.b_um},
                    "equation": format!("e{ax} += b_um/2 * sign(v_{ax}) (lost motion: the slide trails the screw)")}));
            } else {
                effects.push(json!({"effect": "reversal_profile", "axis": ax, "signal": signal,
                    "params": {"table_pos_mm_b_um": b.profile.iter().map(|r| [r[0], -r[1]]).collect::<Vec<_>>()},
                    "equation": format!("e{ax} += b(x)/2 * sign(v_{ax}), b linear between table points")}));
            }
        }
        if let Some(c) = h.cyclic.get(k) {
            effects.push(json!({"effect": "cyclic_error", "axis": ax, "signal": signal,
                "params": {"period_mm": c.period_mm, "amplitude_um": c.amplitude_um, "phase_rad": c.phase_rad},
                "equation": format!("e{ax} += amplitude_um * sin(2 pi {ax}_motor / period_mm + phase_rad)")}));
        }
        if !cfg.servo.ideal {
            let ms = (1.0 - cfg.servo.feedforward) / cfg.servo.kv_per_s * 1000.0;
            effects.push(json!({"effect": "servo_lag", "axis": ax, "signal": signal, "params": {"ms": ms},
                "equation": format!("e{ax}_um += -ms * v_{ax}_mm_s (following error: the slide trails the set-point)")}));
        }
    }
    if let Some(t) = &h.thermal {
        for e in &t.effects {
            let (node, axis) = match e {
                ThermalEffect::Growth { node, axis, .. }
                | ThermalEffect::Expansion { node, axis, .. } => (node, axis),
            };
            let sensors: Vec<_> = t
                .sensors
                .iter()
                .filter(|s| &s.node == node)
                .map(|s| json!({"sensor": format!("T_{}_C", s.name), "tau_s": s.tau_s}))
                .collect();
            let signal = format!("e{}_um", axis.as_str());
            match e {
                ThermalEffect::Growth { um_per_K, .. } => {
                    let lagged = sensors
                        .iter()
                        .all(|s| s["tau_s"].as_f64().unwrap_or(0.0) > 0.0);
                    effects.push(json!({"effect": if lagged { "thermal_lag" } else { "thermal_drift" },
                        "axis": axis.as_str(), "signal": signal, "node": node, "sensors": sensors,
                        "params": {"um_per_K": um_per_K},
                        "equation": format!("e{} += um_per_K * (T_{node} - T_{node}(0))", axis.as_str())}));
                }
                ThermalEffect::Expansion { ppm_per_K, .. } => {
                    effects.push(json!({"effect": "thermal_expansion", "axis": axis.as_str(), "signal": signal,
                        "node": node, "sensors": sensors, "params": {"ppm_per_K": ppm_per_K},
                        "equation": format!("e{0} += ppm_per_K * (T_{node} - T_{node}(0)) * {0}_mm * 1e-3", axis.as_str())}));
                }
            }
        }
        if t.ambient_drift_C_per_h != 0.0 || t.ambient_swing_C != 0.0 {
            effects.push(json!({"effect": "ambient", "params": {"drift_C_per_h": t.ambient_drift_C_per_h,
                "swing_C": t.ambient_swing_C, "period_s": t.ambient_period_s},
                "equation": "T_amb = ambient_C + drift*t + swing*sin(2 pi t/period); acts through the nodes"}));
        }
    }
    if let Some(c) = &h.cutting {
        for (k, ax) in AXES.iter().enumerate() {
            let um_per_n = c.compliance_um_per_N.get(k);
            if um_per_n != 0.0 {
                effects.push(json!({"effect": "force_deflection", "axis": ax, "signal": format!("e{ax}_um"),
                    "params": {"channel": format!("F_{}_N", c.force_name), "um_per_N": um_per_n},
                    "equation": format!("e{ax} += um_per_N * F (F = kc * depth * feed/(rpm*teeth), in cut only)")}));
            }
        }
    }
    json!({
        "generator": "hil-sim",
        "seed": cfg.seed,
        "sign": "error = actual - nominal (ISO 230-2), um",
        "visible_model": truth.describe(),
        "effects": effects,
        "encoder_count_um": cfg.servo.count_um,
        "error_noise_um": h.error_noise_um,
        "faults": cfg.faults,
        "hidden_config": h,
        "servo": cfg.servo,
        "plc": cfg.plc,
    })
}
