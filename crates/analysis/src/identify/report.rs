//! What a fit means: the machine model it gives (C¹ piecewise quadratics + squareness, loadable by
//! `check-config`, `eval`, `run`), per-component significance (partial F, Spaan's ANOVA) and
//! identifiability (null space of X, with the set-up that would help), and the verification on
//! held-out hole plates: residual, σ and efficiency δ = 1 − Σ|Δm − Δs| / Σ|Δm| per plate and
//! direction (Spaan Tables 3.2–3.4).
//!
//! Δm of a verification plate is its measured deviation with the plate's rigid pose fitted out; Δm −
//! Δs is the same after adding the model's error at each reading (the compensated reading), pose
//! fitted out again. µm throughout.

use serde::Serialize;

use super::Identification;
use super::contracts::HolePlate;
use super::design::{SQUARENESS, Shape};
use super::estimate::block_f;
use super::observe::{expanded_uv, plane_readings, rigid_2d, rot};
use crate::fit::efficiency;
use crate::fit::lead::LeadWave;
use retrocomp_model::{ComponentSpec, SquarenessSpec, ToolSpec};
use retrocomp_model::{ErrorFunction, Interpolation, MachineModel, ModelSpec, Motion, Table};

/// One component's verdict.
#[derive(Debug, Clone, Serialize)]
pub struct ComponentReport {
    pub name: String,
    pub shape: Shape,
    pub range_mm: (f64, f64),
    pub knots_mm: Vec<f64>,
    /// Partial F and its p-value (None: not estimable).
    pub f: Option<f64>,
    pub p_value: Option<f64>,
    /// Per term: name, coefficient, t.
    pub terms: Vec<(String, f64, f64)>,
    /// How far the data's null space moves this component, relative to the component it moves most
    /// (0 = fully seen by the data, 1 = moved as much as anything).
    pub null_weight: f64,
    /// The data see it: no unseen combination moves it by more than [`NULL_LIMIT`].
    pub identifiable: bool,
    /// Largest |value| and largest standard error over the range (µm or µrad).
    pub max_abs: f64,
    pub max_se: f64,
    /// Expanded uncertainty over the range, [`COVERAGE_K`] × `max_se` (µm or µrad).
    pub uncertainty: f64,
    /// Identified within [`TARGET`] µm / µrad: identifiable and `uncertainty` ≤ [`TARGET`]
    /// (issue 15 point 4). A component that is identifiable but not identified is determined by
    /// the data only loosely: combinations it barely sees carry noise (and unseen combinations
    /// that move it by less than the null limit) into it.
    pub identified: bool,
    /// What set-up would identify it (when it is not identifiable, or not to [`TARGET`]).
    pub needs: Option<String>,
}

/// A squareness angle's estimate.
#[derive(Debug, Clone, Serialize)]
pub struct SquarenessReport {
    pub name: &'static str,
    pub value_urad: f64,
    pub se_urad: f64,
    pub identifiable: bool,
    /// [`COVERAGE_K`] × `se_urad`.
    pub uncertainty_urad: f64,
    /// Identifiable and `uncertainty_urad` ≤ [`TARGET`].
    pub identified: bool,
}

/// Components whose null weight is above this are reported as not identifiable.
pub const NULL_LIMIT: f64 = 0.05;

/// What "identified" means (issue 15 point 4): within 2 µm (translations) or 2 µrad (rotations,
/// squareness) of the truth over the identified range.
pub const TARGET: f64 = 2.0;

/// Coverage factor of the expanded uncertainty compared with [`TARGET`]: 3, not GUM's usual 2,
/// because the judgment is on the largest deviation over the whole range (41 points per
/// component, strongly correlated), not at one point.
pub const COVERAGE_K: f64 = 3.0;

/// For each null vector, how far it moves each component (max |value| over its range, µm or µrad)
/// and each squareness angle, relative to the most-moved one: rows = null vectors, columns = the
/// 18 components then the 3 angles. A component the data sees has ~0 in every row.
fn null_moves(id: &Identification) -> Vec<Vec<f64>> {
    id.solve
        .null
        .iter()
        .map(|v| {
            let mut m = moves_of(id, v);
            let top = m.iter().copied().fold(0.0, f64::max);
            if top > 0.0 {
                m.iter_mut().for_each(|x| *x /= top);
            }
            m
        })
        .collect()
}

