//! hil-sim measures artefacts: hole-plate placements and static ball-bar spheres probed on the
//! hidden machine (a machine model, all 21 components, evaluated exactly), written in the contracts
//! of `retrocomp identify` (docs/identify.md). Deterministic per seed: every artefact draws from its
//! own named stream.
//!
//! What the simulated metrology does (µm, mm, °C):
//! - plate: certified centres = true centres + certificate error; placed with a random in-plane
//!   offset (±2 mm) and rotation (±3 mrad) and a small tilt (±0.3 mrad); at a plate temperature
//!   20 ± 1.5 °C (α = 11.5 ppm/K) and scale temperatures 20 ± 1 °C (α = 10 ppm/K); each hole probed
//!   twice (`repeat` 0/1) with probing noise; occasionally one probing gets a 13–15 µm pulse.
//! - ball bar (`spheres.rs`): sphere centre off its nominal by ±0.5 mm, bar at 20 ± 1 °C
//!   (α = 11.5 ppm/K), points on rings from the pole to 20° below the equator inside the travel,
//!   dr with probing noise.
//!
//! The machine reads r where the tool tip r + e(r) sits on the hole (e = actual − nominal, exact
//! model, approach direction unknown = mean of the two directions), solved by fixed-point iteration.

use std::path::Path;

use retrocomp_analysis::identify::contracts::{BallBar, HolePlate, HoleProbe, Plane, REFERENCE_C};
use retrocomp_model::{MachineModel, ModelInput, ModelState};

use crate::rng::Noise;

mod lead;
mod spheres;
pub use lead::*;
pub use spheres::*;

/// Noise and misalignment of the simulated metrology.
#[derive(Debug, Clone, PartialEq)]
pub struct Metrology {
    pub probing_noise_um: f64,
    pub certificate_uncertainty_um: f64,
    /// Chance that a probing is hit by a lubrication pulse.
    pub outlier_rate: f64,
    pub plate_alpha_ppm_per_k: f64,
    pub scale_alpha_ppm_per_k: f64,
}

impl Default for Metrology {
    fn default() -> Self {
        Metrology {
            probing_noise_um: 0.5,
            certificate_uncertainty_um: 0.1,
            outlier_rate: 0.01,
            plate_alpha_ppm_per_k: 11.5,
            scale_alpha_ppm_per_k: 10.0,
        }
    }
}

/// Where a plate goes: plate (0, 0) at `origin_mm`, holes `n[0]`×`n[1]` at `pitch_mm` along u, v.
/// One measurement (one CSV); two measurements of one `placement` with different probes share the
/// plate's pose and temperature (the plate stays put while the probe is changed), not the noise.
#[derive(Debug, Clone, PartialEq)]
pub struct PlatePlacement {
    /// The measurement's name (the CSV's stem).
    pub name: String,
    /// The physical placement: its pose and temperatures are drawn from this name's stream.
    pub placement: String,
    pub plane: Plane,
    pub origin_mm: [f64; 3],
    pub tool_mm: f64,
    pub n: [usize; 2],
    pub pitch_mm: [f64; 2],
}

fn plate(
    name: &str,
    plane: Plane,
    o: [f64; 3],
    tool: f64,
    n: [usize; 2],
    pitch: [f64; 2],
) -> PlatePlacement {
    PlatePlacement {
        name: name.into(),
        placement: name.into(),
        plane,
        origin_mm: o,
        tool_mm: tool,
        n,
        pitch_mm: pitch,
    }
}

/// The two probe configurations of the identification plates, mm along the tool axis.
pub const ID_PROBES_MM: [f64; 2] = [50.0, 300.0];
/// The probe lengths of the verification plates: a short and a long one, outside `ID_PROBES_MM`.
pub const VERIFY_PROBES_MM: [f64; 2] = [25.0, 400.0];

/// Which identification plan `hil-sim artefacts` probes (both on an 800 × 500 × 500 mm mill, 10 × 10
/// holes per plate).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Plan {
    /// Spaan's six hole-plate measurements (Ch3: "three different locations … measured with two
    /// different probe configurations"; "two in the XZ-plane, two in the XY-plane and two in the
    /// YZ-plane"): one placement per plane, in the middle of the travel across the plane, each
    /// probed with both probes (50 and 300 mm) — six measurements, about 2 h of probing.
    #[default]
    Six,
    /// The six plus a seventh: a second XZ placement at the back of the Y travel (y = 400 mm,
    /// 300 mm probe). Pins the one combination six measurements cannot see (see
    /// [`spaan_plates_for`]).
    Seven,
    /// Twelve measurements: six placements, two per plane at two places across the plane, each
    /// probed with both probes (the plan before six was the default). Pins it too.
    Twelve,
}

