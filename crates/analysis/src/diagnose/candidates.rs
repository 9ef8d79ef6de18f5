//! The candidate library: for one error signal (axis `a`), every effect id of docs/diagnose-json.md that the
//! recording's channels allow, as regressor columns whose least-squares coefficients ARE the effect's
//! linear parameters in contract units (µm per column unit). Nonlinear parameters (τ, period, decay
//! length) are a scalar `theta` searched on `grid` (profile) and then refined.

mod periods;

use super::effects::EffectModel;
use super::features::{AxisFeatures, Context};
#[cfg(test)]
pub(crate) use periods::SWEEP_CHUNK;
pub use periods::{MIN_PITCH_MM, shortest_period};
use periods::{cyclic_columns, period_grid};
use retrocomp_model::recording::AXES;

/// Number of equal zones of a `reversal_profile` over the axis' travel.
pub const REVERSAL_ZONES: usize = 4;

/// Fewest rows read at a steady commanded feed ([`steady_rows`]) for `servo_lag` to be a
/// candidate (a handful cannot separate a velocity term from the direction or position terms).
pub const MIN_MOVING_ROWS: usize = 8;

#[derive(Clone, Debug, PartialEq)]
pub enum Kind {
    Scale,
    Backlash,
    ReversalProfile {
        edges_mm: Vec<f64>,
    },
    Cyclic,
    /// A cyclic error with its second harmonic: one fundamental period, two sin/cos pairs (a
    /// lead-screw pitch error is rarely a pure sine; its harmonic alone can alias to a false period).
    CyclicHarmonic,
    Squareness {
        other: char,
    },
    Straightness {
        along: char,
        mid_mm: f64,
    },
    Abbe,
    ThermalDrift {
        sensor: String,
    },
    ThermalLag {
        sensor: String,
    },
    ThermalExpansion {
        sensor: String,
    },
    Force {
        channel: String,
    },
    ServoLag,
    ReversalSpike,
    TimeDrift,
}

#[derive(Clone, Debug)]
pub struct Candidate {
    /// Axis of the error signal this candidate explains.
    pub axis: char,
    pub kind: Kind,
    /// Profile grid of the nonlinear parameter (empty: the candidate is linear).
    pub grid: Vec<f64>,
}

