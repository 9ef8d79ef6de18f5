//! Building [`Plan`](super::Plan)'s parts from a [`ModelSpec`] and its [`Compiled`] indices: once,
//! when a model is loaded, so everything here may allocate and branch per term.

use std::ops::Range;

use super::{Block6, Group, LoadTerm, Single, Target, ThermalByKind, ThermalOp, ThermalTerm};
use crate::function::{ErrorFunction, Interpolation, Table};
use crate::lookup::{Curve, Nodes, by_dir};
use crate::reference::Compiled;
use crate::spec::{LoadKind, ModelSpec, ThermalKind};

/// Components split into groups (linear tables of one element with equal positions, rows not yet
/// filled) and singles (everything else, as curves).
pub(super) fn group_components(spec: &ModelSpec, c: &Compiled) -> (Vec<Group>, Vec<Single>) {
    let mut groups: Vec<Group> = Vec::new();
    let mut singles = Vec::new();
    for (k, (cs, s)) in spec.components.iter().zip(&c.components).enumerate() {
        let target = Target::new(k, s.elem, s.slot);
        match &cs.function {
            ErrorFunction::Table(tb) if tb.interpolation == Interpolation::Linear => {
                let g = match groups
                    .iter_mut()
                    .position(|g| g.elem == s.elem && g.nodes.x == tb.positions_mm)
                {
                    Some(i) => &mut groups[i],
                    None => {
                        groups.push(Group {
                            elem: s.elem,
                            nodes: Nodes::new(&tb.positions_mm),
                            rows: Default::default(),
                            members: Vec::new(),
                            full_from_term: None,
                        });
                        groups.last_mut().expect("just pushed")
                    }
                };
                g.members.push(target);
            }
            f => singles.push(Single {
                target,
                curve: Curve::new(f),
            }),
        }
    }
    (groups, singles)
}

/// Per group: its rows (one per approach direction) and whether it is an element's full block.
pub(super) fn fill_group_rows(groups: &mut [Group], spec: &ModelSpec) {
    // Interleave the members' values per node now that each group's members are known.
    for g in groups.iter_mut() {
        let t0 = g.members[0].term;
        let full = g.members.len() == 6
            && g.members
                .iter()
                .enumerate()
                .all(|(s, m)| m.at == g.elem * 6 + s && m.term == t0 + s && m.elem == g.elem);
        g.full_from_term = full.then_some(t0);
        let tables: Vec<&Table> = g
            .members
            .iter()
            .map(|m| match &spec.components[m.term].function {
                ErrorFunction::Table(t) => t,
                _ => unreachable!("groups hold tables only"),
            })
            .collect();
        let per_table: Vec<[Vec<f64>; 3]> = tables
            .iter()
            .map(|t| by_dir(&t.forward, &t.reverse))
            .collect();
        for (slot, rows) in g.rows.iter_mut().enumerate() {
            for i in 0..g.nodes.x.len() {
                rows.extend(per_table.iter().map(|v| v[slot][i]));
            }
        }
    }
}

/// The thermal terms, their non-zero coefficients appended to `linear` and `quadratic`; the first
/// thermal term has breakdown index `first_term`.
pub(super) fn thermal_terms(
    spec: &ModelSpec,
    c: &Compiled,
    first_term: usize,
    linear: &mut Vec<(usize, f64)>,
    quadratic: &mut Vec<(usize, usize, f64)>,
) -> Vec<ThermalTerm> {
    spec.thermal
        .iter()
        .zip(&c.thermal)
        .enumerate()
        .map(|(i, (th, (s, idx, along)))| {
            let op = thermal_op(&th.kind, idx, *along, linear, quadratic);
            ThermalTerm {
                target: Target::new(first_term + i, s.elem, s.slot),
                op,
            }
        })
        .collect()
}

/// One thermal term's formula; `idx` are its sensors' indices, `along` the stations' element.
fn thermal_op(
    kind: &ThermalKind,
    idx: &[usize],
    along: Option<usize>,
    linear: &mut Vec<(usize, f64)>,
    quadratic: &mut Vec<(usize, usize, f64)>,
) -> ThermalOp {
    match kind {
        ThermalKind::PolynomialDt {
            e0,
            b_per_k,
            c_per_k2,
            ..
        } => ThermalOp::Polynomial {
            e0: *e0,
            linear: push_linear(linear, b_per_k, idx),
            quadratic: push_quadratic(quadratic, c_per_k2, idx),
        },
        ThermalKind::Slope {
            s0_per_mm,
            s_per_mm_k,
            d_per_mm_k2,
            ..
        } => ThermalOp::Slope {
            s0: *s0_per_mm,
            linear: push_linear(linear, s_per_mm_k, idx),
            quadratic: push_quadratic(quadratic, d_per_mm_k2, idx),
        },
        ThermalKind::Expansion {
            alpha_ppm_per_k,
            origin_mm,
            reference_c,
            ..
        } => ThermalOp::Expansion {
            sensor: idx[0],
            alpha_ppm_per_k: *alpha_ppm_per_k,
            origin_mm: *origin_mm,
            reference_c: *reference_c,
        },
        ThermalKind::Stations {
            stations_mm,
            e0,
            b_per_k,
            ..
        } => ThermalOp::Stations {
            along,
            inv_gap: stations_mm
                .windows(2)
                .map(|w| 1.0 / (w[1] - w[0]))
                .collect(),
            stations_mm: stations_mm.clone(),
            e0: e0.clone(),
            linear: b_per_k
                .iter()
                .map(|b| push_linear(linear, b, idx))
                .collect(),
        },
    }
}

