//! The reference evaluator (straightforward): a [`ModelSpec`] compiled into index arrays, evaluated term by
//! term. `MachineModel::evaluate` runs the faster flat plan (`plan.rs`) built from these arrays;
//! this one stays as its oracle (`MachineModel::evaluate_reference`, `tests/models/fastpath.rs`).
//!
//! Terms (index = term id): components in file order, squareness entries, thermal terms, load terms,
//! and last `higher_order` (exact − Σ first-order terms; zero in first-order evaluation). Every
//! term's contribution is its first-order effect at the tool tip, so Σ terms = total in both modes.

use super::function::{ErrorFunction, Location};
use super::kinematics::{Elem, arms, cross, exact_tip, nominal_tip, rotation_about};
use super::names::Axis;
use super::spec::{LoadKind, ModelSpec};
use super::thermal::{ThermalState, thermal_value};
use super::{ErrorBreakdown, ModelInput, ModelState};

#[derive(Clone, Debug)]
pub(crate) struct Slot {
    /// Chain element index.
    pub elem: usize,
    /// 0..3 translation x/y/z, 3..6 rotation a/b/c.
    pub slot: usize,
}

#[derive(Clone, Debug)]
pub(crate) struct Compiled {
    pub elems: Vec<Elem>,
    pub axes: Vec<Axis>,
    pub components: Vec<Slot>,
    /// Per component: its table has the same element and positions as the previous component's
    /// table, so the previous lookup's location is reused (one search per axis, not six).
    pub shares_location: Vec<bool>,
    /// Per squareness entry: element and the first-order tip shift per mm of travel, µm/mm.
    pub squareness: Vec<(usize, [f64; 3])>,
    pub thermal: Vec<(Slot, Vec<usize>, Option<usize>)>,
    pub load: Vec<(Slot, usize)>,
    /// Per force channel: index into the direct force inputs, or the strain source index.
    pub force_source: Vec<ForceSource>,
    pub term_names: Vec<String>,
    pub temperature_sensors: Vec<String>,
    /// Column each sensor reads (`T_<name>_C` or its `column`), same index.
    pub sensor_columns: Vec<String>,
    pub force_channels: Vec<String>,
    pub strain_channels: Vec<String>,
}

#[derive(Clone, Copy, Debug)]
pub(crate) enum ForceSource {
    Direct(usize),
    Strain {
        index: usize,
        gain_n_per_ue: f64,
        offset_ue: f64,
    },
}

impl Compiled {
    pub(crate) fn new(spec: &ModelSpec) -> Compiled {
        let (mut elems, elem_of_axis) = chain_elems(spec);
        let slot = |axis: Axis, s: usize| slot_of(&elem_of_axis, axis, s);

        let mut term_names = Vec::new();
        let components = spec
            .components
            .iter()
            .map(|c| {
                term_names.push(c.id.iso_name());
                slot(c.id.axis, c.id.slot())
            })
            .collect();
        let shares_location = shares_location(spec);
        let squareness = squareness_shifts(spec, &elem_of_axis, &mut elems, &mut term_names);
        let thermal = thermal_slots(spec, &elem_of_axis, &mut term_names);
        let (force_source, force_channels, strain_channels) = force_sources(spec);
        let load = load_slots(spec, &elem_of_axis, &mut term_names);
        term_names.push("higher_order".into());

        Compiled {
            axes: elems.iter().map(|e| e.axis).collect(),
            elems,
            components,
            shares_location,
            squareness,
            thermal,
            load,
            force_source,
            term_names,
            temperature_sensors: spec.sensors.iter().map(|s| s.name.clone()).collect(),
            sensor_columns: spec.sensors.iter().map(|s| s.column_name()).collect(),
            force_channels,
            strain_channels,
        }
    }
}

/// The chain's elements in file order, untilted, and per axis (X/Y/Z index) its element index.
fn chain_elems(spec: &ModelSpec) -> (Vec<Elem>, [Option<usize>; 3]) {
    let mut elem_of_axis = [None; 3];
    let elems: Vec<Elem> = spec
        .axes
        .iter()
        .enumerate()
        .map(|(j, a)| {
            elem_of_axis[a.axis.index()] = Some(j);
            Elem::untilted(a)
        })
        .collect();
    (elems, elem_of_axis)
}

/// Where a value of `axis` in `s` (0..6) lands: its chain element and slot.
fn slot_of(elem_of_axis: &[Option<usize>; 3], axis: Axis, s: usize) -> Slot {
    Slot {
        elem: elem_of_axis[axis.index()].expect("validated: axis in chain"),
        slot: s,
    }
}