impl Candidate {
    pub fn effect_id(&self) -> &'static str {
        self.to_model(&[0.0; REVERSAL_ZONES], 1.0).id()
    }

    /// A short human label, e.g. `thermal_lag(T_spindle_C)`.
    pub fn label(&self) -> String {
        let id = self.effect_id();
        match &self.kind {
            Kind::ThermalDrift { sensor }
            | Kind::ThermalLag { sensor }
            | Kind::ThermalExpansion { sensor } => {
                format!("{id}({sensor})")
            }
            Kind::Force { channel } => format!("{id}({channel})"),
            Kind::Squareness { other } => format!("{id}(vs {other})"),
            Kind::Straightness { along, .. } => format!("{id}(along {along})"),
            _ => id.to_string(),
        }
    }

    /// Ambiguity is only reported between candidates of different families: a reversal family
    /// (backlash ⊂ reversal_profile, reversal_spike) and a thermal-offset family (drift = lag with τ→0)
    /// are nested forms of one physics, ranked by ΔBIC instead.
    pub fn family(&self) -> &'static str {
        match self.kind {
            Kind::Backlash | Kind::ReversalProfile { .. } | Kind::ReversalSpike => "reversal",
            Kind::ThermalDrift { .. } | Kind::ThermalLag { .. } => "thermal_offset",
            _ => self.effect_id(),
        }
    }

    /// Whether its columns follow a context column that changes over the recording (a
    /// temperature, `rpm`, a force, time itself) rather than position and direction alone. Only
    /// such a term can be judged by how it predicts later rows from earlier ones: a geometric
    /// term is estimable from the early rows only if they visit its positions and directions
    /// (a forward pass recorded before the reverse one does not).
    pub fn follows_context(&self) -> bool {
        matches!(
            self.kind,
            Kind::ThermalDrift { .. }
                | Kind::ThermalLag { .. }
                | Kind::ThermalExpansion { .. }
                | Kind::Force { .. }
                | Kind::TimeDrift
        )
    }

    /// A cyclic error (with or without its second harmonic).
    pub fn is_cyclic(&self) -> bool {
        matches!(self.kind, Kind::Cyclic | Kind::CyclicHarmonic)
    }

    pub fn is_nonlinear(&self) -> bool {
        !self.grid.is_empty()
    }

    /// A thermal lag's column at each time constant of `taus_s` (s): the sensor's reading
    /// through the first-order lag ([`super::features::lowpass`], started at the first reading)
    /// minus the first reading, °C (or the driver's unit). Empty for other candidates.
    pub fn lag_columns(&self, ctx: &Context, taus_s: &[f64]) -> Vec<Vec<f64>> {
        let Kind::ThermalLag { sensor } = &self.kind else {
            return vec![];
        };
        let t = ctx.temp(sensor).expect("listed");
        retrocomp_model::lag::series_each(&ctx.t_s, t, taus_s, t[0], t[0])
    }

    /// Regressor columns at nonlinear parameter `theta` (ignored by linear candidates).
    pub fn columns(&self, ctx: &Context, theta: f64) -> Vec<Vec<f64>> {
        let own = || {
            ctx.axis(self.axis)
                .expect("library only lists candidates whose inputs exist")
        };
        let rise = |s: &str| {
            let t = ctx.temp(s).expect("listed");
            let t0 = t[0];
            t.iter().map(move |v| v - t0)
        };
        match &self.kind {
            Kind::Scale => vec![own().pos_mm.iter().map(|x| x * 1e-3).collect()],
            Kind::Backlash => vec![own().dir.iter().map(|&d| f64::from(d) / 2.0).collect()],
            Kind::ReversalProfile { edges_mm } => reversal_zone_columns(own(), edges_mm),
            Kind::Cyclic => cyclic_columns(own(), theta),
            Kind::CyclicHarmonic => {
                let mut cols = cyclic_columns(own(), theta);
                cols.extend(cyclic_columns(own(), theta / 2.0));
                cols
            }
            Kind::Squareness { other } => {
                vec![
                    ctx.axis(*other)
                        .expect("listed")
                        .pos_mm
                        .iter()
                        .map(|y| y * 1e-3)
                        .collect(),
                ]
            }
            Kind::Straightness { along, mid_mm } => {
                vec![
                    ctx.axis(*along)
                        .expect("listed")
                        .pos_mm
                        .iter()
                        .map(|y| (y - mid_mm).powi(2))
                        .collect(),
                ]
            }
            Kind::Abbe => {
                let tool = ctx.tool_mm.as_ref().expect("listed");
                vec![
                    own()
                        .pos_mm
                        .iter()
                        .zip(tool.iter())
                        .map(|(x, h)| x * h * 1e-3)
                        .collect(),
                ]
            }
            Kind::ThermalDrift { sensor } => vec![rise(sensor).collect()],
            Kind::ThermalLag { .. } => self.lag_columns(ctx, &[theta]),
            Kind::ThermalExpansion { sensor } => {
                vec![
                    rise(sensor)
                        .zip(own().pos_mm.iter())
                        .map(|(d, x)| x * 1e-3 * d)
                        .collect(),
                ]
            }
            Kind::Force { channel } => vec![ctx.load(channel).expect("listed").to_vec()],
            Kind::ServoLag => vec![own().vel_mm_s().iter().map(|v| -v).collect()],
            Kind::ReversalSpike => {
                let f = own();
                vec![spike_column(&f.dir, &f.dist_since_rev_mm(), theta)]
            }
            Kind::TimeDrift => vec![ctx.t_s.iter().map(|t| t / 3600.0).collect()],
        }
    }

    /// The effect model for fitted column coefficients `c` (µm per column unit) at `theta`.
    pub fn to_model(&self, c: &[f64], theta: f64) -> EffectModel {
        match &self.kind {
            Kind::Scale => EffectModel::ScaleError { ppm: c[0] },
            Kind::Backlash => EffectModel::Backlash { b_um: c[0] },
            Kind::ReversalProfile { edges_mm } => EffectModel::ReversalProfile {
                edges_mm: edges_mm.clone(),
                b_um: c[..REVERSAL_ZONES].to_vec(),
            },
            Kind::Cyclic => EffectModel::CyclicError {
                period_mm: theta,
                amplitude_um: c[0].hypot(c[1]),
                // a·sin + b·cos = A·sin(· + φ) with A·cos φ = a, A·sin φ = b.
                phase_rad: c[1].atan2(c[0]),
                harmonic2_um: 0.0,
                harmonic2_phase_rad: 0.0,
            },
            Kind::CyclicHarmonic => EffectModel::CyclicError {
                period_mm: theta,
                amplitude_um: c[0].hypot(c[1]),
                phase_rad: c[1].atan2(c[0]),
                harmonic2_um: c[2].hypot(c[3]),
                harmonic2_phase_rad: c[3].atan2(c[2]),
            },
            Kind::Squareness { other } => EffectModel::Squareness {
                other_axis: *other,
                urad: c[0],
            },
            Kind::Straightness { along, mid_mm } => EffectModel::Straightness {
                along_axis: *along,
                mid_mm: *mid_mm,
                c2_um_per_mm2: c[0],
            },
            Kind::Abbe => EffectModel::Abbe { urad_per_mm: c[0] },
            Kind::ThermalDrift { sensor } => EffectModel::ThermalDrift {
                sensor: sensor.clone(),
                um_per_k: c[0],
            },
            Kind::ThermalLag { sensor } => EffectModel::ThermalLag {
                sensor: sensor.clone(),
                tau_s: theta,
                um_per_k: c[0],
            },
            Kind::ThermalExpansion { sensor } => EffectModel::ThermalExpansion {
                sensor: sensor.clone(),
                ppm_per_k: c[0],
            },
            Kind::Force { channel } => EffectModel::ForceDeflection {
                channel: channel.clone(),
                um_per_n: c[0],
            },
            Kind::ServoLag => EffectModel::ServoLag { ms: c[0] },
            Kind::ReversalSpike => EffectModel::ReversalSpike {
                amplitude_um: c[0],
                decay_mm: theta,
            },
            Kind::TimeDrift => EffectModel::TimeDrift { um_per_h: c[0] },
        }
    }
}