/// How far a change `v` of the parameters moves each component (max |value| over its range, µm or
/// µrad) and each squareness angle: the 18 components then the 3 angles.
fn moves_of(id: &Identification, v: &nalgebra::DVector<f64>) -> Vec<f64> {
    let mut col = 0;
    let mut m: Vec<f64> = id
        .bases
        .iter()
        .map(|b| {
            let c: Vec<f64> = (col..col + b.n_terms()).map(|j| v[j]).collect();
            col += b.n_terms();
            (0..=40)
                .map(|k| {
                    b.eval(&c, b.lo_mm + (b.hi_mm - b.lo_mm) * f64::from(k) / 40.0)
                        .abs()
                })
                .fold(0.0, f64::max)
        })
        .collect();
    m.extend((0..3).map(|k| v[col + k].abs()));
    m
}

/// The per-component table.
pub fn components(id: &Identification) -> (Vec<ComponentReport>, Vec<SquarenessReport>) {
    let s = &id.solve;
    let moves = null_moves(id);
    let weight = |k: usize| moves.iter().map(|m| m[k]).fold(0.0, f64::max);
    let mut col = 0;
    let mut out = Vec::new();
    for (ib, b) in id.bases.iter().enumerate() {
        let cols = col..col + b.n_terms();
        col += b.n_terms();
        let coef = &s.coef[cols.clone()];
        let grid: Vec<f64> = (0..=40)
            .map(|k| b.lo_mm + (b.hi_mm - b.lo_mm) * f64::from(k) / 40.0)
            .collect();
        let max_abs = grid
            .iter()
            .map(|q| b.eval(coef, *q).abs())
            .fold(0.0, f64::max);
        let max_se = grid
            .iter()
            .map(|q| {
                let mut v = Vec::new();
                b.values(*q, &mut v);
                let var: f64 = (0..v.len())
                    .flat_map(|i| (0..v.len()).map(move |j| (i, j)))
                    .map(|(i, j)| v[i] * v[j] * s.xtx_pinv[(cols.start + i, cols.start + j)])
                    .sum();
                s.sigma_um * var.max(0.0).sqrt()
            })
            .fold(0.0, f64::max);
        let nw = weight(ib);
        let identifiable = nw < NULL_LIMIT;
        let uncertainty = COVERAGE_K * max_se;
        let identified = identifiable && uncertainty <= TARGET;
        let fp = if identifiable {
            block_f(s, cols.clone())
        } else {
            None
        };
        let terms = b
            .term_names()
            .into_iter()
            .zip(cols.clone())
            .map(|(n, j)| {
                let t = if s.se[j] > 0.0 {
                    s.coef[j] / s.se[j]
                } else {
                    0.0
                };
                (n, s.coef[j], t)
            })
            .collect();
        out.push(ComponentReport {
            name: b.id.iso_name(),
            shape: b.shape,
            range_mm: (b.lo_mm, b.hi_mm),
            knots_mm: b.knots_mm.clone(),
            f: fp.map(|x| x.0),
            p_value: fp.map(|x| x.1),
            terms,
            null_weight: nw,
            identifiable,
            max_abs,
            max_se,
            uncertainty,
            identified,
            needs: if !identifiable {
                Some(needs(id, &moves, ib, b.id))
            } else if !identified {
                Some(needs_precision(id, b.id, uncertainty))
            } else {
                None
            },
        });
    }
    let sq = SQUARENESS
        .iter()
        .enumerate()
        .map(|(k, q)| {
            let j = col + k;
            let identifiable = weight(id.bases.len() + k) < NULL_LIMIT;
            let uncertainty_urad = COVERAGE_K * s.se[j];
            SquarenessReport {
                name: q.iso_name(),
                value_urad: s.coef[j],
                se_urad: s.se[j],
                identifiable,
                uncertainty_urad,
                identified: identifiable && uncertainty_urad <= TARGET,
            }
        })
        .collect();
    (out, sq)
}

