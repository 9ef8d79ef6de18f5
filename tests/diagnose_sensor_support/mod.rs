//! Generators of the issue 36 points 4 and 5 benchmark families, shared by the CI tests and the
//! full benchmark (`tests/diagnose/sensor.rs`). Thermal-only recordings (no axis column: `t_s`,
//! drivers, temperatures °C, `ez_um` actual − nominal µm with `sim_ez_um` = 0), one row every
//! 30 s; every draw comes from a ChaCha8 stream seeded by (family, seed, index).
//!
//! Sensor families (point 4): a spindle heated by `rpm` in steps (levels 0–6000 rpm, 1–3 h each);
//! `T_spindle_C` and `T_spindle_b_C` read the same spot (redundant pair, own noise 0.01 K),
//! `T_column_C` a slower node fed by the spindle and the room, `T_room_C` a slow day wave. Half
//! the cases hide physics driven by the (healthy) column node, `ez += g·(T_column − T_column(0))`
//! with g 0.5–3 µm/K at effect/noise 3–8; the other half are nulls (noise only). The fault is on
//! one column (drawn) from a time drawn in the first 70 %:
//!
//! * `stuck`: the reading freezes at its last value for 10–30 % of the recording;
//! * `open_circuit`: a PT100 open circuit, 850.0 °C (± a few tenths), for 1–10 % of the rows;
//! * `drifting`: one of the redundant pair drifts linearly to 1.5–4 K by the end;
//! * `disagreement`: one of the redundant pair comes loose for 10–30 % of the recording and reads
//!   the room plus 1–3 K (the air next to it) before it is fixed back;
//! * `healthy`: no fault (the false-alarm check).
//!
//! Power family (point 5): `motor_current_A` in steps over 4–6 distinct levels (0 and 3–25 A,
//! 45–150 min each, every level visited in a shuffled order before any is repeated); Joule heat ∝ I², `ez = g·(LPF_τ(I²) − I(0)²)` with τ 600–3600 s, g set for
//! effect/noise 4–10, plus a room wave `T_room_C` and a decoy `spindle_power_kW` that is a
//! random walk of its own.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use retrocomp_analysis::diagnose::features::lowpass;
use retrocomp_model::recording::Recording;

pub(crate) const DT_S: f64 = 30.0;

pub(crate) fn rng_for(family: u64, seed: u64, index: usize) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(
        seed ^ family.rotate_left(29) ^ (index as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15),
    )
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Fault {
    Healthy,
    Stuck,
    OpenCircuit,
    Drifting,
    Disagreement,
}

impl Fault {
    pub(crate) const ALL: [Fault; 5] = [
        Fault::Stuck,
        Fault::OpenCircuit,
        Fault::Drifting,
        Fault::Disagreement,
        Fault::Healthy,
    ];
    pub(crate) fn name(self) -> &'static str {
        match self {
            Fault::Healthy => "healthy",
            Fault::Stuck => "stuck",
            Fault::OpenCircuit => "open_circuit",
            Fault::Drifting => "drifting",
            Fault::Disagreement => "disagreement",
        }
    }
}

/// What a sensor case hides.
#[derive(Clone, Debug)]
pub(crate) struct SensorTruth {
    /// The faulted column and its window (rows, inclusive); `None` when healthy.
    pub(crate) column: Option<String>,
    pub(crate) rows: [usize; 2],
    /// Physics gain on `T_column_C` (µm/K); 0 for a null.
    pub(crate) gain_um_per_k: f64,
}

/// First-order lag step of `y` towards `u` over `DT_S`.
fn lag(y: &mut f64, u: f64, tau_s: f64) {
    *y += (1.0 - (-DT_S / tau_s).exp()) * (u - *y);
}

fn normal(rng: &mut ChaCha8Rng) -> f64 {
    rng.sample::<f64, _>(StandardNormal)
}

/// Step levels: `(level, rows)` until `n` rows, levels drawn from `levels`.
fn steps(rng: &mut ChaCha8Rng, n: usize, levels: &[f64], rows: (usize, usize)) -> Vec<f64> {
    let mut out = Vec::with_capacity(n);
    let mut last = f64::NAN;
    while out.len() < n {
        let mut l = levels[rng.random_range(0..levels.len())];
        while l == last {
            l = levels[rng.random_range(0..levels.len())];
        }
        last = l;
        let k = rng.random_range(rows.0..rows.1);
        out.extend(std::iter::repeat_n(l, k));
    }
    out.truncate(n);
    out
}