/// A reversal spike's column at decay length `decay_mm`: the latched direction (±1, 0) times
/// e^(−s/decay) of the distance since the reversal `dist_mm` (mm).
pub(super) fn spike_column(dir: &[i8], dist_mm: &[f64], decay_mm: f64) -> Vec<f64> {
    dir.iter()
        .zip(dist_mm)
        .map(|(&d, s)| f64::from(d) * (-s / decay_mm).exp())
        .collect()
}

fn range(v: &[f64]) -> (f64, f64) {
    v.iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| {
            (lo.min(x), hi.max(x))
        })
}

fn varies(v: &[f64]) -> bool {
    let (lo, hi) = range(v);
    hi - lo > 1e-9
}

/// Log-spaced grid from `lo` to `hi` with ratio `r` between neighbours.
pub fn log_grid(lo: f64, hi: f64, r: f64) -> Vec<f64> {
    let mut g = vec![];
    let mut v = lo;
    while v <= hi * (1.0 + 1e-12) {
        g.push(v);
        v *= r;
    }
    g
}

/// Every candidate for the error signal of axis `a` that the context supports.
pub fn library(ctx: &Context, a: char) -> Vec<Candidate> {
    let lin = |kind| Candidate {
        axis: a,
        kind,
        grid: vec![],
    };
    let mut out = vec![];
    let duration_s =
        ctx.t_s.last().copied().unwrap_or(0.0) - ctx.t_s.first().copied().unwrap_or(0.0);
    if let Some(f) = ctx.axis(a).filter(|f| varies(&f.pos_mm)) {
        out.extend(own_axis_candidates(ctx, a, f));
    }
    for o in AXES.iter().copied().filter(|&o| o != a) {
        if let Some(f) = ctx.axis(o).filter(|f| varies(&f.pos_mm)) {
            let (lo, hi) = range(&f.pos_mm);
            out.push(lin(Kind::Squareness { other: o }));
            out.push(lin(Kind::Straightness {
                along: o,
                mid_mm: 0.5 * (lo + hi),
            }));
        }
    }
    for (s, t) in &ctx.temps {
        if varies(t) {
            out.push(lin(Kind::ThermalDrift { sensor: s.clone() }));
            if duration_s > 60.0 {
                let g = log_grid(30.0, (duration_s / 2.0).max(60.0), 1.3);
                out.push(Candidate {
                    axis: a,
                    kind: Kind::ThermalLag { sensor: s.clone() },
                    grid: g,
                });
            }
        }
    }
    // Heat sources seen without a temperature sensor: a driver column (rpm, or any other numeric
    // column, which may be a decoy) through a first-order lag; other columns also as they are.
    // A power of a driver (`krpm^2` = (rpm/1000)², heat ∝ n²; `<name>_A^2`, Joule heat ∝ I²)
    // only through a lag, like rpm.
    if duration_s > 60.0 {
        for (s, v) in ctx.drivers() {
            if varies(v) {
                if s != "rpm" && super::features::power_of(s).is_none() {
                    out.push(lin(Kind::ThermalDrift { sensor: s.into() }));
                }
                out.push(Candidate {
                    axis: a,
                    kind: Kind::ThermalLag { sensor: s.into() },
                    grid: log_grid(30.0, (duration_s / 2.0).max(60.0), 1.3),
                });
            }
        }
    }
    for (c, v) in &ctx.loads {
        if varies(v) {
            out.push(lin(Kind::Force { channel: c.clone() }));
        }
    }
    if duration_s > 0.0 {
        out.push(lin(Kind::TimeDrift));
    }
    out
}