/// Append the non-zero entries of `b` (one per sensor of `idx`) and return their range.
fn push_linear(linear: &mut Vec<(usize, f64)>, b: &[f64], idx: &[usize]) -> Range<usize> {
    let start = linear.len();
    linear.extend(
        b.iter()
            .zip(idx)
            .filter(|(b, _)| **b != 0.0)
            .map(|(&b, &i)| (i, b)),
    );
    start..linear.len()
}

/// Append the non-zero entries of the sensor matrix `cm` and return their range.
fn push_quadratic(
    quadratic: &mut Vec<(usize, usize, f64)>,
    cm: &[Vec<f64>],
    idx: &[usize],
) -> Range<usize> {
    let start = quadratic.len();
    for (i, row) in cm.iter().enumerate() {
        for (j, &cij) in row.iter().enumerate() {
            if cij != 0.0 {
                quadratic.push((idx[i], idx[j], cij));
            }
        }
    }
    start..quadratic.len()
}

/// The load terms as curves with their force scale; the first has breakdown index `first_term`.
pub(super) fn load_terms(spec: &ModelSpec, c: &Compiled, first_term: usize) -> Vec<LoadTerm> {
    spec.load
        .iter()
        .zip(&c.load)
        .enumerate()
        .map(|(i, (l, (s, fi)))| {
            let (function, scale) = match &l.kind {
                LoadKind::Compliance { compliance, .. } => (compliance.clone(), 1.0),
                LoadKind::WeightAngular {
                    reference,
                    reference_force_n,
                    lever_mm,
                    load_height_mm,
                    ..
                } => (
                    reference.clone(),
                    (lever_mm - load_height_mm) / lever_mm / reference_force_n,
                ),
            };
            LoadTerm {
                target: Target::new(first_term + i, s.elem, s.slot),
                force: *fi,
                curve: Curve::new(&function),
                scale,
            }
        })
        .collect()
}

/// The thermal terms by kind (polynomial, slope, expansion, the rest), or `None` when running the
/// kinds one after the other would add two terms of one motion in another order than the terms'.
pub(super) fn thermal_by_kind(thermal: &[ThermalTerm]) -> Option<ThermalByKind> {
    let rank = |op: &ThermalOp| match op {
        ThermalOp::Polynomial { .. } => 0,
        ThermalOp::Slope { .. } => 1,
        ThermalOp::Expansion { .. } => 2,
        ThermalOp::Stations { .. } => 3,
    };
    for (i, a) in thermal.iter().enumerate() {
        for b in &thermal[i + 1..] {
            if a.target.at == b.target.at && rank(&a.op) > rank(&b.op) {
                return None;
            }
        }
    }
    let mut k = ThermalByKind::default();
    for th in thermal {
        let tg = th.target;
        match &th.op {
            ThermalOp::Polynomial {
                e0,
                linear,
                quadratic,
            } => k
                .polynomial
                .push((tg, *e0, linear.clone(), quadratic.clone())),
            ThermalOp::Slope {
                s0,
                linear,
                quadratic,
            } => k.slope.push((tg, *s0, linear.clone(), quadratic.clone())),
            ThermalOp::Expansion {
                sensor,
                alpha_ppm_per_k,
                origin_mm,
                reference_c,
            } => k
                .expansion
                .push((tg, *sensor, *alpha_ppm_per_k, *origin_mm, *reference_c)),
            ThermalOp::Stations { .. } => k.other.push(th.clone()),
        }
    }
    Some(k)
}

/// The full groups that can run first as [`Block6`]s (no group before one has its element, so every
/// motion's sums keep their order), and the groups left.
pub(super) fn split_blocks(groups: Vec<Group>) -> (Vec<Block6>, Vec<Group>) {
    let (mut blocks, mut rest) = (Vec::new(), Vec::new());
    for (i, g) in groups.iter().enumerate() {
        let first_of_elem = groups[..i].iter().all(|h| h.elem != g.elem);
        match g.full_from_term {
            Some(first_term) if first_of_elem => blocks.push(Block6 {
                elem: g.elem,
                nodes: g.nodes.clone(),
                rows: g.rows.each_ref().map(|r| {
                    r.chunks_exact(6)
                        .map(|c| c.try_into().expect("six members"))
                        .collect()
                }),
                first_term,
            }),
            _ => rest.push(g.clone()),
        }
    }
    (blocks, rest)
}