/// A placement of a plan: name, plane, origin (mm), holes, pitch (mm).
type Place = (&'static str, Plane, [f64; 3], [usize; 2], [f64; 2]);

/// The identification plates of `plan` and the five verification plates.
///
/// What a plate sees is only what is not a rigid in-plane motion. With the tool along Z, the
/// linear parts of table roll EAX and Y pitch EBY (equal), Z pitch EBZ and squareness EB0Z form
/// one combination that is rigid on every XY and YZ plate, and rigid on an XZ plate whose
/// (y, probe length) satisfies one linear equation: two XZ measurements — all that six
/// measurements give — always satisfy it, so the combination stays unseen and XZ plates at other
/// y / probe lengths see what the model guesses there. Six measurements put the XZ plate in the
/// middle of the Y travel, which halves the largest lever of that guess; a seventh measurement, a
/// second XZ placement elsewhere in Y, pins it (so does the twelve-measurement plan). Both probes
/// on every placement also give the Z roll EAZ a 250 mm Abbe arm difference on the YZ plates (with
/// 100/200 mm probes on separate placements it was 3.6 µrad off, all of it noise). Verification
/// plates: five at other places with probe lengths outside the identification's (25 and 400 mm),
/// so the Abbe terms extrapolate.
pub fn spaan_plates_for(plan: Plan) -> (Vec<PlatePlacement>, Vec<PlatePlacement>) {
    use Plane::*;
    let (wide, square) = ([10, 10], [10, 10]);
    let six: &[Place] = &[
        ("id_xy", Xy, [130.0, 50.0, 150.0], wide, [60.0, 40.0]),
        ("id_xz", Xz, [130.0, 225.0, 50.0], wide, [60.0, 40.0]),
        ("id_yz", Yz, [375.0, 50.0, 50.0], square, [40.0, 40.0]),
    ];
    let places: &[Place] = match plan {
        Plan::Six | Plan::Seven => six,
        Plan::Twelve => &[
            ("id_xy_low", Xy, [130.0, 50.0, 50.0], wide, [60.0, 40.0]),
            ("id_xy_high", Xy, [130.0, 50.0, 300.0], wide, [60.0, 40.0]),
            ("id_xz_front", Xz, [130.0, 100.0, 50.0], wide, [60.0, 40.0]),
            ("id_xz_back", Xz, [130.0, 350.0, 50.0], wide, [60.0, 40.0]),
            ("id_yz_left", Yz, [150.0, 50.0, 50.0], square, [40.0, 40.0]),
            ("id_yz_right", Yz, [600.0, 50.0, 50.0], square, [40.0, 40.0]),
        ],
    };
    let mut id: Vec<PlatePlacement> = places
        .iter()
        .flat_map(|&(name, plane, o, n, pitch)| {
            ID_PROBES_MM.map(|t| PlatePlacement {
                name: format!("{name}_t{t:.0}"),
                ..plate(name, plane, o, t, n, pitch)
            })
        })
        .collect();
    if plan == Plan::Seven {
        id.push(PlatePlacement {
            name: "id_xz_back_t300".into(),
            ..plate(
                "id_xz_back",
                Xz,
                [130.0, 400.0, 50.0],
                ID_PROBES_MM[1],
                wide,
                [60.0, 40.0],
            )
        });
    }
    // Probe lengths outside the identification's, so the Abbe terms must extrapolate.
    let verify = vec![
        plate(
            "v_xy",
            Xy,
            [220.0, 50.0, 150.0],
            VERIFY_PROBES_MM[1],
            square,
            [40.0, 40.0],
        ),
        plate(
            "v_xz_short",
            Xz,
            [300.0, 250.0, 120.0],
            VERIFY_PROBES_MM[0],
            square,
            [30.0, 30.0],
        ),
        plate(
            "v_xz_long",
            Xz,
            [150.0, 200.0, 50.0],
            VERIFY_PROBES_MM[1],
            wide,
            [55.0, 40.0],
        ),
        plate(
            "v_yz_left",
            Yz,
            [250.0, 50.0, 50.0],
            VERIFY_PROBES_MM[1],
            square,
            [40.0, 40.0],
        ),
        plate(
            "v_yz_right",
            Yz,
            [650.0, 50.0, 50.0],
            VERIFY_PROBES_MM[0],
            square,
            [40.0, 40.0],
        ),
    ];
    (id, verify)
}

/// Two more XZ plates, at the front and back ends of the Y travel (y = 30 and 460 mm, probes 25 and
/// 400 mm): where the combination six measurements cannot see shows most (tests only; Spaan's
/// five verification plates are `spaan_plates_for(..).1`).
pub fn xz_edge_plates() -> Vec<PlatePlacement> {
    [("v_xz_front_edge", 30.0, 0), ("v_xz_back_edge", 460.0, 1)]
        .into_iter()
        .map(|(name, y, k)| {
            plate(
                name,
                Plane::Xz,
                [150.0, y, 50.0],
                VERIFY_PROBES_MM[k],
                [10, 10],
                [55.0, 40.0],
            )
        })
        .collect()
}

/// The default plan's plates ([`Plan::Six`]).
pub fn spaan_plates() -> (Vec<PlatePlacement>, Vec<PlatePlacement>) {
    spaan_plates_for(Plan::default())
}

/// The hidden machine, evaluated exactly at reference temperatures.
#[derive(Debug)]
pub struct Probe<'a> {
    model: &'a MachineModel,
    state: ModelState,
    input: ModelInput,
    out: retrocomp_model::ErrorBreakdown,
}