/// Per component: whether it may reuse the previous component's table lookup.
fn shares_location(spec: &ModelSpec) -> Vec<bool> {
    (0..spec.components.len())
        .map(|k| {
            k > 0 && {
                let (prev, cur) = (&spec.components[k - 1], &spec.components[k]);
                match (&prev.function, &cur.function) {
                    (ErrorFunction::Table(a), ErrorFunction::Table(b)) => {
                        prev.id.axis == cur.id.axis && a.same_positions(b)
                    }
                    _ => false,
                }
            }
        })
        .collect()
}

/// Per squareness entry its first-order tip shift; also tilts the carrying element's axis for the
/// exact chain, and names the term.
fn squareness_shifts(
    spec: &ModelSpec,
    elem_of_axis: &[Option<usize>; 3],
    elems: &mut [Elem],
    term_names: &mut Vec<String>,
) -> Vec<(usize, [f64; 3])> {
    let mut squareness = Vec::new();
    for s in &spec.squareness {
        let (_reference, rotated, about) = s.kind.axes();
        // On the axis ISO rotates the angle is +S; on the reference axis −S keeps the same angle
        // between the two axes (see names::Squareness for the sign of each kind).
        let theta_rad = if s.on_axis == rotated {
            s.value_urad
        } else {
            -s.value_urad
        } * 1e-6;
        let e = elem_of_axis[s.on_axis.index()].expect("validated: squareness axis in chain");
        let mut r_hat = [0.0; 3];
        r_hat[about.index()] = 1.0;
        let d = cross(r_hat, elems[e].u);
        squareness.push((
            e,
            [
                theta_rad * d[0] * 1e3,
                theta_rad * d[1] * 1e3,
                theta_rad * d[2] * 1e3,
            ],
        ));
        let m = rotation_about(about, theta_rad);
        let u = elems[e].u_tilted;
        let v = m * nalgebra::Vector3::new(u[0], u[1], u[2]);
        elems[e].u_tilted = [v[0], v[1], v[2]];
        term_names.push(ModelSpec::squareness_term_name(s));
    }
    squareness
}

/// Per thermal term its slot, its sensors' indices and (stations) the element they lie along.
fn thermal_slots(
    spec: &ModelSpec,
    elem_of_axis: &[Option<usize>; 3],
    term_names: &mut Vec<String>,
) -> Vec<(Slot, Vec<usize>, Option<usize>)> {
    let slot = |axis: Axis, s: usize| slot_of(elem_of_axis, axis, s);
    let sensor_index = |n: &String| {
        spec.sensors
            .iter()
            .position(|s| &s.name == n)
            .expect("validated: sensor exists")
    };
    spec.thermal
        .iter()
        .map(|t| {
            term_names.push(t.name.clone());
            let (idx, along) = match &t.kind {
                super::spec::ThermalKind::PolynomialDt { sensors, .. }
                | super::spec::ThermalKind::Slope { sensors, .. } => {
                    (sensors.iter().map(sensor_index).collect(), None)
                }
                super::spec::ThermalKind::Expansion { sensor, .. } => {
                    (vec![sensor_index(sensor)], None)
                }
                super::spec::ThermalKind::Stations { sensors, along, .. } => (
                    sensors.iter().map(sensor_index).collect(),
                    elem_of_axis[along.index()],
                ),
            };
            (slot(t.target.axis, t.target.slot()), idx, along)
        })
        .collect()
}

/// Per force channel where its value comes from, with the direct force and strain input names
/// (a strain column shared by several channels is read once).
fn force_sources(spec: &ModelSpec) -> (Vec<ForceSource>, Vec<String>, Vec<String>) {
    let mut force_channels = Vec::new();
    let mut strain_channels: Vec<String> = Vec::new();
    let force_source = spec
        .forces
        .iter()
        .map(|f| match &f.from_strain {
            None => {
                force_channels.push(f.name.clone());
                ForceSource::Direct(force_channels.len() - 1)
            }
            Some(src) => {
                let index = strain_channels
                    .iter()
                    .position(|s| s == &src.strain)
                    .unwrap_or_else(|| {
                        strain_channels.push(src.strain.clone());
                        strain_channels.len() - 1
                    });
                ForceSource::Strain {
                    index,
                    gain_n_per_ue: src.gain_n_per_ue,
                    offset_ue: src.offset_ue,
                }
            }
        })
        .collect();
    (force_source, force_channels, strain_channels)
}