/// The extra set-up that would make a component visible. `moves`: [`null_moves`].
fn needs(
    id: &Identification,
    moves: &[Vec<f64>],
    ib: usize,
    c: retrocomp_model::ComponentId,
) -> String {
    // A null direction that moves this component and a squareness angle: the combination is rigid
    // on every plate of that squareness' plane measured so far (two XZ measurements always are,
    // whatever their place and probe): one more plate in that plane elsewhere pins it.
    let n_comp = id.bases.len();
    let sq = moves
        .iter()
        .filter(|m| m[ib] > NULL_LIMIT)
        .flat_map(|m| (0..3).filter(move |&k| m[n_comp + k] > NULL_LIMIT))
        .next();
    if let Some(k) = sq {
        let q = SQUARENESS[k];
        let (a, b, across) = q.axes();
        return format!(
            "one more plate in the {}{} plane at another {} position (or probe length): with the \
             plates so far, a combination of this component, others and the {} squareness is a \
             rigid motion of every plate",
            a.lower(),
            b.lower(),
            across.upper(),
            q.iso_name()
        );
    }
    by_motion(id, c)
}

/// The set-up that would pin a component the data see only loosely (expanded uncertainty `u`
/// above [`TARGET`]): noise averages down as 1/√n, so (u / TARGET)² times the probings of the
/// same set-ups, or — usually far cheaper — a set-up that gives it leverage of its own.
fn needs_precision(id: &Identification, c: retrocomp_model::ComponentId, u: f64) -> String {
    let unit = if c.is_rotation() { "µrad" } else { "µm" };
    let factor = (u / TARGET).powi(2).ceil();
    format!(
        "not identified to {TARGET} {unit}: ±{u:.1} {unit} over the range ({COVERAGE_K} σ);          {factor:.0}× the probings of these set-ups, or {}",
        by_motion(id, c)
    )
}

/// The set-up that gives a component leverage, by its kind of motion.
fn by_motion(id: &Identification, c: retrocomp_model::ComponentId) -> String {
    let tool_axis = id.geometry.spec.tool_axis.0;
    let tool_side = id
        .geometry
        .spec
        .axes
        .iter()
        .any(|a| a.axis == c.axis && a.branch == retrocomp_model::Branch::Tool);
    match c.motion {
        Motion::Rotation(d) if d == tool_axis && tool_side => format!(
            "a second tool vector with a sideways offset (a probe offset along X or Y): rotation \
             about {} of a tool-side carriage has no Abbe arm with the tool along {} (Spaan: only \
             two tool vectors, zrz poorly identified)",
            d.upper(),
            tool_axis.upper()
        ),
        Motion::Rotation(d) => format!(
            "artefacts whose Abbe arm across {} changes while {} moves: plates at two heights / \
             two probe lengths, or a plate in a plane containing {}",
            d.upper(),
            c.axis.upper(),
            c.axis.upper()
        ),
        Motion::Translation(d) => format!(
            "a plate in the {}{} plane (or spheres spanning both axes)",
            c.axis.lower(),
            d.lower()
        ),
    }
}

/// The lead wave of one positioning component and whether the data see it.
#[derive(Debug, Clone, Serialize)]
pub struct LeadReport {
    #[serde(flatten)]
    pub wave: LeadWave,
    /// No combination the data cannot see moves the wave by more than [`NULL_LIMIT`] of what it
    /// moves most, and its sin and cos coefficients are known to [`LEAD_TARGET_UM`]
    /// ([`COVERAGE_K`] σ). Not so when every hole of each plate sits at one phase of the lead (a
    /// pitch that is a multiple of it): the plate's pose then absorbs the wave, all but what the
    /// plate's small rotation and expansion spread over the phases.
    pub identified: bool,
}

/// How well a lead wave's sin and cos coefficients must be known to call it identified, µm
/// (expanded, [`COVERAGE_K`] σ): issue 37's tolerance on the amplitude.
pub const LEAD_TARGET_UM: f64 = 0.2;

/// The lead wave of each positioning component fitted with one (`--lead-mm`): amplitude and phase
/// with their standard errors (from the fit's covariance).
pub fn lead_waves(id: &Identification) -> Vec<LeadReport> {
    let s = &id.solve;
    let mut col = 0;
    let mut out = Vec::new();
    for b in &id.bases {
        if let (Some(lead), Some(k)) = (b.lead_mm, b.lead_term()) {
            let j = col + k;
            let v = |a: usize, b: usize| s.sigma_um * s.sigma_um * s.xtx_pinv[(j + a, j + b)];
            let cov = [[v(0, 0), v(0, 1)], [v(1, 0), v(1, 1)]];
            let unseen = s.null.iter().any(|n| {
                let top = moves_of(id, n).into_iter().fold(0.0, f64::max);
                top > 0.0 && n[j].hypot(n[j + 1]) > NULL_LIMIT * top
            });
            let se = cov[0][0].max(cov[1][1]).sqrt();
            out.push(LeadReport {
                wave: LeadWave::new(&b.id.iso_name(), lead, s.coef[j], s.coef[j + 1], cov),
                identified: !unseen && COVERAGE_K * se <= LEAD_TARGET_UM,
            });
        }
        col += b.n_terms();
    }
    out
}