/// The candidates of the signal's own axis `a` (moving: `f` its features): scale, backlash,
/// reversal profile, cyclic error, Abbe, servo lag, reversal spike, thermal expansion.
fn own_axis_candidates(ctx: &Context, a: char, f: &AxisFeatures) -> Vec<Candidate> {
    let lin = |kind| Candidate {
        axis: a,
        kind,
        grid: vec![],
    };
    let mut out = vec![];
    let (lo, hi) = range(&f.pos_mm);
    let travel = hi - lo;
    out.push(lin(Kind::Scale));
    out.push(lin(Kind::Backlash));
    let edges_mm = (0..=REVERSAL_ZONES)
        .map(|k| lo + travel * k as f64 / REVERSAL_ZONES as f64)
        .collect();
    out.push(lin(Kind::ReversalProfile { edges_mm }));
    let grid = period_grid(travel, shortest_period(&f.distinct_mm));
    out.push(Candidate {
        axis: a,
        kind: Kind::Cyclic,
        grid: grid.clone(),
    });
    out.push(Candidate {
        axis: a,
        kind: Kind::CyclicHarmonic,
        grid,
    });
    if ctx.tool_mm.as_ref().is_some_and(|t| varies(t)) {
        out.push(lin(Kind::Abbe));
    }
    // Servo lag is a candidate only where the axis is read while moving at a commanded feed: its
    // column (velocity) is zero at every standstill row, and the rows between two dwells of a
    // step-and-dwell run are transients of a step, not readings at a feed (issue 36.6).
    if steady_rows(&f.vel_mm_s()) >= MIN_MOVING_ROWS {
        out.push(lin(Kind::ServoLag));
    }
    out.push(Candidate {
        axis: a,
        kind: Kind::ReversalSpike,
        grid: log_grid(travel / 500.0, travel / 5.0, 1.25),
    });
    for (s, t) in &ctx.temps {
        if varies(t) {
            out.push(lin(Kind::ThermalExpansion { sensor: s.clone() }));
        }
    }
    out
}