/// Per load term its slot and the index of its force channel.
fn load_slots(
    spec: &ModelSpec,
    elem_of_axis: &[Option<usize>; 3],
    term_names: &mut Vec<String>,
) -> Vec<(Slot, usize)> {
    let slot = |axis: Axis, s: usize| slot_of(elem_of_axis, axis, s);
    spec.load
        .iter()
        .map(|l| {
            term_names.push(l.name.clone());
            let force = match &l.kind {
                LoadKind::Compliance { force, .. } | LoadKind::WeightAngular { force, .. } => force,
            };
            let fi = spec
                .forces
                .iter()
                .position(|f| &f.name == force)
                .expect("validated: force exists");
            (slot(l.target.axis, l.target.slot()), fi)
        })
        .collect()
}

/// First-order tip contribution (µm) of value `v` in `slot` of an element with Abbe arm `arm_mm`.
#[inline(always)]
fn contribution(slot: usize, v: f64, arm_mm: [f64; 3]) -> [f64; 3] {
    // Written out per slot (not `c[slot] = v`): a one-lane store followed by a whole-vector load
    // defeats store forwarding and cost ~40 % of an evaluation.
    let w = v * 1e-3; // µrad × mm = 1e-3 µm
    let [ax, ay, az] = arm_mm;
    match slot {
        0 => [v, 0.0, 0.0],
        1 => [0.0, v, 0.0],
        2 => [0.0, 0.0, v],
        3 => [0.0, -w * az, w * ay], // (w, 0, 0) × arm
        4 => [w * az, 0.0, -w * ax], // (0, w, 0) × arm
        _ => [-w * ay, w * ax, 0.0], // (0, 0, w) × arm
    }
}

/// Per-element error motions.
struct Acc {
    delta_um: [[f64; 3]; 3],
    eps_urad: [[f64; 3]; 3],
}

impl Acc {
    #[inline(always)]
    fn apply(&mut self, s: &Slot, v: f64, arm: &[[f64; 3]; 3], term: &mut [f64; 3]) {
        if s.slot < 3 {
            self.delta_um[s.elem][s.slot] += v;
        } else {
            self.eps_urad[s.elem][s.slot - 3] += v;
        }
        *term = contribution(s.slot, v, arm[s.elem]);
    }

    /// Σ over elements of δ + ε × arm, µm: the first-order effect of all accumulated motions.
    #[inline]
    fn first_order_um(&self, arm: &[[f64; 3]; 3], n: usize) -> [f64; 3] {
        let mut t = [0.0; 3];
        for ((d, r), a) in self.delta_um.iter().zip(&self.eps_urad).zip(arm).take(n) {
            let c = cross([r[0] * 1e-3, r[1] * 1e-3, r[2] * 1e-3], *a);
            t = [t[0] + d[0] + c[0], t[1] + d[1] + c[1], t[2] + d[2] + c[2]];
        }
        t
    }
}

#[inline]
fn eval_fn(f: &ErrorFunction, q: f64, dir: i8) -> (f64, bool) {
    f.eval(q, dir)
}