/// The identified machine model (components as Spaan's piecewise quadratics, squareness angles;
/// a positioning component with a lead wave as a linear table every lead/16).
pub fn to_spec(id: &Identification, name: &str) -> ModelSpec {
    let mut spec = id.geometry.spec.clone();
    spec.name = name.to_string();
    spec.description = format!(
        "identified by retrocomp identify from {} artefact set-ups ({} observations, σ = {:.2} µm)",
        id.setups.len(),
        id.obs.len(),
        id.solve.sigma_um
    );
    spec.synthetic = false;
    let mean_tool = id.obs.iter().map(|o| o.tool_mm).sum::<f64>() / id.obs.len().max(1) as f64;
    spec.tools = vec![ToolSpec {
        name: "probe".into(),
        offset_mm: id.geometry.tool_dir.map(|d| d * mean_tool),
    }];
    let mut col = 0;
    for b in &id.bases {
        let c = &id.solve.coef[col..col + b.n_terms()];
        col += b.n_terms();
        if let Some(lead) = b.lead_mm {
            // The wave needs nodes every lead/16: the whole component as one fine linear table.
            let q = crate::fit::lead::table_positions(b.lo_mm, b.hi_mm, lead);
            let v: Vec<f64> = q.iter().map(|x| b.eval(c, *x)).collect();
            spec.components.push(ComponentSpec {
                id: b.id,
                function: ErrorFunction::Table(Table::new(q, v.clone(), v, Interpolation::Linear)),
            });
            continue;
        }
        let (a1, rest) = if b.shape == Shape::Straightness {
            (0.0, c)
        } else {
            (c[0], &c[1..])
        };
        let a2 = rest[0];
        let lo = b.lo_mm;
        spec.components.push(ComponentSpec {
            id: b.id,
            function: ErrorFunction::PiecewiseQuadratic {
                base: [-a1 * lo + a2 * lo * lo, a1 - 2.0 * a2 * lo, a2],
                knots_mm: b.knots_mm.clone(),
                knot_coefficients: rest[1..].to_vec(),
                range_mm: Some((b.lo_mm, b.hi_mm)),
            },
        });
    }
    for (k, q) in SQUARENESS.iter().enumerate() {
        spec.squareness.push(SquarenessSpec {
            kind: *q,
            on_axis: q.axes().1,
            value_urad: id.solve.coef[col + k],
        });
    }
    spec
}

/// One verification plate, one direction (a row of Spaan Tables 3.2–3.4).
#[derive(Debug, Clone, Serialize)]
pub struct DirVerify {
    pub plate: String,
    pub direction: char,
    /// Largest |Δm| (Spaan's "Meas").
    pub meas_um: f64,
    /// Largest |Δm − Δs| (Spaan's "Res").
    pub res_um: f64,
    pub sigma_um: f64,
    pub efficiency: f64,
    /// Per probing: (hole, Δm, Δm − Δs), for plots.
    pub holes: Vec<(String, f64, f64)>,
    /// Per probing (same order): machine position along `direction`, mm (the plots' x axis).
    pub pos_mm: Vec<f64>,
}

/// In-plane deviations of a plate after its rigid pose is fitted out, µm, for readings `r`.
fn pose_free_deviation(p: &[[f64; 2]], r: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let (c, th) = rigid_2d(p, r);
    p.iter()
        .zip(r)
        .map(|(p, r)| {
            let h = rot(th, *p);
            [(r[0] - c[0] - h[0]) * 1e3, (r[1] - c[1] - h[1]) * 1e3]
        })
        .collect()
}

