//! The floor: a hand-specialised evaluator of exactly `deploy/examples/vmc-3axis.toml`, kept as the
//! benchmark reference for `Plan::run` (issue 39, point 1).
//!
//! The numbers (tables, coefficients, time constants, tools) are read from the TOML through
//! [`MachineModel`] when the floor is built; the structure is written out here by hand: chain
//! X (workpiece) F Y Z (tool), 18 linear bidirectional tables in three blocks of six sharing their
//! positions, the three squareness entries, 16 sensors with fixed indices, the seven thermal terms
//! and three load terms of that file, and the exact 4×4 chain with its zero entries dropped.
//! [`Floor::new`] panics when the model is not shaped like that file.
//!
//! It gives `MachineModel::evaluate`'s breakdown (total, all 32 terms, the clamp and travel flags)
//! to 1e-12 µm (`crates/model/tests/model/floor.rs`): every sum is formed in the plan's order, so the
//! results are equal up to signed zeros. What it leaves out, and the plan pays for: the checks for
//! non-finite positions, times, temperatures, forces and strains (the floor assumes them finite),
//! missing channels and tool indices, sensors never read, and time going backwards (the floor's
//! caller keeps time moving forward).
//!
//! Shared by `benches/floor.rs`, `tests/model/floor.rs` and `examples/floor_count.rs` (`#[path]`).

#![allow(
    dead_code,
    reason = "each includer uses a different part (the test reads the flags, the bench does not)"
)]

use retrocomp_model::kinematics::rotation_about;
use retrocomp_model::{Axis, ErrorFunction, MachineModel, ModelInput, Table};
use retrocomp_model::{LoadKind, ThermalKind};

/// Sensors by index in the file: the thermal terms below address them by these numbers.
const SENSORS: [&str; 16] = [
    "spindle_front",
    "spindle_rear",
    "spindle_motor",
    "headstock",
    "column_front",
    "column_rear",
    "column_top",
    "base_left",
    "base_right",
    "table",
    "scale_x",
    "scale_y",
    "scale_z",
    "coolant",
    "ambient",
    "ballscrew_x",
];
const N_TERMS: usize = 32;

/// Six linear tables of one axis at shared positions: per direction slot (reverse, mean, forward),
/// per node, the six values δx δy δz εa εb εc.
#[derive(Debug)]
struct Block {
    x: Vec<f64>,
    inv_h: Vec<f64>,
    inv_mean_h: f64,
    rows: [Vec<[f64; 6]>; 3],
}

/// (segment i, fraction f, clamped) of q in nodes `x`: x_i ≤ q < x_{i+1}, the last segment up to
/// its end; outside (or NaN) the end node with f = 0 (i = n − 1 past the end).
#[inline(always)]
fn locate(x: &[f64], inv_h: &[f64], inv_mean_h: f64, q: f64) -> (usize, f64, bool) {
    let n = x.len();
    if q.is_nan() || q < x[0] {
        return (0, 0.0, true);
    }
    if q > x[n - 1] {
        return (n - 1, 0.0, true);
    }
    #[allow(
        clippy::cast_possible_truncation,
        clippy::cast_sign_loss,
        reason = "a guess, ≥ 0 since q ≥ x[0], kept in the table by min and corrected below"
    )]
    let mut i = (((q - x[0]) * inv_mean_h) as usize).min(n - 2);
    while x[i] > q {
        i -= 1;
    }
    while i < n - 2 && x[i + 1] <= q {
        i += 1;
    }
    (i, (q - x[i]) * inv_h[i], false)
}

fn inv_h(x: &[f64]) -> (Vec<f64>, f64) {
    let n = x.len();
    let inv = x.windows(2).map(|w| 1.0 / (w[1] - w[0])).collect();
    #[allow(clippy::cast_precision_loss, reason = "a node count")]
    let m = (n - 1) as f64 / (x[n - 1] - x[0]);
    (inv, m)
}

/// Per direction slot −1/0/+1: reverse, ½ forward + ½ reverse, forward (as the model weights them).
fn by_dir(f: &[f64], r: &[f64]) -> [Vec<f64>; 3] {
    [-1.0f64, 0.0, 1.0].map(|d| {
        let w = 0.5 * (1.0 + d);
        f.iter()
            .zip(r)
            .map(|(f, r)| w * f + (1.0 - w) * r)
            .collect()
    })
}