/// The reference evaluation: one straight pass along the chain, kept whole (over the ~100-line
/// rule) so it reads against docs/model.md's formulas; `plan.rs` is tested equal to it.
pub(crate) fn run(
    spec: &ModelSpec,
    c: &Compiled,
    input: &ModelInput,
    state: &mut ModelState,
    out: &mut ErrorBreakdown,
    exact: bool,
) {
    let n_terms = c.term_names.len();
    out.reset(n_terms);

    // Positions of the chain's axes; a non-finite position makes the whole evaluation invalid.
    let mut q = [0.0; 3];
    let mut dir = [0i8; 3];
    for (j, e) in c.elems.iter().enumerate() {
        q[j] = input.pos_mm[e.axis.index()];
        dir[j] = input.dir[e.axis.index()].signum();
    }
    let tool = spec.tools.get(input.tool).or(spec.tools.first());
    let mut t = tool.map_or([0.0; 3], |t| t.offset_mm);
    if let Some(len) = input.tool_mm {
        t[spec.tool_axis.0.index()] = spec.tool_axis.1 * len;
    }
    if q.iter().chain(t.iter()).any(|x| !x.is_finite()) || !input.t_s.is_finite() {
        out.flags.invalid_input = true;
        return;
    }
    if input.tool >= spec.tools.len() {
        out.flags.missing_input = true;
    }
    for (j, a) in spec.axes.iter().enumerate() {
        if let Some((lo, hi)) = a.travel_mm
            && (q[j] < lo || q[j] > hi)
        {
            out.flags.outside_travel[a.axis.index()] = true;
        }
    }

    // Thermal state.
    let issues = state.thermal.step(&spec.sensors, &input.temps_c, input.t_s);
    out.flags.missing_input |= issues.missing_temperature;
    out.flags.time_backwards |= issues.time_backwards;
    let ts: &ThermalState = &state.thermal;

    // Forces (N) per force channel, into the state's scratch (sized once).
    if state.forces_n.len() != c.force_source.len() {
        state.forces_n.resize(c.force_source.len(), 0.0);
    }
    for (i, src) in c.force_source.iter().enumerate() {
        let v = match *src {
            ForceSource::Direct(k) => input.forces_n.get(k).copied(),
            ForceSource::Strain {
                index,
                gain_n_per_ue,
                offset_ue,
            } => input
                .strains_ue
                .get(index)
                .map(|s| gain_n_per_ue * (s - offset_ue)),
        };
        state.forces_n[i] = match v {
            Some(f) if f.is_finite() => f,
            _ => {
                out.flags.missing_input = true;
                0.0
            }
        };
    }

    let mut arm = [[0.0; 3]; 3];
    arms(&c.elems, &q, t, &mut arm);
    let mut acc = Acc {
        delta_um: [[0.0; 3]; 3],
        eps_urad: [[0.0; 3]; 3],
    };
    let mut sq_total = [0.0; 3];
    let mut k = 0;

    let mut loc = Location::Clamped(0);
    for ((cs, s), &shared) in spec
        .components
        .iter()
        .zip(&c.components)
        .zip(&c.shares_location)
    {
        let (v, clamped) = match &cs.function {
            ErrorFunction::Table(tb) => {
                if !shared {
                    loc = tb.locate(q[s.elem]);
                }
                tb.eval_at(loc, dir[s.elem])
            }
            f => eval_fn(f, q[s.elem], dir[s.elem]),
        };
        if clamped {
            out.flags.clamped[c.elems[s.elem].axis.index()] = true;
        }
        acc.apply(s, v, &arm, &mut out.terms_um[k]);
        k += 1;
    }
    for &(e, d) in &c.squareness {
        let ct = [d[0] * q[e], d[1] * q[e], d[2] * q[e]];
        out.terms_um[k] = ct;
        sq_total = [
            sq_total[0] + ct[0],
            sq_total[1] + ct[1],
            sq_total[2] + ct[2],
        ];
        k += 1;
    }
    for (th, (s, idx, along)) in spec.thermal.iter().zip(&c.thermal) {
        let abs_c = idx
            .first()
            .and_then(|&i| ts.lagged_c(i))
            .unwrap_or(match &th.kind {
                super::spec::ThermalKind::Expansion { reference_c, .. } => *reference_c,
                _ => 20.0,
            });
        let q_along = along.map_or(0.0, |a| q[a]);
        let (v, clamped) = thermal_value(&th.kind, idx, &ts.delta_c, abs_c, q[s.elem], q_along);
        if clamped && let Some(a) = along {
            out.flags.clamped[c.elems[*a].axis.index()] = true;
        }
        acc.apply(s, v, &arm, &mut out.terms_um[k]);
        k += 1;
    }
    for (l, (s, fi)) in spec.load.iter().zip(&c.load) {
        let f = state.forces_n[*fi];
        let (v, clamped) = match &l.kind {
            LoadKind::Compliance { compliance, .. } => {
                let (cmp, cl) = eval_fn(compliance, q[s.elem], dir[s.elem]);
                (cmp * f, cl)
            }
            LoadKind::WeightAngular {
                reference,
                reference_force_n,
                lever_mm,
                load_height_mm,
                ..
            } => {
                let (r, cl) = eval_fn(reference, q[s.elem], dir[s.elem]);
                (
                    r * f / reference_force_n * (lever_mm - load_height_mm) / lever_mm,
                    cl,
                )
            }
        };
        if clamped {
            out.flags.clamped[c.elems[s.elem].axis.index()] = true;
        }
        acc.apply(s, v, &arm, &mut out.terms_um[k]);
        k += 1;
    }
    debug_assert_eq!(k, n_terms - 1);
    let fo = acc.first_order_um(&arm, c.elems.len());
    let first = [
        fo[0] + sq_total[0],
        fo[1] + sq_total[1],
        fo[2] + sq_total[2],
    ];

    if exact {
        let r = exact_tip(&c.elems, &q, t, &acc.delta_um, &acc.eps_urad);
        let r0 = nominal_tip(&c.elems, &q, t);
        let e = [
            (r[0] - r0[0]) * 1e3,
            (r[1] - r0[1]) * 1e3,
            (r[2] - r0[2]) * 1e3,
        ];
        out.terms_um[k] = [e[0] - first[0], e[1] - first[1], e[2] - first[2]];
        out.total_um = e;
    } else {
        out.total_um = first;
    }
    if out.total_um.iter().any(|x| !x.is_finite()) {
        // Cannot happen with validated finite inputs; never hand a NaN to a controller anyway.
        out.reset(n_terms);
        out.flags.invalid_input = true;
    }
}