impl<'a> Probe<'a> {
    pub fn new(model: &'a MachineModel) -> Self {
        Probe {
            state: model.new_state(),
            input: model.new_input(),
            out: model.new_breakdown(),
            model,
        }
    }

    /// Tool-tip error (µm) at machine position r with a probe `tool_mm` long.
    pub fn error_um(&mut self, r: [f64; 3], tool_mm: f64) -> [f64; 3] {
        self.input.pos_mm = r;
        self.input.dir = [0; 3];
        self.input.tool_mm = Some(tool_mm);
        self.model
            .evaluate(&self.input, &mut self.state, &mut self.out);
        self.out.total_um
    }

    /// The nominal position r at which the actual tip r + e(r) is at `h_mm`.
    pub fn position_for(&mut self, h_mm: [f64; 3], tool_mm: f64) -> [f64; 3] {
        let mut r = h_mm;
        for _ in 0..4 {
            let e = self.error_um(r, tool_mm);
            r = std::array::from_fn(|k| h_mm[k] - e[k] * 1e-3);
        }
        r
    }
}

pub(crate) fn scale_reading(r: [f64; 3], t: [f64; 3], alpha: f64) -> [f64; 3] {
    std::array::from_fn(|k| r[k] / (1.0 + alpha * 1e-6 * (t[k] - REFERENCE_C)))
}

/// Probes one plate placement.
pub fn measure_plate(
    truth: &MachineModel,
    pl: &PlatePlacement,
    m: &Metrology,
    seed: u64,
) -> HolePlate {
    let mut rng = Noise::new(seed, &format!("artefact/{}", pl.placement));
    let mut u = |lo: f64, hi: f64| lo + (hi - lo) * rng.uniform();
    let shift = [u(-2.0, 2.0), u(-2.0, 2.0)];
    let th = u(-3e-3, 3e-3);
    let tilt = [u(-3e-4, 3e-4), u(-3e-4, 3e-4)];
    let t_plate = REFERENCE_C + u(-1.5, 1.5);
    let t_scale = [0; 3].map(|_| REFERENCE_C + u(-1.0, 1.0));
    let mut rng = Noise::new(seed, &format!("artefact/{}/noise", pl.name));
    let [a, b] = pl.plane.axes();
    let c = 3 - a - b;
    let mut probe = Probe::new(truth);
    let mut probes = Vec::new();
    let k_plate = 1.0 + m.plate_alpha_ppm_per_k * 1e-6 * (t_plate - REFERENCE_C);
    for i in 0..pl.n[0] {
        for j in 0..pl.n[1] {
            let nominal = [i as f64 * pl.pitch_mm[0], j as f64 * pl.pitch_mm[1]];
            // Manufactured off grid by a few µm; the certificate knows it to its uncertainty.
            let made = nominal.map(|v| v + rng.gauss(2e-3));
            let cert = made.map(|v| v + rng.gauss(m.certificate_uncertainty_um * 0.5e-3));
            let hot = made.map(|v| v * k_plate);
            let (s, co) = th.sin_cos();
            let pu = co * hot[0] - s * hot[1] + shift[0];
            let pv = s * hot[0] + co * hot[1] + shift[1];
            let mut h = pl.origin_mm;
            h[a] += pu;
            h[b] += pv;
            h[c] += tilt[0] * hot[0] + tilt[1] * hot[1];
            let r = probe.position_for(h, pl.tool_mm);
            for repeat in 0..2 {
                let mut read = scale_reading(r, t_scale, m.scale_alpha_ppm_per_k);
                for k in [a, b] {
                    read[k] += rng.gauss(m.probing_noise_um) * 1e-3;
                }
                if rng.uniform() < m.outlier_rate {
                    let pulse = 13.0 + 2.0 * rng.uniform();
                    let k = if rng.uniform() < 0.5 { a } else { b };
                    read[k] += pulse * 1e-3;
                }
                probes.push(HoleProbe {
                    hole: format!("h{i}_{j}"),
                    uv_mm: cert,
                    pos_mm: read,
                    tool_mm: pl.tool_mm,
                    repeat,
                    t_plate_c: Some(t_plate),
                    t_scale_c: t_scale.map(Some),
                    line: 0,
                });
            }
        }
    }
    HolePlate {
        name: pl.name.clone(),
        plane: pl.plane,
        alpha_ppm_per_k: m.plate_alpha_ppm_per_k,
        certificate_uncertainty_um: m.certificate_uncertainty_um,
        scale_alpha_ppm_per_k: Some(m.scale_alpha_ppm_per_k),
        probes,
    }
}

