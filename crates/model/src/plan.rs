//! The fast evaluator: a [`ModelSpec`] compiled once into a flat evaluation plan.
//!
//! Same conventions, terms and results as the straightforward evaluator in `reference.rs`, which stays
//! as the oracle `tests/models/fastpath.rs` checks this one against (≤ 1e-9 µm; they differ only by
//! the rounding of reordered products): error = actual − nominal, µm, machine X/Y/Z; every term's
//! first-order contribution at the tool tip, and `higher_order` = exact − Σ first-order terms.
//! What differs is the layout, chosen so one evaluation neither branches per term nor allocates:
//!
//! * Linear tables of one chain element with equal positions form a [`Group`]: one search per axis
//!   (`lookup::Nodes`), and per approach direction one row of the members' values per node (the
//!   forward/reverse choice folded in when the plan is built), so a lookup reads two contiguous rows.
//!   A group holding an element's six components in slot and term order is written as one block.
//! * Other functions are `lookup::Curve`s: C¹ tables as one cubic per segment and direction,
//!   polynomials by Horner.
//! * A term's first-order effect is its value times a basis row of its element (translation: unit
//!   vector; rotation ε about e_i: 1e-3 µm/(µrad·mm) · e_i × arm), built once per evaluation.
//! * Thermal terms keep only their non-zero coefficients, as flat (sensor, coefficient) lists; the
//!   lag step multiplies by a stored 1/τ (`thermal::LagPlan`). When no motion would see its thermal
//!   values added in another order, the terms run as one loop per formula (no per-term `match`).
//! * A chain of three elements runs kernels compiled per layout (`plan/chain.rs`).
//! * The breakdown is overwritten in place: every term is written on every valid evaluation, so
//!   nothing is zeroed first and `terms_um` is only resized when its length is wrong.

use super::kinematics::{Elem, arms, cross, exact_tip, nominal_tip};
use super::lookup::{Curve, Nodes, dir_slot};
use super::reference::{Compiled, ForceSource};
use super::spec::ModelSpec;
use super::thermal::LagPlan;
use super::{ErrorBreakdown, EvalFlags, ModelInput, ModelState};

mod build;
mod chain;
mod thermal_ops;

use chain::{Chain3, layout};
use thermal_ops::{ThermalByKind, ThermalOp, ThermalTerm};

/// Where a term's value goes: its breakdown index, chain element and slot (0..3 δ x/y/z in µm,
/// 3..6 ε a/b/c in µrad).
#[derive(Clone, Copy, Debug)]
struct Target {
    term: usize,
    elem: usize,
    /// elem · 6 + slot: the index into the per-evaluation motion and basis arrays.
    at: usize,
}

impl Target {
    fn new(term: usize, elem: usize, slot: usize) -> Target {
        assert!(elem < 3 && slot < 6, "validated: three axes, six slots");
        Target {
            term,
            elem,
            at: elem * 6 + slot,
        }
    }
}

/// Linear tables of one element sharing their positions.
#[derive(Clone, Debug)]
struct Group {
    elem: usize,
    nodes: Nodes,
    /// Per direction slot ([`dir_slot`]): per node, the members' values (`members.len()` per row).
    rows: [Vec<f64>; 3],
    members: Vec<Target>,
    /// Set when the members are the element's six slots in order (δx δy δz εa εb εc) with
    /// consecutive term indices from this one, as a full set of ISO 230-1 components listed per
    /// axis is: then one evaluation writes them as a block, without a lookup per member.
    full_from_term: Option<usize>,
}

/// A group that is a full block (`Group::full_from_term`) with its rows as arrays of six, run before
/// the other groups (built so only when no group before it in the list has its element).
#[derive(Clone, Debug)]
struct Block6 {
    elem: usize,
    nodes: Nodes,
    /// Per direction slot ([`dir_slot`]): per node, δx δy δz εa εb εc.
    rows: [Vec<[f64; 6]>; 3],
    /// The breakdown index of δx (the other five follow).
    first_term: usize,
}

/// A component the groups do not cover (C¹ table, polynomial, piecewise quadratic).
#[derive(Clone, Debug)]
struct Single {
    target: Target,
    curve: Curve,
}

#[derive(Clone, Debug)]
struct LoadTerm {
    target: Target,
    /// Index into the force channels (state scratch).
    force: usize,
    curve: Curve,
    /// v = curve(q) · F · scale: 1 for a compliance, (lever − height) / lever / F_ref for a
    /// weight-scaled reference.
    scale: f64,
}