/// Steps of `(level, rows)` until `n` rows, visiting every level of `levels` in a shuffled
/// order before any level again (no level twice in a row).
fn visiting_steps(
    rng: &mut ChaCha8Rng,
    n: usize,
    levels: &[f64],
    rows: (usize, usize),
) -> Vec<f64> {
    let mut out: Vec<f64> = Vec::with_capacity(n);
    while out.len() < n {
        let mut order = levels.to_vec();
        for i in (1..order.len()).rev() {
            order.swap(i, rng.random_range(0..=i));
        }
        if out.last() == order.first() {
            order.rotate_left(1);
        }
        for l in order {
            let k = rng.random_range(rows.0..rows.1);
            out.extend(std::iter::repeat_n(l, k));
        }
    }
    out.truncate(n);
    out
}

/// Sensor case `index` of `seed` in family `fault`, `n` rows.
pub(crate) fn sensor_case(
    fault: Fault,
    seed: u64,
    index: usize,
    n: usize,
) -> (Recording, SensorTruth) {
    let mut rng = rng_for(0x5e45_0000 + fault as u64, seed, index);
    let rpm = steps(
        &mut rng,
        n,
        &[0.0, 1500.0, 3000.0, 4500.0, 6000.0],
        (120, 360),
    );
    let rise_per_krpm: f64 = rng.random_range(1.0..2.5);
    let tau_sp: f64 = rng.random_range(900.0..2400.0);
    let tau_col: f64 = rng.random_range(3000.0..8000.0);
    let day_s: f64 = rng.random_range(60_000.0..100_000.0);
    let phase: f64 = rng.random_range(0.0..std::f64::consts::TAU);
    let (mut sp, mut col) = (0.0, 0.0);
    let mut t_s = Vec::with_capacity(n);
    let mut cols: [Vec<f64>; 4] = Default::default();
    for (i, r) in rpm.iter().enumerate() {
        let t = i as f64 * DT_S;
        let room = 21.0 + 1.5 * (std::f64::consts::TAU * t / day_s + phase).sin();
        lag(&mut sp, rise_per_krpm * r / 1000.0, tau_sp);
        lag(&mut col, 0.4 * sp, tau_col);
        t_s.push(t);
        let spindle = room + sp;
        cols[0].push(spindle + 0.01 * normal(&mut rng));
        cols[1].push(spindle + 0.01 * normal(&mut rng));
        cols[2].push(room + col + 0.01 * normal(&mut rng));
        cols[3].push(room + 0.01 * normal(&mut rng));
    }
    let names = ["T_spindle_C", "T_spindle_b_C", "T_column_C", "T_room_C"];
    // Physics from the true column node (before any fault), or a null.
    let physics = index.is_multiple_of(2);
    let gain = if physics {
        rng.random_range(0.5..3.0) * if rng.random_bool(0.5) { 1.0 } else { -1.0 }
    } else {
        0.0
    };
    let c0 = cols[2][0];
    let effect: Vec<f64> = cols[2].iter().map(|c| gain * (c - c0)).collect();
    let sigma = if physics {
        rms_centered(&effect) / rng.random_range(3.0..8.0)
    } else {
        0.2
    };
    let e: Vec<f64> = effect
        .iter()
        .map(|v| v + sigma * normal(&mut rng))
        .collect();
    // The fault.
    let start = rng.random_range(n / 10..7 * n / 10);
    let share = |rng: &mut ChaCha8Rng, lo: f64, hi: f64| {
        ((rng.random_range(lo..hi) * n as f64) as usize).min(n - 1 - start)
    };
    let pair = rng.random_range(0..2usize);
    let (column, rows) = match fault {
        Fault::Healthy => (None, [0, 0]),
        Fault::Stuck => {
            let k = [0usize, 1, 2, 3][rng.random_range(0..4)];
            let len = share(&mut rng, 0.1, 0.3);
            let v = cols[k][start];
            cols[k][start..=start + len].fill(v);
            (Some(k), [start, start + len])
        }
        Fault::OpenCircuit => {
            let k = [0usize, 1, 2, 3][rng.random_range(0..4)];
            let len = share(&mut rng, 0.01, 0.1);
            for v in &mut cols[k][start..=start + len] {
                *v = 850.0 + 0.2 * normal(&mut rng);
            }
            (Some(k), [start, start + len])
        }
        Fault::Drifting => {
            let to: f64 =
                rng.random_range(1.5..4.0) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            let len = n - 1 - start;
            for (j, v) in cols[pair][start..].iter_mut().enumerate() {
                *v += to * j as f64 / len as f64;
            }
            (Some(pair), [start, n - 1])
        }
        Fault::Disagreement => {
            let len = share(&mut rng, 0.1, 0.3);
            let off: f64 = rng.random_range(1.0..3.0);
            let (twins, room) = cols.split_at_mut(3);
            for (v, r) in twins[pair][start..=start + len]
                .iter_mut()
                .zip(&room[0][start..=start + len])
            {
                *v = r + off + 0.01 * normal(&mut rng);
            }
            (Some(pair), [start, start + len])
        }
    };
    let mut named = vec![("t_s".to_string(), t_s), ("rpm".to_string(), rpm)];
    for (nm, c) in names.iter().zip(cols) {
        named.push(((*nm).to_string(), c));
    }
    named.push(("ez_um".into(), e));
    named.push(("sim_ez_um".into(), vec![0.0; n]));
    let rec = Recording::from_columns(named).expect("generated recording is valid");
    let truth = SensorTruth {
        column: column.map(|k| names[k].to_string()),
        rows,
        gain_um_per_k: gain,
    };
    (rec, truth)
}