#[inline(always)]
fn slot(dir: i8) -> usize {
    usize::from((dir.signum() + 1).unsigned_abs())
}

impl Block {
    fn new(tables: &[&Table]) -> Block {
        let x = tables[0].positions_mm.clone();
        let (inv_h, inv_mean_h) = inv_h(&x);
        let per: Vec<[Vec<f64>; 3]> = tables
            .iter()
            .map(|t| by_dir(&t.forward, &t.reverse))
            .collect();
        let rows = std::array::from_fn(|s| {
            (0..x.len())
                .map(|i| std::array::from_fn(|m| per[m][s][i]))
                .collect()
        });
        Block {
            x,
            inv_h,
            inv_mean_h,
            rows,
        }
    }

    #[inline(always)]
    fn eval(&self, q: f64, dir: i8) -> ([f64; 6], bool) {
        let (i, f, cl) = locate(&self.x, &self.inv_h, self.inv_mean_h, q);
        let rows = &self.rows[slot(dir)];
        let a = rows[i];
        if cl {
            return (a, true);
        }
        let b = rows[i + 1];
        (std::array::from_fn(|s| a[s] + f * (b[s] - a[s])), false)
    }
}

/// A C¹ load table as one cubic in t ∈ [0, 1] per segment and direction slot.
#[derive(Debug)]
struct Cubic {
    x: Vec<f64>,
    inv_h: Vec<f64>,
    inv_mean_h: f64,
    cubic: [Vec<[f64; 4]>; 3],
    values: [Vec<f64>; 3],
}

impl Cubic {
    fn new(f: &ErrorFunction) -> Cubic {
        let ErrorFunction::Table(t) = f else {
            panic!("vmc-3axis: a C¹ load table expected")
        };
        let x = t.positions_mm.clone();
        let (inv_h, inv_mean_h) = inv_h(&x);
        let (mf, mr) = t.slopes();
        let values = by_dir(&t.forward, &t.reverse);
        let slopes = by_dir(&mf, &mr);
        let cubic = std::array::from_fn(|s| {
            let (v, m) = (&values[s], &slopes[s]);
            (0..v.len() - 1)
                .map(|i| {
                    let (va, vb) = (v[i], v[i + 1]);
                    let h = x[i + 1] - x[i];
                    let (hma, hmb) = (h * m[i], h * m[i + 1]);
                    [
                        va,
                        hma,
                        3.0 * (vb - va) - 2.0 * hma - hmb,
                        2.0 * (va - vb) + hma + hmb,
                    ]
                })
                .collect()
        });
        Cubic {
            x,
            inv_h,
            inv_mean_h,
            cubic,
            values,
        }
    }

    #[inline(always)]
    fn eval(&self, q: f64, dir: i8) -> (f64, bool) {
        let (i, t, cl) = locate(&self.x, &self.inv_h, self.inv_mean_h, q);
        if cl {
            return (self.values[slot(dir)][i], true);
        }
        let [c0, c1, c2, c3] = self.cubic[slot(dir)][i];
        (c0 + t * (c1 + t * (c2 + t * c3)), false)
    }
}

/// The floor's evaluation state: the 16 lags.
#[derive(Clone, Debug)]
pub(crate) struct FloorState {
    lagged: [f64; 16],
    dt_c: [f64; 16],
    last_t_s: Option<f64>,
    dt0: f64,
    keep0: [f64; 16],
}

/// The hand-specialised evaluator of vmc-3axis (see the module doc).
#[derive(Debug)]
pub(crate) struct Floor {
    blocks: [Block; 3],
    travel: [(f64, f64); 3],
    tools_z: Vec<f64>,
    /// Squareness tip shifts per mm: EC0Y (x per y), EB0Z (x per z), EA0Z (y per z), µm/mm.
    sq: [f64; 3],
    /// Tilted directions of Y and Z (the exact chain's ũ).
    u_y: [f64; 3],
    u_z: [f64; 3],
    reference_c: [f64; 16],
    tau: [Option<f64>; 16],
    inv_tau: [f64; 16],
    /// spindle_growth: b for sensors 0..4, c for sensor 0².
    sg_b: [f64; 4],
    sg_c00: f64,
    sg_e0: f64,
    /// x_slope: s0, s for sensors 15, 9, 13.
    xs_s0: f64,
    xs_s: [f64; 3],
    /// Expansions scale_y, scale_z, scale_x: (α, origin, reference).
    exp: [(f64, f64, f64); 3],
    /// column_drift_y along Z: stations, 1/gap, e0, b for sensors 4, 5, 6, 7, 8, 14.
    cd_st: [f64; 3],
    cd_inv_gap: [f64; 2],
    cd_e0: [f64; 3],
    cd_b: [[f64; 6]; 3],
    /// column_tilt: e0, b for sensors 4, 5.
    ct_e0: f64,
    ct_b: [f64; 2],
    defl_x: Cubic,
    /// deflection_y: a0 + a1 z on [lo, hi].
    defl_y: (f64, f64, f64, f64),
    roll: Cubic,
    roll_scale: f64,
    /// workpiece force from strain 0: gain, offset.
    strain: (f64, f64),
}