/// Verification of `model` on a held-out plate: per in-plane direction. Where two probings of a
/// hole disagree beyond the outlier limit (as in the fit), the one farther from the compensated
/// plate is left out; each hole then counts once, at the mean of its remaining probings.
pub fn verify(model: &MachineModel, plate: &HolePlate) -> Vec<DirVerify> {
    let first = verify_all_probings(model, plate);
    let mut diffs: Vec<f64> = Vec::new();
    let mut pairs: Vec<(usize, usize)> = Vec::new();
    for i in 0..plate.probes.len() {
        for j in i + 1..plate.probes.len() {
            if plate.probes[i].hole == plate.probes[j].hole {
                pairs.push((i, j));
                for d in &first {
                    diffs.push((d.holes[i].1 - d.holes[j].1).abs());
                }
            }
        }
    }
    if diffs.is_empty() {
        return first;
    }
    diffs.sort_by(f64::total_cmp);
    let limit = (6.0 * 1.4826 * diffs[diffs.len() / 2]).max(1.0);
    let mut drop = vec![false; plate.probes.len()];
    for (i, j) in pairs {
        let spread = first
            .iter()
            .map(|d| (d.holes[i].1 - d.holes[j].1).abs())
            .fold(0.0, f64::max);
        if spread > limit {
            let res = |k: usize| first.iter().map(|d| d.holes[k].2.abs()).fold(0.0, f64::max);
            drop[if res(i) > res(j) { i } else { j }] = true;
        }
    }
    // One reading per hole: the mean of its probings that are left.
    let mut kept = plate.clone();
    kept.probes.clear();
    let mut count: Vec<f64> = Vec::new();
    for (p, d) in plate.probes.iter().zip(&drop) {
        if *d {
            continue;
        }
        match kept.probes.iter().position(|k| k.hole == p.hole) {
            Some(i) => {
                let n = count[i];
                for k in 0..3 {
                    kept.probes[i].pos_mm[k] =
                        (kept.probes[i].pos_mm[k] * n + p.pos_mm[k]) / (n + 1.0);
                }
                count[i] += 1.0;
            }
            None => {
                kept.probes.push(p.clone());
                count.push(1.0);
            }
        }
    }
    verify_all_probings(model, &kept)
}

fn verify_all_probings(model: &MachineModel, plate: &HolePlate) -> Vec<DirVerify> {
    let [a, b] = plate.plane.axes();
    let p = expanded_uv(plate);
    let r = plane_readings(plate);
    let dm = pose_free_deviation(&p, &r);
    let mut state = model.new_state();
    let mut input = model.new_input();
    let mut out = model.new_breakdown();
    // The compensated reading: the tool was actually at r + e(r).
    let rc: Vec<[f64; 2]> = plate
        .probes
        .iter()
        .zip(&r)
        .map(|(probe, r)| {
            input.pos_mm = super::contracts::scale_corrected(
                probe.pos_mm,
                probe.t_scale_c,
                plate.scale_alpha_ppm_per_k,
            );
            input.tool_mm = Some(probe.tool_mm);
            model.evaluate(&input, &mut state, &mut out);
            [r[0] + out.total_um[a] * 1e-3, r[1] + out.total_um[b] * 1e-3]
        })
        .collect();
    let res = pose_free_deviation(&p, &rc);
    [a, b]
        .into_iter()
        .enumerate()
        .map(|(k, axis)| {
            let m: Vec<f64> = dm.iter().map(|v| v[k]).collect();
            let rr: Vec<f64> = res.iter().map(|v| v[k]).collect();
            let s: Vec<f64> = m.iter().zip(&rr).map(|(m, r)| m - r).collect();
            let eff = efficiency(&m, &s);
            let n = rr.len() as f64;
            let mean = rr.iter().sum::<f64>() / n;
            DirVerify {
                plate: plate.name.clone(),
                direction: ['x', 'y', 'z'][axis],
                meas_um: m.iter().fold(0.0, |x, v| x.max(v.abs())),
                res_um: rr.iter().fold(0.0, |x, v| x.max(v.abs())),
                sigma_um: (rr.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0))
                    .sqrt(),
                efficiency: eff.map_or(f64::NAN, |e| e.delta),
                holes: plate
                    .probes
                    .iter()
                    .zip(m.iter().zip(&rr))
                    .map(|(p, (m, r))| (p.hole.clone(), *m, *r))
                    .collect(),
                pos_mm: r.iter().map(|v| v[k]).collect(),
            }
        })
        .collect()
}