/// What a current-squared case hides.
#[derive(Clone, Debug)]
pub(crate) struct PowerTruth {
    pub(crate) tau_s: f64,
    pub(crate) um_per_a2: f64,
    pub(crate) snr: f64,
}

/// Current-squared heating case `index` of `seed`, `n` rows.
pub(crate) fn current_squared_case(seed: u64, index: usize, n: usize) -> (Recording, PowerTruth) {
    let mut rng = rng_for(0x00a2_4ea7, seed, index);
    let mut levels: Vec<f64> = vec![0.0];
    let k = rng.random_range(3..6);
    while levels.len() <= k {
        let l = (rng.random_range(3.0..25.0_f64) * 10.0).round() / 10.0;
        if levels.iter().all(|v| (v - l).abs() > 2.0) {
            levels.push(l);
        }
    }
    let amps = visiting_steps(&mut rng, n, &levels, (90, 300));
    let tau_s: f64 = rng.random_range(600.0..3600.0);
    let snr: f64 = rng.random_range(4.0..10.0);
    let day_s: f64 = rng.random_range(60_000.0..100_000.0);
    let t_s: Vec<f64> = (0..n).map(|i| i as f64 * DT_S).collect();
    // The lag as docs/diagnose-json.md defines `thermal_lag` (LPF from the first reading).
    let sq: Vec<f64> = amps.iter().map(|a| a * a).collect();
    let heat: Vec<f64> = lowpass(&t_s, &sq, tau_s)
        .iter()
        .map(|y| y - sq[0])
        .collect();
    let um_per_a2 =
        0.02 * rng.random_range(0.5..2.0) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let effect: Vec<f64> = heat.iter().map(|h| um_per_a2 * h).collect();
    let sigma = rms_centered(&effect) / snr;
    let room: Vec<f64> = t_s
        .iter()
        .map(|t| 21.0 + (std::f64::consts::TAU * t / day_s).sin() + 0.01 * normal(&mut rng))
        .collect();
    let mut walk = 5.0;
    let decoy: Vec<f64> = (0..n)
        .map(|_| {
            walk += 0.05 * normal(&mut rng);
            walk
        })
        .collect();
    let e: Vec<f64> = effect
        .iter()
        .map(|v| v + sigma * normal(&mut rng))
        .collect();
    let rec = Recording::from_columns(vec![
        ("t_s".into(), t_s),
        ("motor_current_A".into(), amps),
        ("spindle_power_kW".into(), decoy),
        ("T_room_C".into(), room),
        ("ez_um".into(), e),
        ("sim_ez_um".into(), vec![0.0; n]),
    ])
    .expect("generated recording is valid");
    (
        rec,
        PowerTruth {
            tau_s,
            um_per_a2,
            snr,
        },
    )
}

fn rms_centered(v: &[f64]) -> f64 {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / v.len() as f64).sqrt()
}
