//! The effect library of docs/diagnose-json.md: one forward model per effect id, shared by `diagnose` (as its
//! candidate terms) and by `hil-sim gen-cases` (as the hidden physics of its cases).
//!
//! Every model returns its contribution to ONE error signal (`e<axis>_um`, actual − nominal, µm) per
//! sample of a [`Context`]. `axis` is the axis of that signal; "own position" is that axis' position.
//! Parameter names and units are those of docs/diagnose-json.md and are the serde names (the JSON contract).

use serde::{Deserialize, Serialize};

use super::features::{Context, lowpass};

/// Effect ids of docs/diagnose-json.md, in the contract's order.
pub const EFFECT_IDS: [&str; 14] = [
    "scale_error",
    "backlash",
    "reversal_profile",
    "cyclic_error",
    "squareness",
    "straightness",
    "abbe",
    "thermal_drift",
    "thermal_lag",
    "thermal_expansion",
    "force_deflection",
    "servo_lag",
    "reversal_spike",
    "time_drift",
];

/// One effect with its parameters, serialised as `{"effect": id, "params": {...}}`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "effect", content = "params", rename_all = "snake_case")]
pub enum EffectModel {
    /// `e += ppm·1e-3·pos` (1 ppm of 1 mm = 1e-3 µm).
    ScaleError { ppm: f64 },
    /// `e += b_um/2·dir` (dir = latched approach direction ±1).
    Backlash { b_um: f64 },
    /// `e += b_um[k]/2·dir` while pos is in zone k = `[edges_mm[k], edges_mm[k+1])`.
    ReversalProfile { edges_mm: Vec<f64>, b_um: Vec<f64> },
    /// `e += amplitude_um·sin(2π·pos/period_mm + phase_rad)
    ///      + harmonic2_um·sin(4π·pos/period_mm + harmonic2_phase_rad)`: the second harmonic of the
    /// same fundamental (absent from the JSON when zero).
    CyclicError {
        period_mm: f64,
        amplitude_um: f64,
        phase_rad: f64,
        #[serde(default, skip_serializing_if = "is_zero")]
        harmonic2_um: f64,
        #[serde(default, skip_serializing_if = "is_zero")]
        harmonic2_phase_rad: f64,
    },
    /// `e += urad·1e-3·pos_other` (a squareness angle times the other axis' position).
    Squareness { other_axis: char, urad: f64 },
    /// `e += c2_um_per_mm2·(pos_along − mid_mm)²`: a bow across the travel of another axis.
    Straightness {
        along_axis: char,
        mid_mm: f64,
        c2_um_per_mm2: f64,
    },
    /// `e += urad_per_mm·pos·tool_mm·1e-3`: an angular error growing along the axis (µrad/mm)
    /// times the Abbe arm (tool length).
    Abbe { urad_per_mm: f64 },
    /// `e += um_per_K·(T − T(0))`.
    ThermalDrift {
        sensor: String,
        #[serde(rename = "um_per_K")]
        um_per_k: f64,
    },
    /// `e += um_per_K·(LPF_τ(T) − T(0))`, first-order lag with time constant `tau_s`.
    ThermalLag {
        sensor: String,
        tau_s: f64,
        #[serde(rename = "um_per_K")]
        um_per_k: f64,
    },
    /// `e += ppm_per_K·1e-3·pos·(T − T(0))`.
    ThermalExpansion {
        sensor: String,
        #[serde(rename = "ppm_per_K")]
        ppm_per_k: f64,
    },
    /// `e += um_per_N·F` (for a strain channel the gain is µm per µε, same key).
    ForceDeflection {
        channel: String,
        #[serde(rename = "um_per_N")]
        um_per_n: f64,
    },
    /// `e += −ms·v` (v in mm/s, ms in milliseconds → µm): the slide lags the command.
    ServoLag { ms: f64 },
    /// `e += amplitude_um·dir·exp(−d/decay_mm)`, d = distance since the last reversal.
    ReversalSpike { amplitude_um: f64, decay_mm: f64 },
    /// `e += um_per_h·t_s/3600`.
    TimeDrift { um_per_h: f64 },
}