fn table(m: &MachineModel, k: usize) -> &Table {
    match &m.spec().components[k].function {
        ErrorFunction::Table(t) => t,
        _ => panic!("vmc-3axis: component {k} is a table"),
    }
}

impl Floor {
    /// Read the numbers of a model shaped like vmc-3axis (panics otherwise).
    pub(crate) fn new(m: &MachineModel) -> Floor {
        let s = m.spec();
        assert_eq!(m.term_names().len(), N_TERMS, "vmc-3axis: 32 terms");
        assert_eq!(s.chain_string(), "X F Y Z");
        for (i, name) in SENSORS.iter().enumerate() {
            assert_eq!(&s.sensors[i].name, name);
        }
        let names: Vec<String> = s.components.iter().map(|c| c.id.iso_name()).collect();
        let want = "EXX EYX EZX EAX EBX ECX EXY EYY EZY EAY EBY ECY EXZ EYZ EZZ EAZ EBZ ECZ";
        assert_eq!(names.join(" "), want);
        let blocks = std::array::from_fn(|a| {
            let t: Vec<&Table> = (0..6).map(|k| table(m, 6 * a + k)).collect();
            assert!(t.iter().all(|u| u.positions_mm == t[0].positions_mm));
            Block::new(&t)
        });
        let travel = std::array::from_fn(|a| s.axes[a].travel_mm.expect("travel"));
        assert!(s.axes.iter().all(|a| a.offset_mm == [0.0; 3]));
        assert!(s.tools.iter().all(|t| t.offset_mm[..2] == [0.0, 0.0]));
        assert_eq!(s.tool_axis, (Axis::Z, -1.0));
        let sqv = |k: usize| s.squareness[k].value_urad * 1e-6;
        let (c0y, b0z, a0z) = (sqv(0), sqv(1), sqv(2));
        let rot = |axis, th, u: [f64; 3]| {
            let v = rotation_about(axis, th) * nalgebra::Vector3::new(u[0], u[1], u[2]);
            [v[0], v[1], v[2]]
        };
        let u_y = rot(Axis::Z, c0y, [0.0, 1.0, 0.0]);
        let u_z = rot(Axis::X, a0z, rot(Axis::Y, b0z, [0.0, 0.0, 1.0]));
        let th = |k: usize| &s.thermal[k].kind;
        let ThermalKind::PolynomialDt {
            e0,
            b_per_k,
            c_per_k2,
            ..
        } = th(0)
        else {
            panic!()
        };
        let (sg_e0, sg_b, sg_c00) = (
            *e0,
            [b_per_k[0], b_per_k[1], b_per_k[2], b_per_k[3]],
            c_per_k2[0][0],
        );
        let c_rest: f64 = c_per_k2.iter().flatten().map(|c| c.abs()).sum::<f64>() - sg_c00.abs();
        assert!(c_rest == 0.0, "spindle_growth: only c00 is non-zero");
        let ThermalKind::Slope {
            s0_per_mm,
            s_per_mm_k,
            d_per_mm_k2,
            ..
        } = th(1)
        else {
            panic!()
        };
        assert!(d_per_mm_k2.iter().flatten().all(|d| *d == 0.0));
        let (xs_s0, xs_s) = (*s0_per_mm, [s_per_mm_k[0], s_per_mm_k[1], s_per_mm_k[2]]);
        let exp = [2, 3, 4].map(|k| match th(k) {
            ThermalKind::Expansion {
                alpha_ppm_per_k,
                origin_mm,
                reference_c,
                ..
            } => (*alpha_ppm_per_k, *origin_mm, *reference_c),
            _ => panic!(),
        });
        let ThermalKind::Stations {
            stations_mm,
            e0,
            b_per_k,
            ..
        } = th(5)
        else {
            panic!()
        };
        let cd_st = [stations_mm[0], stations_mm[1], stations_mm[2]];
        let cd_b = std::array::from_fn(|k| std::array::from_fn(|i| b_per_k[k][i]));
        assert!(b_per_k.iter().flatten().all(|b| *b != 0.0));
        let ThermalKind::PolynomialDt {
            e0: ct_e0,
            b_per_k: ct_b,
            c_per_k2: ct_c,
            ..
        } = th(6)
        else {
            panic!()
        };
        assert!(ct_c.iter().flatten().all(|c| *c == 0.0));
        let LoadKind::Compliance { compliance, .. } = &s.load[0].kind else {
            panic!()
        };
        let defl_x = Cubic::new(compliance);
        let LoadKind::Compliance {
            compliance:
                ErrorFunction::Polynomial {
                    coefficients,
                    range_mm: Some((lo, hi)),
                },
            ..
        } = &s.load[1].kind
        else {
            panic!()
        };
        let LoadKind::WeightAngular {
            reference,
            reference_force_n,
            lever_mm,
            load_height_mm,
            ..
        } = &s.load[2].kind
        else {
            panic!()
        };
        let src = s.forces[2]
            .from_strain
            .as_ref()
            .expect("workpiece from strain");
        Floor {
            blocks,
            travel,
            tools_z: s.tools.iter().map(|t| t.offset_mm[2]).collect(),
            sq: [-c0y * 1e3, b0z * 1e3, -a0z * 1e3],
            u_y,
            u_z,
            reference_c: std::array::from_fn(|i| s.sensors[i].reference_c),
            tau: std::array::from_fn(|i| s.sensors[i].tau_s),
            inv_tau: std::array::from_fn(|i| s.sensors[i].tau_s.map_or(0.0, |t| 1.0 / t)),
            sg_b,
            sg_c00,
            sg_e0,
            xs_s0,
            xs_s,
            exp,
            cd_st,
            cd_inv_gap: [1.0 / (cd_st[1] - cd_st[0]), 1.0 / (cd_st[2] - cd_st[1])],
            cd_e0: [e0[0], e0[1], e0[2]],
            cd_b,
            ct_e0: *ct_e0,
            ct_b: [ct_b[0], ct_b[1]],
            defl_x,
            defl_y: (coefficients[0], coefficients[1], *lo, *hi),
            roll: Cubic::new(reference),
            roll_scale: (lever_mm - load_height_mm) / lever_mm / reference_force_n,
            strain: (src.gain_n_per_ue, src.offset_ue),
        }
    }