/// The compiled plan. Built by [`Plan::new`] when a model is loaded.
#[derive(Clone, Debug)]
pub(crate) struct Plan {
    elems: Vec<Elem>,
    /// The chain compiled per layout when it has three elements (`None`: the general code).
    chain3: Option<Chain3>,
    travel_mm: Vec<Option<(f64, f64)>>,
    tools_mm: Vec<[f64; 3]>,
    tool_axis: (usize, f64),
    n_terms: usize,
    blocks: Vec<Block6>,
    groups: Vec<Group>,
    singles: Vec<Single>,
    /// (term, element, first-order tip shift per mm of the element's travel, µm/mm).
    squareness: Vec<(usize, usize, [f64; 3])>,
    thermal: Vec<ThermalTerm>,
    /// `thermal` by kind when that keeps the order of every sum (`None`: one loop over `thermal`).
    thermal_by_kind: Option<ThermalByKind>,
    /// Non-zero linear coefficients: (sensor, coefficient).
    linear: Vec<(usize, f64)>,
    /// Non-zero quadratic coefficients: (sensor i, sensor j, coefficient).
    quadratic: Vec<(usize, usize, f64)>,
    lags: LagPlan,
    force_source: Vec<ForceSource>,
    load: Vec<LoadTerm>,
}

impl Plan {
    pub(crate) fn new(spec: &ModelSpec, c: &Compiled) -> Plan {
        let n_comp = spec.components.len();
        let (mut groups, singles) = build::group_components(spec, c);
        build::fill_group_rows(&mut groups, spec);
        let (blocks, groups) = build::split_blocks(groups);

        let n_sq = spec.squareness.len();
        let squareness = c
            .squareness
            .iter()
            .enumerate()
            .map(|(i, &(e, d))| (n_comp + i, e, d))
            .collect();

        let mut linear = Vec::new();
        let mut quadratic = Vec::new();
        let thermal = build::thermal_terms(spec, c, n_comp + n_sq, &mut linear, &mut quadratic);

        let n_th = spec.thermal.len();
        let load = build::load_terms(spec, c, n_comp + n_sq + n_th);

        Plan {
            elems: c.elems.clone(),
            chain3: Chain3::new(&c.elems),
            travel_mm: spec.axes.iter().map(|a| a.travel_mm).collect(),
            tools_mm: spec.tools.iter().map(|t| t.offset_mm).collect(),
            tool_axis: (spec.tool_axis.0.index(), spec.tool_axis.1),
            n_terms: c.term_names.len(),
            blocks,
            groups,
            singles,
            squareness,
            thermal_by_kind: build::thermal_by_kind(&thermal),
            thermal,
            linear,
            quadratic,
            lags: LagPlan::new(&spec.sensors),
            force_source: c.force_source.clone(),
            load,
        }
    }