// serde's `skip_serializing_if` hands the field by reference.
#[allow(clippy::trivially_copy_pass_by_ref)]
fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

#[derive(Debug, thiserror::Error, PartialEq)]
#[error("effect `{effect}` needs {what}, which the recording does not have")]
pub struct MissingInput {
    pub effect: &'static str,
    pub what: String,
}

impl EffectModel {
    pub fn id(&self) -> &'static str {
        match self {
            Self::ScaleError { .. } => "scale_error",
            Self::Backlash { .. } => "backlash",
            Self::ReversalProfile { .. } => "reversal_profile",
            Self::CyclicError { .. } => "cyclic_error",
            Self::Squareness { .. } => "squareness",
            Self::Straightness { .. } => "straightness",
            Self::Abbe { .. } => "abbe",
            Self::ThermalDrift { .. } => "thermal_drift",
            Self::ThermalLag { .. } => "thermal_lag",
            Self::ThermalExpansion { .. } => "thermal_expansion",
            Self::ForceDeflection { .. } => "force_deflection",
            Self::ServoLag { .. } => "servo_lag",
            Self::ReversalSpike { .. } => "reversal_spike",
            Self::TimeDrift { .. } => "time_drift",
        }
    }

    /// The equation as written in reports, for signal axis `a`.
    pub fn equation(&self, a: char) -> String {
        let e = format!("e{a}");
        match self {
            Self::ScaleError { .. } => format!("{e} += ppm*1e-3 * {a}_mm"),
            Self::Backlash { .. } => format!("{e} += b_um/2 * sign(v_{a})"),
            Self::ReversalProfile { .. } => format!("{e} += b_um[zone({a}_mm)]/2 * sign(v_{a})"),
            Self::CyclicError { harmonic2_um, .. } if *harmonic2_um != 0.0 => format!(
                "{e} += amplitude_um * sin(2*pi*{a}_mm/period_mm + phase_rad) \
                 + harmonic2_um * sin(4*pi*{a}_mm/period_mm + harmonic2_phase_rad)"
            ),
            Self::CyclicError { .. } => {
                format!("{e} += amplitude_um * sin(2*pi*{a}_mm/period_mm + phase_rad)")
            }
            Self::Squareness { other_axis, .. } => format!("{e} += urad*1e-3 * {other_axis}_mm"),
            Self::Straightness { along_axis, .. } => {
                format!("{e} += c2_um_per_mm2 * ({along_axis}_mm - mid_mm)^2")
            }
            Self::Abbe { .. } => format!("{e} += urad_per_mm * {a}_mm * tool_mm * 1e-3"),
            Self::ThermalDrift { sensor, .. } => {
                format!("{e} += um_per_K * ({sensor} - {sensor}(t0))")
            }
            Self::ThermalLag { sensor, .. } => {
                format!("{e} += um_per_K * (LPF[tau_s]({sensor}) - {sensor}(t0))")
            }
            Self::ThermalExpansion { sensor, .. } => {
                format!("{e} += ppm_per_K*1e-3 * {a}_mm * ({sensor} - {sensor}(t0))")
            }
            Self::ForceDeflection { channel, .. } => format!("{e} += um_per_N * {channel}"),
            Self::ServoLag { .. } => format!("{e} += -ms * v_{a} [mm/s]"),
            Self::ReversalSpike { .. } => {
                format!("{e} += amplitude_um * sign(v_{a}) * exp(-d_since_reversal_mm/decay_mm)")
            }
            Self::TimeDrift { .. } => format!("{e} += um_per_h * t_s/3600"),
        }
    }

    /// Value (µm) of an effect that is a function of ONE axis position and the approach direction
    /// only (`dir` ±1): scale, backlash, reversal profile and cyclic error (argument: own position),
    /// straightness (argument: the `along_axis` position). `None` for every other effect. This is
    /// what lets the effect become a bidirectional table of an ISO 230-1 component.
    pub fn at_position(&self, pos_mm: f64, dir: f64) -> Option<f64> {
        Some(match self {
            Self::ScaleError { ppm } => ppm * 1e-3 * pos_mm,
            Self::Backlash { b_um } => b_um / 2.0 * dir,
            Self::ReversalProfile { edges_mm, b_um } => {
                zone_of(edges_mm, pos_mm).map_or(0.0, |k| b_um[k] / 2.0 * dir)
            }
            Self::CyclicError {
                period_mm,
                amplitude_um,
                phase_rad,
                harmonic2_um,
                harmonic2_phase_rad,
            } => {
                let w = std::f64::consts::TAU * pos_mm / period_mm;
                amplitude_um * (w + phase_rad).sin()
                    + harmonic2_um * (2.0 * w + harmonic2_phase_rad).sin()
            }
            Self::Straightness {
                mid_mm,
                c2_um_per_mm2,
                ..
            } => c2_um_per_mm2 * (pos_mm - mid_mm).powi(2),
            _ => return None,
        })
    }

    /// Contribution to the error signal of axis `a` (µm) at every sample.
    pub fn evaluate(&self, a: char, ctx: &Context) -> Result<Vec<f64>, MissingInput> {
        let id = self.id();
        let miss = |what: String| MissingInput { effect: id, what };
        let own = || ctx.axis(a).ok_or_else(|| miss(format!("`{a}_mm`")));
        let temp = |s: &str| ctx.temp(s).ok_or_else(|| miss(format!("`{s}`")));
        Ok(match self {
            Self::ScaleError { .. }
            | Self::Backlash { .. }
            | Self::ReversalProfile { .. }
            | Self::CyclicError { .. }
            | Self::Straightness { .. } => {
                let arg = match self {
                    Self::Straightness { along_axis, .. } => *along_axis,
                    _ => a,
                };
                let f = ctx.axis(arg).ok_or_else(|| miss(format!("`{arg}_mm`")))?;
                f.pos_mm
                    .iter()
                    .zip(&f.dir)
                    .map(|(x, &d)| {
                        self.at_position(*x, f64::from(d))
                            .expect("positional effect")
                    })
                    .collect()
            }
            Self::Squareness { other_axis, urad } => {
                let o = ctx
                    .axis(*other_axis)
                    .ok_or_else(|| miss(format!("`{other_axis}_mm`")))?;
                o.pos_mm.iter().map(|y| urad * 1e-3 * y).collect()
            }
            Self::Abbe { urad_per_mm } => {
                let tool = ctx
                    .tool_mm
                    .as_ref()
                    .ok_or_else(|| miss("`tool_mm`".into()))?;
                own()?
                    .pos_mm
                    .iter()
                    .zip(tool.iter())
                    .map(|(x, h)| urad_per_mm * x * h * 1e-3)
                    .collect()
            }
            Self::ThermalDrift { sensor, um_per_k } => {
                rise(temp(sensor)?).map(|d| um_per_k * d).collect()
            }
            Self::ThermalLag {
                sensor,
                tau_s,
                um_per_k,
            } => {
                let tt = temp(sensor)?;
                let t0 = tt.first().copied().unwrap_or(0.0);
                lowpass(&ctx.t_s, tt, *tau_s)
                    .iter()
                    .map(|y| um_per_k * (y - t0))
                    .collect()
            }
            Self::ThermalExpansion { sensor, ppm_per_k } => {
                let f = own()?;
                rise(temp(sensor)?)
                    .zip(f.pos_mm.iter())
                    .map(|(d, x)| ppm_per_k * 1e-3 * x * d)
                    .collect()
            }
            Self::ForceDeflection { channel, um_per_n } => ctx
                .load(channel)
                .ok_or_else(|| miss(format!("`{channel}`")))?
                .iter()
                .map(|f| um_per_n * f)
                .collect(),
            Self::ServoLag { ms } => own()?.vel_mm_s().iter().map(|v| -ms * v).collect(),
            Self::ReversalSpike {
                amplitude_um,
                decay_mm,
            } => {
                let f = own()?;
                f.dir
                    .iter()
                    .zip(&f.dist_since_rev_mm())
                    .map(|(&d, s)| amplitude_um * f64::from(d) * (-s / decay_mm).exp())
                    .collect()
            }
            Self::TimeDrift { um_per_h } => ctx.t_s.iter().map(|t| um_per_h * t / 3600.0).collect(),
        })
    }
}