    pub(crate) fn new_state(&self) -> FloorState {
        FloorState {
            lagged: [0.0; 16],
            dt_c: [0.0; 16],
            last_t_s: None,
            dt0: f64::NAN,
            keep0: [0.0; 16],
        }
    }
}

mod run;

/// `deploy/examples/vmc-3axis.toml`.
pub(crate) fn vmc_model() -> MachineModel {
    let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../deploy/examples/vmc-3axis.toml");
    MachineModel::from_toml_path(&p).expect("vmc-3axis loads")
}

/// The points of `benches/models.rs`: a deterministic spread over the work zone, directions
/// alternating per axis (Z unknown), warm sensors, 150 N cutting forces, 40 µm/m strain.
pub(crate) fn bench_inputs(model: &MachineModel, n: usize) -> Vec<ModelInput> {
    (0..n)
        .map(|i| {
            let f = f64::from(u32::try_from(i).expect("n < 2³²"));
            let mut input = model.new_input();
            input.pos_mm = [(f * 7.31) % 800.0, (f * 3.77) % 500.0, (f * 5.13) % 500.0];
            input.dir = [
                if i % 2 == 0 { 1 } else { -1 },
                if i % 3 == 0 { -1 } else { 1 },
                0,
            ];
            input.t_s = f * 0.001;
            for (k, t) in input.temps_c.iter_mut().enumerate() {
                *t =
                    20.0 + 0.1 * f64::from(u8::try_from(k).expect("16 sensors")) + (f * 1e-4).sin();
            }
            input.forces_n.fill(150.0);
            input.strains_ue.fill(40.0);
            input
        })
        .collect()
}