    /// One evaluation (exact HTM chain or first order); steps the lag states to `input.t_s`.
    /// Kept as one function over the ~100-line rule: it is the per-evaluation hot path (`cargo
    /// bench --bench gateway -- cycle_compute`) and its stages share the chain's positions, tool
    /// vector and flags as locals.
    #[inline]
    pub(crate) fn run(
        &self,
        input: &ModelInput,
        state: &mut ModelState,
        out: &mut ErrorBreakdown,
        exact: bool,
    ) {
        let n_terms = self.n_terms;
        out.total_um = [0.0; 3];
        out.flags = EvalFlags::default();
        if out.terms_um.len() != n_terms {
            out.reset(n_terms);
        }

        // Positions of the chain's axes; a non-finite position makes the whole evaluation invalid.
        let mut q = [0.0; 3];
        let mut dir = [0i8; 3];
        for (j, e) in self.elems.iter().enumerate() {
            q[j] = input.pos_mm[e.axis.index()];
            dir[j] = input.dir[e.axis.index()].signum();
        }
        let mut t = self
            .tools_mm
            .get(input.tool)
            .or(self.tools_mm.first())
            .copied()
            .unwrap_or([0.0; 3]);
        if let Some(len) = input.tool_mm {
            t[self.tool_axis.0] = self.tool_axis.1 * len;
        }
        if q.iter().chain(t.iter()).any(|x| !x.is_finite()) || !input.t_s.is_finite() {
            out.reset(n_terms);
            out.flags.invalid_input = true;
            return;
        }
        if input.tool >= self.tools_mm.len() {
            out.flags.missing_input = true;
        }
        for (j, travel) in self.travel_mm.iter().enumerate() {
            if let Some((lo, hi)) = *travel
                && (q[j] < lo || q[j] > hi)
            {
                out.flags.outside_travel[self.elems[j].axis.index()] = true;
            }
        }

        let issues = state
            .thermal
            .step_planned(&self.lags, &input.temps_c, input.t_s);
        out.flags.missing_input |= issues.missing_temperature;
        out.flags.time_backwards |= issues.time_backwards;

        // Forces (N) per force channel, into the state's scratch (sized once).
        if state.forces_n.len() != self.force_source.len() {
            state.forces_n.resize(self.force_source.len(), 0.0);
        }
        for (f, src) in state.forces_n.iter_mut().zip(&self.force_source) {
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
            *f = match v {
                Some(f) if f.is_finite() => f,
                _ => {
                    out.flags.missing_input = true;
                    0.0
                }
            };
        }

        let arm = match &self.chain3 {
            Some(c) => layout!(c, arms(&q, &input.pos_mm, t)),
            None => {
                let mut arm = [[0.0; 3]; 3];
                arms(&self.elems, &q, t, &mut arm);
                arm
            }
        };
        // arm_um[j]: element j's arm · 1e-3, the tip shift (µm) per µrad of rotation about each
        // axis is e_i × arm_um. basis[6 j + slot]: the tip shift (µm) per unit value in `slot`.
        let arm_um = arm.map(|a| [a[0] * 1e-3, a[1] * 1e-3, a[2] * 1e-3]);
        let mut basis = [[0.0; 3]; 18];
        for (b, &[ax, ay, az]) in basis.chunks_exact_mut(6).zip(&arm_um) {
            b.copy_from_slice(&[
                [1.0, 0.0, 0.0],
                [0.0, 1.0, 0.0],
                [0.0, 0.0, 1.0],
                [0.0, -az, ay], // e_x × arm
                [az, 0.0, -ax], // e_y × arm
                [-ay, ax, 0.0], // e_z × arm
            ]);
        }
        // acc[6 j + slot]: element j's δ x/y/z (µm), then ε a/b/c (µrad).
        let mut acc = [0.0; 18];
        let terms = &mut out.terms_um[..];
        let mut clamped = [false; 3];

        // A full block's values into its element's motions and, through its basis rows written
        // out (v · 1 as v, v · 0 as 0, v · (−a)), into its six terms.
        #[inline(always)]
        fn write_block(acc: &mut [f64], block: &mut [[f64; 3]], v: [f64; 6], arm_um: [f64; 3]) {
            for (acc, v) in acc.iter_mut().zip(&v) {
                *acc += v;
            }
            let [ax, ay, az] = arm_um;
            block.copy_from_slice(&[
                [v[0], 0.0, 0.0],
                [0.0, v[1], 0.0],
                [0.0, 0.0, v[2]],
                [0.0, v[3] * -az, v[3] * ay],
                [v[4] * az, 0.0, v[4] * -ax],
                [v[5] * -ay, v[5] * ax, 0.0],
            ]);
        }
        for b in &self.blocks {
            // Clamped: both nodes the end node and f = 0, so a + 0 · (b − a) = a exactly.
            let e = b.elem;
            let (lo, hi, f, cl) = b.nodes.locate(q[e]);
            clamped[e] |= cl;
            let rows = &b.rows[dir_slot(dir[e])];
            let (r0, r1) = (rows[lo], rows[hi]);
            let v: [f64; 6] = std::array::from_fn(|s| r0[s] + f * (r1[s] - r0[s]));
            let t0 = b.first_term;
            write_block(
                &mut acc[6 * e..6 * e + 6],
                &mut terms[t0..t0 + 6],
                v,
                arm_um[e],
            );
        }
        for g in &self.groups {
            let (lo, hi, f, cl) = g.nodes.locate(q[g.elem]);
            clamped[g.elem] |= cl;
            let rows = &g.rows[dir_slot(dir[g.elem])];
            let m = g.members.len();
            let a = &rows[m * lo..m * (lo + 1)];
            let b = &rows[m * hi..m * (hi + 1)];
            if let Some(t0) = g.full_from_term
                && let (Ok(a), Ok(b)) = (<&[f64; 6]>::try_from(a), <&[f64; 6]>::try_from(b))
                && let Some(block) = terms.get_mut(t0..t0 + 6)
            {
                let v: [f64; 6] = std::array::from_fn(|s| a[s] + f * (b[s] - a[s]));
                let e = g.elem;
                write_block(&mut acc[6 * e..6 * e + 6], block, v, arm_um[e]);
                continue;
            }
            for (&tg, (&a, &b)) in g.members.iter().zip(a.iter().zip(b)) {
                apply(&mut acc, &basis, terms, tg, a + f * (b - a));
            }
        }
        for s in &self.singles {
            let e = s.target.elem;
            let (v, cl) = s.curve.eval(q[e], dir[e]);
            clamped[e] |= cl;
            apply(&mut acc, &basis, terms, s.target, v);
        }
        let mut sq_total = [0.0; 3];
        for &(k, e, d) in &self.squareness {
            let ct = [d[0] * q[e], d[1] * q[e], d[2] * q[e]];
            terms[k] = ct;
            sq_total = [
                sq_total[0] + ct[0],
                sq_total[1] + ct[1],
                sq_total[2] + ct[2],
            ];
        }
        self.thermal_stage(&q, &state.thermal, &mut acc, &basis, terms, &mut clamped);
        for l in &self.load {
            let e = l.target.elem;
            let (v, cl) = l.curve.eval(q[e], dir[e]);
            clamped[e] |= cl;
            apply(
                &mut acc,
                &basis,
                terms,
                l.target,
                v * state.forces_n[l.force] * l.scale,
            );
        }
        for (j, e) in self.elems.iter().enumerate() {
            out.flags.clamped[e.axis.index()] |= clamped[j];
        }

        // Σ over elements of δ + ε × arm: the first-order effect of all accumulated motions.
        let mut first = [0.0; 3];
        for (a, r) in acc.chunks_exact(6).zip(&arm).take(self.elems.len()) {
            let c = cross([a[3] * 1e-3, a[4] * 1e-3, a[5] * 1e-3], *r);
            first = [
                first[0] + a[0] + c[0],
                first[1] + a[1] + c[1],
                first[2] + a[2] + c[2],
            ];
        }
        let first = [
            first[0] + sq_total[0],
            first[1] + sq_total[1],
            first[2] + sq_total[2],
        ];

        if exact {
            let delta = [
                [acc[0], acc[1], acc[2]],
                [acc[6], acc[7], acc[8]],
                [acc[12], acc[13], acc[14]],
            ];
            let eps = [
                [acc[3], acc[4], acc[5]],
                [acc[9], acc[10], acc[11]],
                [acc[15], acc[16], acc[17]],
            ];
            let e = match &self.chain3 {
                Some(c) => layout!(c, exact_error(&q, &input.pos_mm, t, &delta, &eps)),
                None => exact_error(&self.elems, &q, t, &delta, &eps),
            };
            terms[n_terms - 1] = [e[0] - first[0], e[1] - first[1], e[2] - first[2]];
            out.total_um = e;
        } else {
            terms[n_terms - 1] = [0.0; 3];
            out.total_um = first;
        }
        if out.total_um.iter().any(|x| !x.is_finite()) {
            // Cannot happen with validated finite inputs; never hand a NaN to a controller anyway.
            out.reset(n_terms);
            out.flags.invalid_input = true;
        }
    }
}

/// A term's value: into its element's motions and, times its basis row, into its term.
#[inline(always)]
fn apply(acc: &mut [f64; 18], basis: &[[f64; 3]; 18], terms: &mut [[f64; 3]], tg: Target, v: f64) {
    acc[tg.at] += v;
    let b = basis[tg.at];
    terms[tg.term] = [v * b[0], v * b[1], v * b[2]];
}

/// Exact minus nominal tool tip, µm, for a chain of other than three elements (`Chain3` otherwise).
#[inline]
fn exact_error(
    elems: &[Elem],
    q: &[f64; 3],
    t: [f64; 3],
    delta: &[[f64; 3]; 3],
    eps: &[[f64; 3]; 3],
) -> [f64; 3] {
    let r = exact_tip(elems, q, t, delta, eps);
    let r0 = nominal_tip(elems, q, t);
    [
        (r[0] - r0[0]) * 1e3,
        (r[1] - r0[1]) * 1e3,
        (r[2] - r0[2]) * 1e3,
    ]
}