fn rise(t: &[f64]) -> impl Iterator<Item = f64> + '_ {
    let t0 = t.first().copied().unwrap_or(0.0);
    t.iter().map(move |v| v - t0)
}

/// Zone index of `x` for zone edges (the last zone includes its upper edge).
pub fn zone_of(edges_mm: &[f64], x: f64) -> Option<usize> {
    let k = edges_mm.len().checked_sub(1)?;
    if k == 0 || x < edges_mm[0] || x > edges_mm[k] {
        return None;
    }
    Some(edges_mm.windows(2).position(|w| x < w[1]).unwrap_or(k - 1))
}

#[cfg(test)]
mod tests {
    use super::*;
    use retrocomp_model::recording::Recording;

    fn ctx() -> Context {
        let rec = Recording::from_columns(vec![
            ("t_s".into(), vec![0.0, 3600.0, 7200.0]),
            ("x_mm".into(), vec![0.0, 100.0, 50.0]),
            ("ex_um".into(), vec![0.0; 3]),
            ("T_a_C".into(), vec![20.0, 21.0, 22.0]),
        ])
        .unwrap();
        Context::from_recording(&rec)
    }

    #[test]
    fn units_of_each_linear_model_are_as_documented() {
        let c = ctx();
        let ev = |m: EffectModel| m.evaluate('x', &c).unwrap();
        assert_eq!(
            ev(EffectModel::ScaleError { ppm: 10.0 }),
            vec![0.0, 1.0, 0.5]
        ); // 10 ppm of 100 mm = 1 µm
        assert_eq!(
            ev(EffectModel::Backlash { b_um: 4.0 }),
            vec![2.0, 2.0, -2.0]
        );
        assert_eq!(
            ev(EffectModel::ThermalExpansion {
                sensor: "T_a_C".into(),
                ppm_per_k: 10.0
            })[1],
            1.0
        );
        assert_eq!(
            ev(EffectModel::TimeDrift { um_per_h: 3.0 }),
            vec![0.0, 3.0, 6.0]
        );
        // 2 ms × 100 mm / 3600 s (row 0 moves: one-sided difference at the run's start) in µm.
        assert_eq!(
            ev(EffectModel::ServoLag { ms: 2.0 })[0],
            -2.0 * 100.0 / 3600.0
        );
        let miss = EffectModel::Abbe { urad_per_mm: 1.0 }
            .evaluate('x', &c)
            .unwrap_err();
        assert_eq!(miss.what, "`tool_mm`");
    }

    #[test]
    fn json_uses_contract_names() {
        let m = EffectModel::ThermalLag {
            sensor: "T_s_C".into(),
            tau_s: 600.0,
            um_per_k: 2.0,
        };
        let j = serde_json::to_value(&m).unwrap();
        assert_eq!(j["effect"], "thermal_lag");
        assert_eq!(j["params"]["um_per_K"], 2.0);
        assert_eq!(j["params"]["tau_s"], 600.0);
        let back: EffectModel = serde_json::from_value(j).unwrap();
        assert_eq!(back, m);
        assert_eq!(zone_of(&[0.0, 10.0, 20.0], 20.0), Some(1));
        assert_eq!(zone_of(&[0.0, 10.0, 20.0], 10.0), Some(1));
        assert_eq!(zone_of(&[0.0, 10.0, 20.0], 25.0), None);
    }
}