/// The travel of the truth model's axes (0…800/500/500 where the model gives none).
pub fn travel(truth: &MachineModel) -> [(f64, f64); 3] {
    let mut t = [(0.0, 800.0), (0.0, 500.0), (0.0, 500.0)];
    for a in &truth.spec().axes {
        if let Some(r) = a.travel_mm {
            t[a.axis.index()] = r;
        }
    }
    t
}

/// Everything Spaan's way: identification plates, verification plates, spheres.
#[derive(Debug)]
pub struct Measured {
    pub plates: Vec<HolePlate>,
    pub verify: Vec<HolePlate>,
    pub spheres: Vec<BallBar>,
}

/// Everything with the default plan ([`Plan::Six`]).
pub fn measure_all(truth: &MachineModel, m: &Metrology, seed: u64) -> Measured {
    measure_plan(truth, m, seed, Plan::default())
}

/// Everything with `plan`'s identification plates.
pub fn measure_plan(truth: &MachineModel, m: &Metrology, seed: u64, plan: Plan) -> Measured {
    let (id, v) = spaan_plates_for(plan);
    let tr = travel(truth);
    Measured {
        plates: id
            .iter()
            .map(|p| measure_plate(truth, p, m, seed))
            .collect(),
        verify: v.iter().map(|p| measure_plate(truth, p, m, seed)).collect(),
        spheres: spaan_spheres()
            .iter()
            .map(|s| measure_sphere(truth, s, tr, m, seed))
            .collect(),
    }
}

/// Writes `<out>/plates/*.csv|toml`, `<out>/verify/…`, `<out>/ballbar/…`.
pub fn write_all(meas: &Measured, out: &Path) -> anyhow::Result<usize> {
    let mut n = 0;
    let mut put = |dir: &str, name: &str, (csv, side): (String, String)| -> anyhow::Result<()> {
        let d = out.join(dir);
        std::fs::create_dir_all(&d)?;
        std::fs::write(d.join(format!("{name}.csv")), csv)?;
        std::fs::write(d.join(format!("{name}.toml")), side)?;
        n += 1;
        Ok(())
    };
    for p in &meas.plates {
        put("plates", &p.name, p.to_texts())?;
    }
    for p in &meas.verify {
        put("verify", &p.name, p.to_texts())?;
    }
    for s in &meas.spheres {
        put("ballbar", &s.name, s.to_texts())?;
    }
    Ok(n)
}

/// The truth as a set of artefacts sampled it: every component replaced by the linear
/// interpolation of its values at `positions_mm[axis]` (the probed positions along that axis;
/// positions within 5 mm are merged, as one hole row probed from several placements), held
/// constant outside. What an identification from those artefacts can at best be: content shorter
/// than twice the spacing is not followed, and what of it the samples caught is aliased into
/// longer waves, as it is in the fit. Squareness and thermal terms unchanged.
pub fn resampled(truth: &MachineModel, positions_mm: &[Vec<f64>; 3]) -> MachineModel {
    use retrocomp_model::{ErrorFunction, Interpolation, Table};
    let nodes: Vec<Vec<f64>> = positions_mm
        .iter()
        .map(|p| {
            let mut p = p.clone();
            p.sort_by(f64::total_cmp);
            let mut groups: Vec<Vec<f64>> = Vec::new();
            for q in p {
                match groups.last_mut() {
                    Some(g) if q - g[0] <= 5.0 => g.push(q),
                    _ => groups.push(vec![q]),
                }
            }
            groups
                .iter()
                .map(|g| g.iter().sum::<f64>() / g.len() as f64)
                .collect()
        })
        .collect();
    let mut spec = truth.spec().clone();
    for c in &mut spec.components {
        let q = nodes[c.id.axis.index()].clone();
        if q.len() < 2 {
            continue;
        }
        let at = |dir: i8| -> Vec<f64> { q.iter().map(|&x| c.function.eval(x, dir).0).collect() };
        let (fwd, rev) = (at(1), at(-1));
        c.function = ErrorFunction::Table(Table::new(q, fwd, rev, Interpolation::Linear));
    }
    MachineModel::from_spec(spec)
}