/// Rows read at a commanded feed: moving, between two rows moving the same way. A step-and-dwell
/// run has none when each step is sampled once or twice between its dwells (a transient, whatever
/// the sampling rate); a scan or a contour at a feed has one per row of its moving parts (timing
/// jitter does not matter: only the signs are read).
pub fn steady_rows(vel_mm_s: &[f64]) -> usize {
    vel_mm_s
        .windows(3)
        .filter(|w| w[1] != 0.0 && w[0] * w[1] > 0.0 && w[2] * w[1] > 0.0)
        .count()
}

/// The experiment that would separate two candidate families the data cannot tell apart.
pub fn separating_experiment(a: &str, b: &str) -> String {
    let has = |x: &str| a.contains(x) || b.contains(x);
    if has("abbe") {
        "repeat the run with a second tool length (different Abbe arm)".into()
    } else if has("thermal")
        && (has("scale_error") || has("time_drift") || has("thermal_expansion"))
    {
        "a cool-down run: stop the heat source and repeat the bidirectional travel while the temperature falls".into()
    } else if has("scale_error") && has("thermal_expansion") {
        "measure the axis at two clearly different temperatures (cold start and warm)".into()
    } else if has("servo_lag") {
        "a step-and-dwell run with readings at standstill, or the same run at a second feed rate"
            .into()
    } else if has("reversal") || has("backlash") {
        "a bidirectional run with reversals spread over the whole travel".into()
    } else if has("force") {
        "an air-cut pass (same path without load) next to the loaded pass".into()
    } else {
        "a run that moves each axis over its full travel at a different time and temperature".into()
    }
}

impl Candidate {
    /// Contract name of the parameter each linear coefficient estimates (`b_um` for every zone of a
    /// reversal profile; cyclic coefficients are the sin/cos parts of `amplitude_um`).
    pub fn coef_key(&self) -> &'static str {
        match self.kind {
            Kind::Scale => "ppm",
            Kind::Backlash | Kind::ReversalProfile { .. } => "b_um",
            Kind::Cyclic | Kind::CyclicHarmonic | Kind::ReversalSpike => "amplitude_um",
            Kind::Squareness { .. } => "urad",
            Kind::Straightness { .. } => "c2_um_per_mm2",
            Kind::Abbe => "urad_per_mm",
            Kind::ThermalDrift { .. } | Kind::ThermalLag { .. } => "um_per_K",
            Kind::ThermalExpansion { .. } => "ppm_per_K",
            Kind::Force { .. } => "um_per_N",
            Kind::ServoLag => "ms",
            Kind::TimeDrift => "um_per_h",
        }
    }

    /// Contract name of the nonlinear parameter, if any.
    pub fn theta_key(&self) -> Option<&'static str> {
        match self.kind {
            Kind::Cyclic | Kind::CyclicHarmonic => Some("period_mm"),
            Kind::ThermalLag { .. } => Some("tau_s"),
            Kind::ReversalSpike => Some("decay_mm"),
            _ => None,
        }
    }
}

/// Reversal profile: per position zone (`edges_mm`), half the latched direction (±½) inside the
/// zone, 0 outside.
fn reversal_zone_columns(f: &AxisFeatures, edges_mm: &[f64]) -> Vec<Vec<f64>> {
    (0..REVERSAL_ZONES)
        .map(|k| {
            f.pos_mm
                .iter()
                .zip(&f.dir)
                .map(|(x, d)| {
                    if super::effects::zone_of(edges_mm, *x) == Some(k) {
                        f64::from(*d) / 2.0
                    } else {
                        0.0
                    }
                })
                .collect()
        })
        .collect()
}

#[cfg(test)]
mod tests;
